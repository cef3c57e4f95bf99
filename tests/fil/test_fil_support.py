"""The helpers of the firmware-in-the-loop tests (fil_support.py): the scenario as cdro-fil reads
it, the world model's truth from it, the check of cdro-fil's truth file against that, and the
tools' alignment used the way the cdro-hostd test uses it. Only the native build is needed (no
AVR image)."""
from __future__ import annotations

import math
import pathlib
import random

import pytest

from cdro_tools.evaluation.alignment import align
from cdro_tools.simulation.scenario import ScenarioError, from_shared_view
from cdro_tools.simulation.world import World

from fil_support import fil_scenario, tag_ids, truth_disagreement_m

HERE = pathlib.Path(__file__).resolve().parent
OFFICE = HERE / "office_60s.yaml"


def test_the_scenario_is_what_cdro_fil_reads_with_the_runs_options(fil_binary):
    scenario = fil_scenario(fil_binary, OFFICE, ["--seed", "99", "--duration-s", "12.5"])
    assert (scenario.own_id, scenario.seed, scenario.duration_s) == (0x6000, 99, 12.5)
    assert scenario.remote_ids == [0x6A01, 0x6A02, 0x6A03, 0x6A04, 0x6B05, 0x6B06]
    assert tag_ids(scenario) == [0x6000, 0x6B05, 0x6B06]
    assert fil_scenario(fil_binary, OFFICE).seed == 20261122, "the file's seed without --seed"
    with pytest.raises(AssertionError, match="--print-scenario"):
        fil_scenario(fil_binary, HERE / "no-such-scenario.yaml")


def test_the_world_model_carries_the_node_as_the_file_says(fil_binary):
    world = World(fil_scenario(fil_binary, OFFICE))
    # 0x6B05 leaves (3.0, 5.5) at 24 s at 1 m/s for (6.5, 6.0), then (7.5, 3.0), at its 1.1 m.
    first_leg_m, second_leg_m = math.hypot(3.5, 0.5), math.hypot(1.0, 3.0)
    assert world.position(0x6B05, 24.0) == pytest.approx((3.0, 5.5, 1.1))
    assert world.position(0x6B05, 24.0 + 2.0) == pytest.approx((3.0 + 3.5 * 2.0 / first_leg_m,
                                                                5.5 + 0.5 * 2.0 / first_leg_m, 1.1))
    assert world.position(0x6B05, 24.0 + first_leg_m + second_leg_m) == pytest.approx((7.5, 3.0, 1.1))
    assert world.position(0x6B05, 64.0) == pytest.approx((7.5, 3.0, 1.1))
    assert world.position(0x6B06, 40.0) == pytest.approx((7.0, 1.5, 1.0))
    assert world.distance_m(0x6000, 0x6A01, 0.0) == pytest.approx(math.dist((1.0, 1.0, 0.8), (9.0, 0.5, 2.4)))


def test_a_truth_file_off_the_world_model_is_measured(fil_binary, tmp_path):
    world = World(fil_scenario(fil_binary, OFFICE))
    rows = ["t,id,x,y,z"]
    for t_s in (0.0, 26.0, 40.0):
        for node in (0x6000, 0x6B05):
            rows.append(f"{t_s:.3f},{node}," + ",".join(f"{v:.4f}" for v in world.position(node, t_s)))
    path = tmp_path / "truth.csv"
    path.write_text("\n".join(rows) + "\n")
    worst_m, samples = truth_disagreement_m(world, path)
    assert samples == 6 and worst_m <= 1e-4
    rows[4] = f"26.000,{0x6B05},9.0,9.0,1.1"  # 0x6B05 somewhere else at 26 s
    path.write_text("\n".join(rows) + "\n")
    worst_m, _ = truth_disagreement_m(world, path)
    assert worst_m == pytest.approx(math.dist((9.0, 9.0), world.position(0x6B05, 26.0)[:2]), abs=1e-3)


def test_a_waypoint_off_the_nodes_height_is_refused_by_the_world_model(fil_binary, tmp_path):
    path = tmp_path / "stairs.yaml"
    path.write_text("own_id: 0x6000\nnodes:\n  - {id: 0x6000, x_m: 0, y_m: 0}\n"
                    "  - {id: 0x6A01, x_m: 4, y_m: 0, z_m: 1}\n"
                    "motion:\n  - {node: 0x6A01, start_s: 1, speed_mps: 1, waypoints_m: [[4, 2, 3.5]]}\n")
    with pytest.raises(ScenarioError, match=r"motion\[0\]\.waypoints_m\[0\]: z 3.5 m is not the height of node 0x6A01"):
        fil_scenario(fil_binary, path)
    with pytest.raises(ScenarioError, match="not a shared scenario view"):
        from_shared_view({"nodes": []}, "test")


def test_the_alignment_the_hostd_test_uses_carries_a_point_outside_the_fit():
    # The still nodes fix the frame; the carried node, not among them, is compared in it.
    seed = 20261122
    print(f"seed {seed}")
    rng = random.Random(seed)
    truth = {i: (rng.uniform(0, 10), rng.uniform(0, 8)) for i in range(1, 8)}
    angle, tx, ty = rng.uniform(-math.pi, math.pi), rng.uniform(-5, 5), rng.uniform(-5, 5)
    c, s = math.cos(angle), math.sin(angle)
    mapped = {i: (c * x + s * y + tx, s * x - c * y + ty) for i, (x, y) in truth.items()}  # reflected
    still = {i: mapped[i] for i in range(1, 7)}
    fit = align(still, truth)
    assert fit.reflected and fit.nodes == 6 and fit.rmse_m == pytest.approx(0.0, abs=1e-9)
    assert fit.apply(mapped[7]) == pytest.approx(truth[7], abs=1e-9)
    moved = {**still, 3: (still[3][0] + 0.3, still[3][1])}  # one node 0.3 m off
    errors = align(moved, truth).errors_m  # the fit spreads the 0.3 m; node 3 keeps the most
    assert max(errors, key=errors.get) == 3 and 0.05 < errors[3] < 0.3
