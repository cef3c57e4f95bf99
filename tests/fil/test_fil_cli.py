"""cdro-fil on its own: bad input is a clear error, a run ends cleanly at its duration or on
SIGTERM with its summary, and two runs side by side each get their own serial port and boot."""
from __future__ import annotations

import json
import os
import pathlib
import select
import signal
import subprocess
import time

import pytest

from cdro_tools.codec import Result, StreamDecoder

from fil_support import avr_elf

HERE = pathlib.Path(__file__).resolve().parent
SCENARIO = HERE / "office_60s.yaml"
GUARD_S = 30.0  # s of wall-clock time; only reached when something is broken


@pytest.fixture
def fil(build_dir, avr_build_dir):
    binary = build_dir / "bin" / "cdro-fil"
    elf = avr_elf(avr_build_dir)
    if not binary.exists():
        pytest.fail(f"{binary} missing: build the native tree first (cmake --build build)")
    if not elf.exists():
        pytest.fail(f"{elf} missing: build the AVR image first (cmake --build build-avr)")
    return binary, elf


def run_fil(binary, *args, timeout_s=GUARD_S):
    return subprocess.run([str(binary), *map(str, args)], capture_output=True, text=True, timeout=timeout_s)


def test_bad_input_is_a_clear_error(fil, tmp_path):
    binary, elf = fil
    bad = tmp_path / "bad.yaml"
    bad.write_text("own_id: 0x6000\nnodes:\n  - {id: 0x6000, x_m: 0, y_m: 0}\n"
                   "  - {id: 0x6A01, x_m: 1, y_m: 0, colour: red}\n")
    result = run_fil(binary, "--elf", elf, "--scenario", bad)
    assert result.returncode == 2
    assert f"{bad}:4: nodes[1].colour: unknown key" in result.stderr
    assert result.stdout == ""

    hang = tmp_path / "hang.yaml"
    hang.write_text(SCENARIO.read_text().replace("faults:\n", "faults:\n  - {kind: hang, at_s: 3}\n"))
    result = run_fil(binary, "--elf", elf, "--scenario", hang)
    assert result.returncode == 2 and "'hang' cannot be simulated here" in result.stderr

    result = run_fil(binary, "--elf", tmp_path / "missing.elf", "--scenario", SCENARIO)
    assert result.returncode == 2 and "missing.elf" in result.stderr

    not_avr = tmp_path / "not-an.elf"
    not_avr.write_bytes(b"\x7fELF but not really")
    result = run_fil(binary, "--elf", not_avr, "--scenario", SCENARIO, "--duration-s", "0.1")
    assert result.returncode == 2 and "not-an.elf" in result.stderr

    result = run_fil(binary, "--elf", elf, "--scenario", SCENARIO, "--loop-symbol", "no_such_function")
    assert result.returncode == 2 and "no function symbol 'no_such_function'" in result.stderr

    result = run_fil(binary, "--elf", elf, "--scenario", SCENARIO, "--summary", tmp_path / "no-dir" / "s.json")
    assert result.returncode == 2 and "cannot write the summary" in result.stderr

    file_in_the_way = tmp_path / "port"
    file_in_the_way.write_text("a file")
    result = run_fil(binary, "--elf", elf, "--scenario", SCENARIO, "--link", file_in_the_way)
    assert result.returncode == 2 and "is not a symlink" in result.stderr
    assert file_in_the_way.read_text() == "a file"


def test_run_without_a_host_ends_at_its_duration(fil, tmp_path):
    binary, elf = fil
    summary_path = tmp_path / "summary.json"
    result = run_fil(binary, "--elf", elf, "--scenario", SCENARIO, "--duration-s", "1.5", "--summary", summary_path,
                     "--truth-csv", tmp_path / "truth.csv", "--truth-period-ms", "500")
    assert result.returncode == 0, result.stderr
    assert result.stdout == "", "with --summary nothing goes to stdout"
    s = json.loads(summary_path.read_text())
    assert s["exit_reason"] == "duration"
    assert s["simulated_s"] == pytest.approx(1.5, abs=0.002)
    assert s["cycles"] == pytest.approx(1.5 * 16e6, abs=16e3)
    # Nobody had the port open: the boot's 0x00, HELLO and NODE_LIST went nowhere, like a USB
    # serial port nobody reads.
    assert s["uart"]["tx_bytes"] > 24 and s["uart"]["tx_dropped_bytes"] == s["uart"]["tx_bytes"]
    # Boot: the Pozyx was identified and discovery found every remote node, over the real TWI.
    assert s["i2c"]["transactions"] > 10 and s["protocol_violations"] == 0
    assert s["loop"]["iterations"] > 100
    assert 20_000 < s["loop"]["worst_us"] < 100_000, "the discovery step (~42 ms) is the longest of a boot"
    lines = (tmp_path / "truth.csv").read_text().splitlines()
    assert lines[0] == "t,id,x,y,z" and len(lines) == 1 + 7 * 4  # 7 nodes at 0, 0.5, 1, 1.5 s


def read_frames(fd, seconds: float) -> list:
    decoder, frames = StreamDecoder(), []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.05)
        if ready:
            frames += [e for e in decoder.feed(os.read(fd, 4096))]
    return frames


def test_sigterm_and_two_runs_side_by_side(fil, tmp_path):
    binary, elf = fil
    runs = []
    for name in ("a", "b"):
        link = tmp_path / f"tty-{name}"
        log = open(tmp_path / f"{name}.log", "w")
        process = subprocess.Popen([str(binary), "--elf", str(elf), "--scenario", str(SCENARIO), "--duration-s", "0",
                                    "--link", str(link), "--start-on-open"],
                                   stdout=subprocess.PIPE, stderr=log, text=True)
        runs.append((name, link, process, log))
    ports = []
    for name, link, process, _ in runs:
        deadline = time.monotonic() + 10
        while not link.is_symlink():
            assert process.poll() is None and time.monotonic() < deadline, f"run {name} made no port"
            time.sleep(0.01)
        ports.append(os.path.realpath(link))
    assert ports[0] != ports[1], "each run has its own pseudo-terminal"

    # --start-on-open: each AVR boots when its port is opened, so the first frame is the boot HELLO.
    fds = [os.open(link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK) for _, link, _, _ in runs]
    for fd in fds:
        events = read_frames(fd, 1.5)
        good = [e.frame for e in events if e.result == Result.OK]
        assert good and good[0].type == "HELLO" and good[0].sequence == 0, [str(e.result) for e in events]
        assert all(e.result == Result.OK for e in events)

    for (name, link, process, log), fd in zip(runs, fds):
        process.send_signal(signal.SIGTERM)
        out, _ = process.communicate(timeout=GUARD_S)
        log.close()
        os.close(fd)
        assert process.returncode == 0, (tmp_path / f"{name}.log").read_text()
        s = json.loads(out)  # the summary on stdout, nothing else there
        assert s["exit_reason"] == "signal"
        assert s["simulated_s"] > 1.0
        assert not link.exists() and not link.is_symlink(), "the symlink is removed at exit"
