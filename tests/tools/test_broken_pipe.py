"""Every tool, when its reader stops early (`cdro-eval | head`), ends quietly: no traceback, the
status of a program ended by SIGPIPE (128 + 13), as `yes | head` gives."""
import os
import pathlib
import subprocess
import sys
import tomllib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
GUARD_S = 60
ENTRY_POINTS = sorted(tomllib.loads((REPO / "tools" / "pyproject.toml").read_text())["project"]["scripts"])
SIGPIPE_STATUS = 141


def run_with_a_closed_reader(argv, cwd):
    """argv with its stdout a pipe whose reading end is already closed: every write fails with
    EPIPE, whatever the pipe's buffer size."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        return subprocess.run(argv, stdout=write_end, stderr=subprocess.PIPE, text=True, cwd=cwd, timeout=GUARD_S)
    finally:
        os.close(write_end)


def tool(name):
    return str(pathlib.Path(sys.executable).parent / name)


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_that_help_into_a_closed_pipe_ends_quietly(name, tmp_path):
    result = run_with_a_closed_reader([tool(name), "--help"], tmp_path)
    assert "Traceback" not in result.stderr and "Exception ignored" not in result.stderr, result.stderr
    assert result.returncode == SIGPIPE_STATUS


def test_that_eval_and_decode_into_a_closed_pipe_end_quietly(tmp_path):
    # Fixture: a short simulated run, as CSV files and a capture
    subprocess.run([tool("cdro-sim"), "--scenario", "demo", "--duration", "10", "--ranges-csv", "ranges.csv",
                    "--truth-csv", "truth.csv", "--capture", "run.cdrocap"], cwd=tmp_path, check=True,
                   capture_output=True, timeout=GUARD_S)

    # Test
    evaluated = run_with_a_closed_reader([tool("cdro-eval"), "--truth", "truth.csv", "--ranges", "ranges.csv",
                                          "--heights-from-truth", "--json", "eval.json"], tmp_path)
    decoded = run_with_a_closed_reader([tool("cdro-decode"), "run.cdrocap"], tmp_path)

    # Assert: no traceback; cdro-eval still writes the file it was asked for
    for result in (evaluated, decoded):
        assert "Traceback" not in result.stderr and "Exception ignored" not in result.stderr, result.stderr
    assert (tmp_path / "eval.json").stat().st_size > 0
    assert decoded.returncode == SIGPIPE_STATUS
