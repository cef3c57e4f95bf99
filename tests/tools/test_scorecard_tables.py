"""scripts/scorecard.py's tables and options (the runs themselves are measured on purpose, never
here): a family run in file order only (walls, the largest) has no order spread, and its tables
still print; --netgen's options reach cdro-netgen."""
import importlib.util
import pathlib
import subprocess
import sys

SCRIPT = pathlib.Path(__file__).resolve().parents[2] / "scripts" / "scorecard.py"


def load_scorecard():
    spec = importlib.util.spec_from_file_location("scorecard", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run(rmse_m, converged, wrong, coverage):
    return {"rmse_m": rmse_m, "placed": 10, "nodes": 10, "converged": converged, "rmse_converged_m": rmse_m,
            "converged_wrong": wrong, "ellipse_coverage": coverage, "nees": 1.0, "unplaced": 0}


def row(family, seed, engine, order_spread):
    return {"family": family, "seed": seed, "heights": "known", "world": "", "nodes": 10, "links": 30,
            "engine": engine, "baselines": {"mds": 2.0, "lsq-huber": 1.25, "lsq-drop": 1.5}, "reference_m": 0.75,
            "order_spread": order_spread}


def test_a_family_in_file_order_only_says_so_instead_of_a_spread():
    scorecard = load_scorecard()
    walls = row("walls", 1, {"file": run(1.0, 4, 0, 0.5)}, None)
    random = row("random", 2, {"file": run(0.5, 8, 0, 1.0), "late": run(0.75, 6, 1, 0.5)}, 0.5)
    per_draw = scorecard.tables([random, walls]).splitlines()
    assert per_draw[2].endswith("| 0.75 | 0.50-0.75, 50 % |")
    assert per_draw[3] == ("| walls | 1 | 10 | 30 | 1.00 | 10 / 4 | 0 | 50 % | 2.00 | 1.25 | 1.50 | 0.75 | "
                           "file order only |")
    per_family = scorecard.summary([random, walls]).splitlines()
    assert per_family[2].endswith("| 14 | 1 | 79 % | 50 % / 50 % |")
    assert per_family[3].endswith("| 0 | 50 % | file order only |")


def test_the_netgen_options_reach_every_draw(tmp_path, build_dir):
    scorecard = load_scorecard()
    scorecard.BIN = build_dir / "bin"
    scorecard.NETGEN_OPTIONS[:] = ["--sweeps", "3"]
    network = scorecard.netgen("random", 5, tmp_path / "draw")
    links = len((network / "links.csv").read_text().splitlines()) - 1
    ranges = len((network / "ranges.csv").read_text().splitlines()) - 1
    assert links > 0
    assert ranges == 3 * links, "three sweeps over every link, as --netgen asked (the family's default is 20)"


def test_netgen_options_that_the_scorecard_sets_itself_are_refused():
    result = subprocess.run([sys.executable, str(SCRIPT), "--netgen=--seed 3", "--seeds", "1"],
                            capture_output=True, text=True)
    assert result.returncode == 2
    assert "--netgen may not set" in result.stderr
