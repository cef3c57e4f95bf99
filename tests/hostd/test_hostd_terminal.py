"""cdro-hostd at a terminal, as a person first runs it: stdout and stderr on a real
pseudo-terminal. The terminal gets the logs and a progress line, not a flood of JSON Lines;
`--jsonl -` still puts them there, and a pipe gets them as it always did (docs/service.md,
"Outputs"). On a terminal the progress line is redrawn in place under the log; elsewhere it is
an ordinary line. Timeouts are deadlock guards only."""
from __future__ import annotations

import json
import os
import pathlib
import pty
import re
import select
import signal
import socket
import subprocess
import sys
import time

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
GUARD_S = 60.0
PROGRESS = "cdro-hostd: replay |"
PROGRESS_WITH_NODES = re.compile(r"cdro-hostd: replay \| [^\r\n]* nodes [1-9][0-9]*:")
LOG_LINE = re.compile(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3} [a-z]+ ")
COLOUR = re.compile(r"\x1b\[[0-9;]*m")


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    directory = tmp_path_factory.mktemp("terminal")
    path = directory / "run.cdrocap"
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--duration", "30",
                    "--capture", str(path)], check=True, capture_output=True, timeout=GUARD_S)
    return path


def run_on_a_terminal(build_dir, capture, extra, until):
    """cdro-hostd replaying at real speed with stdout and stderr on a pseudo-terminal; stopped
    with SIGTERM once the text on the terminal matches `until`. Returns everything it wrote."""
    master, slave = pty.openpty()
    process = subprocess.Popen([str(build_dir / "bin" / "cdro-hostd"), "--replay", str(capture), "--speed", "1",
                                *extra], stdin=subprocess.DEVNULL, stdout=slave, stderr=slave)
    os.close(slave)
    text = ""
    deadline = time.monotonic() + GUARD_S
    stopped = False
    try:
        while True:
            assert time.monotonic() < deadline, f"deadlock guard; the terminal showed:\n{text[-2000:]}"
            if not stopped and until(text):
                process.send_signal(signal.SIGTERM)
                stopped = True
            ready, _, _ = select.select([master], [], [], 0.1)
            if not ready:
                continue
            try:
                chunk = os.read(master, 65536)
            except OSError:          # EIO: the last writer closed the terminal
                break
            if not chunk:
                break
            text += chunk.decode("utf-8", errors="replace")
    finally:
        if process.poll() is None and not stopped:
            process.kill()
        process.wait(timeout=GUARD_S)
        os.close(master)
    assert process.returncode == 0, text[-2000:]
    return text


def screen_lines(text: str) -> list[str]:
    """The lines a terminal shows after `text`: carriage return, line feed, and the ANSI erase
    (ESC[K to the end of the line, ESC[J to the end of the screen) and cursor-up (ESC[nA)
    sequences; colours dropped."""
    lines, row, column = [""], 0, 0
    for token in re.split(r"(\r|\n|\x1b\[\d*[AJK])", COLOUR.sub("", text)):
        if token == "\r":
            column = 0
        elif token == "\n":
            row, column = row + 1, 0
            if row == len(lines):
                lines.append("")
        elif token.startswith("\x1b["):
            if token[-1] == "A":
                row = max(0, row - int(token[2:-1] or 1))
            else:
                lines[row] = lines[row][:column]
                if token[-1] == "J":
                    del lines[row + 1:]
        elif token:
            line = lines[row].ljust(column)
            lines[row] = line[:column] + token + line[column + len(token):]
            column += len(token)
    return lines


def json_lines(text: str) -> list[str]:
    return [line for line in text.replace("\r", "").splitlines() if line.startswith('{"type"')]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_terminal_gets_a_progress_line_and_no_json_lines(build_dir, capture):
    port = free_port()
    text = run_on_a_terminal(build_dir, capture, ["--http-port", str(port)],
                             lambda t: PROGRESS_WITH_NODES.search(t))
    assert json_lines(text) == []
    assert "stdout is a terminal" in text
    # The progress line: link, nodes placed and converged, and where the live map is.
    progress = PROGRESS_WITH_NODES.search(text).group(0)
    line = text[text.index(progress):].splitlines()[0]
    assert "placed" in line and "converged" in line and f"| map http://127.0.0.1:{port}/" in line


def test_on_a_terminal_the_progress_line_is_redrawn_in_place_under_the_log(build_dir, capture):
    # Act: stopped after three updates, so that the shutdown's log lines come while it is shown
    text = run_on_a_terminal(build_dir, capture, ["--http-port", "0"], lambda t: t.count(PROGRESS) >= 3)
    screen = [line for line in screen_lines(text) if line.strip()]

    # Assert
    draws = [m.start() for m in re.finditer(re.escape(PROGRESS), text)]
    assert len(draws) >= 3, text
    assert all(text[:start].endswith("\r\x1b[K") for start in draws), text
    between = [text[a:b] for a, b in zip(draws, draws[1:])]
    quiet = [span for span in between if not LOG_LINE.search(COLOUR.sub("", span))]
    assert quiet and all("\n" not in span for span in quiet), between
    logs = [line for line in screen if LOG_LINE.search(line)]
    assert any("stopping" in line for line in logs), screen
    assert all(LOG_LINE.match(line) for line in logs), screen            # none glued to the progress line
    assert all(line.startswith(PROGRESS) for line in screen if PROGRESS in line), screen
    assert screen[-1].startswith(PROGRESS), screen                        # kept under the log, to the end
    assert text.endswith("\n")                                            # and ended for what follows


def test_off_a_terminal_the_progress_line_is_an_ordinary_line(build_dir, capture, tmp_path):
    # Fixture
    stderr_path = tmp_path / "stderr.txt"

    # Act
    with open(stderr_path, "w") as stderr:
        process = subprocess.Popen([str(build_dir / "bin" / "cdro-hostd"), "--replay", str(capture), "--speed", "1",
                                    "--progress", "--jsonl", "", "--http-port", "0"], stdin=subprocess.DEVNULL,
                                   stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        deadline = time.monotonic() + GUARD_S
        while stderr_path.read_text().count(PROGRESS) < 3:
            assert time.monotonic() < deadline, f"deadlock guard:\n{stderr_path.read_text()}"
            time.sleep(0.1)
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=GUARD_S) == 0
    finally:
        if process.poll() is None:
            process.kill()
    text = stderr_path.read_text()

    # Assert
    assert "\r" not in text and "\x1b" not in text, repr(text)
    lines = text.splitlines()
    progress = [line for line in lines if PROGRESS in line]
    assert len(progress) >= 3 and all(line.startswith(PROGRESS) for line in progress), lines
    assert any("stopping" in line for line in lines) and text.endswith("\n")


def test_json_lines_on_a_terminal_when_asked(build_dir, capture):
    text = run_on_a_terminal(build_dir, capture, ["--jsonl", "-"], lambda t: '{"type":"node"' in t)
    assert json_lines(text)
    assert "stdout is a terminal" not in text


def test_a_pipe_gets_json_lines_as_before(build_dir, capture):
    result = subprocess.run([str(build_dir / "bin" / "cdro-hostd"), "--replay", str(capture), "--speed", "max"],
                            capture_output=True, text=True, timeout=GUARD_S)
    assert result.returncode == 0, result.stderr
    lines = [json.loads(line) for line in json_lines(result.stdout)]
    assert lines
    assert "cdro-hostd: replay |" not in result.stderr   # no progress line unless asked
    # Every key the service writes is documented, and every line says its schema.
    documented = (REPO / "docs" / "outputs.md").read_text()
    assert not [key for key in {key for line in lines for key in line} if f"`{key}`" not in documented]
    assert {line["schema"] for line in lines} == {2}
    unplaced = [line for line in lines if line["type"] == "node" and not line["placed"]]
    assert unplaced and all(line["x_m"] is None and line["var_x_m2"] is None for line in unplaced)
    assert all(line["z_m"] is None for line in lines if line["type"] == "node")   # no heights given


def test_known_heights_are_written_as_z(build_dir, capture):
    heights = {0x6001: 1.25, 0x6003: 0.5}
    path = capture.parent / "heights.csv"
    path.write_text("id,z\n" + "".join(f"{i},{z}\n" for i, z in heights.items()))
    result = subprocess.run([str(build_dir / "bin" / "cdro-hostd"), "--replay", str(capture), "--speed", "max",
                             "--heights-csv", str(path)], capture_output=True, text=True, timeout=GUARD_S)
    assert result.returncode == 0, result.stderr
    nodes = [json.loads(line) for line in json_lines(result.stdout) if '"type":"node"' in line]
    z = {line["id"]: line["z_m"] for line in nodes}
    assert z[0x6001] == 1.25 and z[0x6003] == 0.5
    assert z[0x6002] is None
