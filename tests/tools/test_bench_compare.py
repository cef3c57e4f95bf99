"""scripts/bench_compare.py: the engine against a baseline build, side by side (the figures
themselves are measured on purpose, never here; this checks that the comparison runs and refuses
what it cannot use)."""
import os
import pathlib
import subprocess
import sys

import pytest

SCRIPT = pathlib.Path(__file__).resolve().parents[2] / "scripts" / "bench_compare.py"


def compare(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True)


def test_a_missing_baseline_is_refused(tmp_path):
    result = compare("--baseline-bin", tmp_path / "nothing")
    assert result.returncode == 2
    assert "no such program" in result.stderr


def test_a_build_against_itself_prints_every_figure(build_dir, tmp_path):
    data = pathlib.Path(os.environ.get("CDRO_DATA_DIR", SCRIPT.parents[2] / "shared" / "data"))
    if not (data / "plant").is_dir():
        pytest.skip(f"no PLANT data at {data}")
    bench = build_dir / "bin" / "cdro-bench-engine"
    result = compare("--bin", bench, "--baseline-bin", bench, "--data-dir", data, "--pairs", "1", "--passes", "2",
                     "--json", tmp_path / "runs.json")
    assert result.returncode == 0, result.stderr
    rows = [line for line in result.stdout.splitlines() if line.startswith("| ") and "median" not in line]
    assert [row.split(" | ")[0] for row in rows] == ["| steady, per pass (ranges/s, wall)",
                                                    "| steady, all passes (ranges/CPU-s)",
                                                    "| first pass (ms CPU/range)"]
    assert (tmp_path / "runs.json").is_file()
