"""cdro-eval's baselines on the real PLANT network reproduce the reference figures of the
data README (shared/data/README.md: 28 nodes, heights known, rigid alignment with
reflection). The data is not part of this repository: it is looked for at ../shared/data
from the repository root, or at $CDRO_DATA_DIR; the test is skipped without it."""
import json
import os
import pathlib
import subprocess
import sys

import pytest

GUARD_S = 60
# data README figure (m), and the tolerance held to (m)
REFERENCE_M = {"mds": (2.83, 0.05), "lsq-huber": (0.51, 0.05), "lsq-drop": (0.39, 0.05)}
CRB_PER_LINK_M = (0.16, 0.01)


@pytest.fixture(scope="module")
def plant(repo_root) -> pathlib.Path:
    data = pathlib.Path(os.environ.get("CDRO_DATA_DIR", repo_root.parent / "shared" / "data"))
    plant = data / "plant"
    if not (plant / "ranges.csv").is_file() or not (plant / "nodes.csv").is_file():
        pytest.skip(f"PLANT data not found at {plant} (set CDRO_DATA_DIR to the folder that holds plant/)")
    return plant


def evaluate(plant, *extra):
    result = subprocess.run([sys.executable, "-m", "cdro_tools.eval", "--truth", plant / "nodes.csv", "--ranges",
                             plant / "ranges.csv", "--heights-from-truth", "--json", "-", *extra],
                            capture_output=True, text=True, timeout=GUARD_S)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_that_the_baselines_reproduce_the_plant_reference_figures(plant):
    report = evaluate(plant, "--crb-per-link")
    print({name: report["methods"][name]["rmse_m"] for name in REFERENCE_M}, report["crb"]["rmse_m"])
    ranges = report["ranges"]
    assert (ranges["used"], ranges["links"], ranges["nodes"]) == (1205, 105, 28)
    assert (ranges["projected"], ranges["clamped"], ranges["bad_rows"]) == (1205, 0, 0)
    for name, (figure_m, tolerance_m) in REFERENCE_M.items():
        method = report["methods"][name]
        assert method["nodes"] == 28, name
        assert method["rmse_m"] == pytest.approx(figure_m, abs=tolerance_m), name
    assert len(report["methods"]["lsq-drop"]["dropped_links"]) == 7       # "7 links have a median error above 1 m"
    crb = report["crb"]
    assert crb["per"] == "link" and crb["entries"] == 105 and crb["rigid"]
    assert crb["rmse_m"] == pytest.approx(CRB_PER_LINK_M[0], abs=CRB_PER_LINK_M[1])


def test_that_the_plant_bound_per_range_is_below_the_bound_per_link(plant):
    # 1205 ranges on 105 links: counting every range as independent lowers the bound by about
    # sqrt(1205 / 105) = 3.4 (not exactly: the links do not all have the same count)
    report = evaluate(plant, "--baselines", "crb")
    assert report["crb"]["per"] == "range" and report["crb"]["entries"] == 1205
    assert 0.16 / 4.5 < report["crb"]["rmse_m"] < 0.16 / 2.5
