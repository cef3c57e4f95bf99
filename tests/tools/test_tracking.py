"""Moving nodes in 3D: the scorer (cdro_tools.evaluation.tracking, cdro-eval-motion
--tag-trajectory) on cases with a known answer, the RTLS baselines
(cdro_tools.evaluation.tracking_baselines) on a seeded simulated flight, and, when the data is
there, scripts/miluv.py on the real MiLUV runs ($CDRO_DATA_DIR/miluv, else ../shared/data/miluv
from the repository root; skipped without it)."""
from __future__ import annotations

import json
import math
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from cdro_tools.evaluation import tracking
from cdro_tools.evaluation import tracking_baselines as tb

GUARD_S = 120
REPO = pathlib.Path(__file__).resolve().parents[2]


# ----------------------------------------------------------------------------- the scorer

def write_line_truth(path, ids=(10, 11), gap=(4.0, 4.5)):
    """Nodes flying along x at 1 m/s (node 11 1 m beside node 10), y = 2, z = 1, truth every 0.1 s
    from 0 to 10 s, with the rows strictly inside `gap` missing (a 0.5 s mocap dropout)."""
    lines = ["t,id,x,y,z"]
    for k in range(101):
        t = k / 10
        if gap[0] < t < gap[1]:
            continue
        for node in ids:
            lines.append(f"{t:.1f},{node},{t:.4f},{2.0 + (node - 10):.4f},1.0")
    path.write_text("\n".join(lines) + "\n")


def line_estimates(times_s, node, offset_m, hex_id=False):
    """Rows t,id,x,y,z on the truth of write_line_truth shifted by offset_m."""
    node_text = f"0x{node:x}" if hex_id else str(node)
    return [f"{t:.3f},{node_text},{t + offset_m[0]:.4f},{2.0 + (node - 10) + offset_m[1]:.4f},{1.0 + offset_m[2]:.4f}"
            for t in times_s]


def test_that_an_offset_estimate_scores_exactly_its_offset_and_gaps_are_skipped(tmp_path):
    # Fixture: estimates every 0.25 s between truth rows (interpolated), 0.3 m off in x and
    # 0.4 m in z: 3D error 0.5 m, horizontal 0.3 m; one at 4.25 s (inside the truth's gap) and
    # two outside the truth's span (-0.5 s, 10.5 s).
    truth, estimate = tmp_path / "truth.csv", tmp_path / "estimate.csv"
    write_line_truth(truth)
    inside = [0.125 + 0.25 * k for k in range(40) if not 4.0 < 0.125 + 0.25 * k < 4.5]
    estimate.write_text("\n".join(["t,id,x,y,z"] + line_estimates(inside + [4.25, -0.5, 10.5], 10, (0.3, 0.0, 0.4)))
                        + "\n")
    bad = []

    # Test
    report = tracking.evaluate_tracking(tracking.read_node_tracks(str(estimate), bad),
                                        tracking.read_node_tracks(str(truth), bad))

    # Assert
    assert not bad
    node = report["nodes"]["10"]
    assert node["points"] == len(inside) == 38
    assert node["across_gap"] == 1 and node["outside_truth"] == 2 and node["no_truth"] == 0
    for key, value in (("rmse_3d_m", 0.5), ("p95_3d_m", 0.5), ("max_3d_m", 0.5), ("rmse_h_m", 0.3), ("max_h_m", 0.3)):
        assert node[key] == pytest.approx(value, abs=1e-6), key
    assert report["overall"]["points"] == 38 and report["overall"]["across_gap"] == 1
    assert report["truth_nodes_without_estimates"] == [11]
    assert node["inside_95_h"] is None      # no covariance columns


def test_that_the_overall_figures_pool_the_nodes_and_a_node_without_truth_is_counted(tmp_path):
    truth, estimate = tmp_path / "truth.csv", tmp_path / "estimate.csv"
    write_line_truth(truth, gap=(20.0, 20.0))
    rows = (line_estimates([0.05 + 0.1 * k for k in range(30)], 10, (0.0, 0.1, 0.0))
            + line_estimates([0.05 + 0.1 * k for k in range(10)], 11, (0.0, 0.0, 0.7), hex_id=True)
            + ["1.0,99,0,0,0", "2.0,99,0,0,0"])
    estimate.write_text("\n".join(["t,id,x,y,z"] + rows) + "\n")
    bad = []

    report = tracking.evaluate_tracking(tracking.read_node_tracks(str(estimate), bad),
                                        tracking.read_node_tracks(str(truth), bad))

    assert not bad
    assert report["nodes"]["11"]["rmse_3d_m"] == pytest.approx(0.7, abs=1e-6)       # 0x0b read as node 11
    assert report["nodes"]["11"]["rmse_h_m"] == pytest.approx(0.0, abs=1e-6)
    overall = report["overall"]
    assert overall["points"] == 40 and overall["nodes"] == 2
    assert overall["rmse_3d_m"] == pytest.approx(math.sqrt((30 * 0.1 ** 2 + 10 * 0.7 ** 2) / 40), abs=1e-6)
    assert overall["max_3d_m"] == pytest.approx(0.7, abs=1e-6)
    assert overall["no_truth"] == 2 and report["nodes_without_truth"] == [99]


def test_that_align_takes_out_a_rigid_motion_with_a_reflection_and_the_anchored_score_does_not(tmp_path):
    # Fixture: a helix (not planar: a 3D fit is determined), and the estimate at the truth's
    # times in a frame rotated about z, mirrored in z and shifted.
    truth, estimate = tmp_path / "truth.csv", tmp_path / "estimate.csv"
    times = [0.1 * k for k in range(100)]
    helix = [np.array([2.0 * math.cos(t), 2.0 * math.sin(t), 0.5 + 0.1 * t]) for t in times]
    truth.write_text("t,id,x,y,z\n" + "".join(f"{t:.1f},7,{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}\n"
                                               for t, p in zip(times, helix)))
    angle = 0.7
    rotation = np.array([[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0],
                         [0.0, 0.0, -1.0]])
    moved = [rotation @ p + [5.0, -3.0, 2.0] for p in helix]
    estimate.write_text("t,id,x,y,z\n" + "".join(f"{t:.1f},7,{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}\n"
                                                  for t, p in zip(times, moved)))
    bad = []
    estimates, truths = tracking.read_node_tracks(str(estimate), bad), tracking.read_node_tracks(str(truth), bad)

    anchored = tracking.evaluate_tracking(estimates, truths)
    aligned = tracking.evaluate_tracking(estimates, truths, align=True)

    assert anchored["overall"]["rmse_3d_m"] > 1.0
    assert aligned["overall"]["rmse_3d_m"] < 1e-5 and aligned["overall"]["points"] == 100
    assert aligned["alignment"]["reflected"]
    assert np.allclose(np.array(aligned["alignment"]["rotation"]) @ rotation, np.eye(3), atol=1e-6)


def test_that_covariance_columns_give_the_share_inside_the_95_percent_region(tmp_path):
    truth, estimate = tmp_path / "truth.csv", tmp_path / "estimate.csv"
    write_line_truth(truth, gap=(20.0, 20.0))
    header = "t,id,x,y,z,var_x,cov_xy,var_y,var_z,cov_xz,cov_yz"
    # 0.3 m off in x: inside a 0.25 m sigma (NIS 1.44), outside a 0.1 m sigma (NIS 9)
    rows = [f"{r},0.0625,0,0.0625,0.0625,0,0" for r in line_estimates([0.5, 1.5, 2.5], 10, (0.3, 0.0, 0.0))]
    rows += [f"{r},0.01,0,0.01,0.01,0,0" for r in line_estimates([3.5], 10, (0.3, 0.0, 0.0))]
    estimate.write_text("\n".join([header] + rows) + "\n")
    bad = []

    report = tracking.evaluate_tracking(tracking.read_node_tracks(str(estimate), bad),
                                        tracking.read_node_tracks(str(truth), bad))

    assert not bad
    assert report["overall"]["inside_95_h"] == pytest.approx(0.75)
    assert report["overall"]["inside_95_3d"] == pytest.approx(0.75)


def test_that_bad_rows_are_counted_and_skipped(tmp_path):
    estimate = tmp_path / "estimate.csv"
    estimate.write_text("t,id,x,y,z,var_x,cov_xy,var_y\n1.0,10,0,0,0,0.1,0,0.1\n2.0,10,nan,0,0,0.1,0,0.1\n"
                        "3.0,10,0,0,0,0.1,0.5,0.1\n4.0,10,0,0,0,,,\n")
    bad = []

    tracks = tracking.read_node_tracks(str(estimate), bad)

    assert [b.line for b in bad] == [3, 4]
    assert list(tracks[10].t_s) == [1.0, 4.0]
    assert np.isnan(tracks[10].cov_m2[1]).all() and tracks[10].cov_m2[0][0, 0] == pytest.approx(0.1)


def test_the_command_line_round_trip(tmp_path):
    # Fixture: the trajectory written by write_trajectory (the baselines' writer), 0.2 m off in y
    truth, estimate, report_path = tmp_path / "truth.csv", tmp_path / "estimate.csv", tmp_path / "report.json"
    write_line_truth(truth)
    rows = [(0.05 + 0.1 * k, node, np.array([0.05 + 0.1 * k, 2.0 + (node - 10) + 0.2, 1.0]), 0.04 * np.eye(3))
            for k in range(99) for node in (10, 11)]
    tracking.write_trajectory(str(estimate), rows)

    # Test
    result = subprocess.run([sys.executable, "-m", "cdro_tools.eval_motion", "--tag-trajectory", str(estimate),
                             "--tag-truth", str(truth), "--json", str(report_path)],
                            check=False, capture_output=True, text=True, timeout=GUARD_S)

    # Assert
    assert result.returncode == 0, result.stderr
    assert "moving nodes (anchors' frame, no fit)" in result.stdout, result.stdout
    assert "across a truth gap" in result.stdout            # 4.05, 4.15, ..., 4.45 for both nodes
    tags = json.loads(report_path.read_text())["tags"]
    assert tags["overall"]["across_gap"] == 2 * 5 and tags["overall"]["points"] == 2 * 99 - 10
    for node in ("10", "11"):
        assert tags["nodes"][node]["rmse_3d_m"] == pytest.approx(0.2, abs=1e-4)
        assert tags["nodes"][node]["inside_95_h"] == 1.0        # 0.2 m against a 0.2 m sigma
    aligned = subprocess.run([sys.executable, "-m", "cdro_tools.eval_motion", "--tag-trajectory", str(estimate),
                              "--tag-truth", str(truth), "--align", "--json", "-"],
                             check=False, capture_output=True, text=True, timeout=GUARD_S)
    assert aligned.returncode == 0, aligned.stderr
    assert json.loads(aligned.stdout)["tags"]["overall"]["rmse_3d_m"] < 1e-3   # a shift: the fit takes it out


def test_that_the_command_line_exits_2_on_half_a_pair_or_a_missing_column(tmp_path):
    truth = tmp_path / "truth.csv"
    write_line_truth(truth)
    flat = tmp_path / "flat.csv"
    flat.write_text("t,id,x,y\n1.0,10,0,0\n")
    for args, message in ((["--tag-truth", str(truth)], "--tag-trajectory and --tag-truth go together"),
                          (["--tag-trajectory", str(flat), "--tag-truth", str(truth)], "missing column(s) z"),
                          (["--align"], "--align goes with --tag-trajectory")):
        result = subprocess.run([sys.executable, "-m", "cdro_tools.eval_motion", *args],
                                check=False, capture_output=True, text=True, timeout=GUARD_S)
        assert result.returncode == 2, (args, result.stderr)
        assert message in result.stderr, result.stderr


# ----------------------------------------------------------------------------- the baselines

ANCHORS_M = {0: (0.0, 0.0, 2.0), 1: (5.0, -0.5, 2.8), 2: (10.0, 0.0, 2.0), 3: (10.0, 8.0, 2.8), 4: (5.0, 8.5, 2.0),
             5: (0.0, 8.0, 2.8)}
# three tags flying straight at 0.6-0.75 m/s below the anchors: start (m), velocity (m/s)
TAGS = {10: ((1.0, 1.0, 0.5), (0.6, 0.45, 0.03)), 20: ((9.0, 1.5, 1.2), (-0.5, 0.5, -0.02)),
        30: ((5.0, 7.0, 0.8), (0.3, -0.6, 0.0))}
DURATION_S, RANGE_EVERY_S, NOISE_M = 12.0, 0.05, 0.1
SEED = 1


def true_position(tag: int, t_s: float) -> np.ndarray:
    start, velocity = TAGS[tag]
    return np.array(start) + t_s * np.array(velocity)


def simulate(seed: int, tag_tag: bool = True) -> tb.TimedRanges:
    """One range every 0.05 s, round robin over the 18 tag-anchor pairs and the 3 tag-tag pairs
    (each tag hears each anchor about once a second), Gaussian noise NOISE_M."""
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    pairs = [(t, a) for t in TAGS for a in ANCHORS_M] + ([(10, 20), (20, 30), (30, 10)] if tag_tag else [])
    rows = []
    for k in range(round(DURATION_S / RANGE_EVERY_S)):
        t_s = k * RANGE_EVERY_S
        a, b = pairs[k % len(pairs)]
        other = np.array(ANCHORS_M[b]) if b in ANCHORS_M else true_position(b, t_s)
        rows.append((t_s, a, b, float(np.linalg.norm(true_position(a, t_s) - other)) + NOISE_M * rng.standard_normal()))
    columns = list(zip(*rows))
    return tb.TimedRanges(np.array(columns[0]), np.array(columns[1]), np.array(columns[2]), np.array(columns[3]),
                          np.arange(len(rows)))


def anchors() -> dict[int, np.ndarray]:
    return {i: np.array(p, dtype=float) for i, p in ANCHORS_M.items()}


def truth_tracks() -> dict[int, tracking.NodeTrack]:
    times = np.arange(0.0, DURATION_S + 0.005, 0.01)
    return {tag: tracking.NodeTrack(times, np.array([true_position(tag, t) for t in times])) for tag in TAGS}


def score(result: tb.TrackingResult, keep: set | None = None) -> dict:
    """Overall figures of a baseline's rows (only the (t, id) in keep, when given)."""
    estimates = {}
    for tag in TAGS:
        rows = [r for r in result.rows if r[1] == tag and (keep is None or (r[0], tag) in keep)]
        estimates[tag] = tracking.NodeTrack(np.array([r[0] for r in rows]), np.array([r[2] for r in rows]),
                                            np.array([r[3] for r in rows]))
    return tracking.evaluate_tracking(estimates, truth_tracks())["overall"]


def test_that_the_baselines_track_a_simulated_flight_and_the_ekf_beats_trilateration():
    ranges = simulate(SEED)

    trilateration = score(tb.trilaterate(ranges, anchors()))
    ekf_result = tb.track_ekf(ranges, anchors())
    ekf = score(ekf_result)
    coop = score(tb.track_ekf(ranges, anchors(), cooperative=True))
    print({name: (round(s["rmse_3d_m"], 3), round(s["rmse_h_m"], 3)) for name, s in
           (("trilateration", trilateration), ("ekf", ekf), ("coop-ekf", coop))})

    # every tag has a row at (almost) every range it takes part in
    assert trilateration["points"] >= 0.9 * 18 * len(ranges) / 21 and ekf["points"] >= 0.9 * 18 * len(ranges) / 21
    # stated bounds (observed on seeds 1-15: trilateration 0.51-0.54 m, EKF 0.28-0.40 m, 3D)
    assert trilateration["rmse_3d_m"] < 0.6
    assert ekf["rmse_3d_m"] < 0.4 and ekf["rmse_h_m"] < 0.25
    assert coop["rmse_3d_m"] < 0.4 and coop["rmse_h_m"] < 0.25
    # the motion model is worth it: trilateration's ranges are up to a second old at 0.75 m/s
    assert ekf["rmse_3d_m"] < 0.8 * trilateration["rmse_3d_m"]
    assert ekf["rmse_h_m"] < 0.8 * trilateration["rmse_h_m"]
    # its covariance is not overconfident (q = 1 m^2/s^3 is generous for a straight flight)
    assert ekf["inside_95_3d"] > 0.9
    assert ekf_result.counts().get("rejected", 0) <= 3


def test_that_the_cooperative_ekf_is_no_worse_than_the_per_tag_ekf():
    # Compared at the same rows (the per-tag EKF's: after each tag-anchor range), over seeds 1-5
    # (one seed alone moves by +-0.05 m either way; observed mean difference -0.012 m).
    differences = []
    for seed in range(1, 6):
        ranges = simulate(seed)
        ekf = tb.track_ekf(ranges, anchors())
        coop = tb.track_ekf(ranges, anchors(), cooperative=True)
        keep = {(r[0], r[1]) for r in ekf.rows}
        differences.append(score(coop, keep)["rmse_3d_m"] - score(ekf)["rmse_3d_m"])
        assert coop.counts()["used"] > ekf.counts()["used"]     # it did take tag-tag ranges
    print([round(d, 3) for d in differences])
    assert np.mean(differences) <= 0.0


def test_that_the_joint_filter_without_tag_to_tag_ranges_is_the_per_tag_filter():
    ranges = simulate(SEED)
    joint = tb.track_ekf(ranges, anchors())
    for tag in TAGS:
        mine = ((ranges.from_ids == tag) & np.isin(ranges.to_ids, list(ANCHORS_M))) | (
            (ranges.to_ids == tag) & np.isin(ranges.from_ids, list(ANCHORS_M)))
        alone = tb.track_ekf(tb.TimedRanges(ranges.t_s[mine], ranges.from_ids[mine], ranges.to_ids[mine],
                                            ranges.range_m[mine], ranges.lines[mine]), anchors())
        rows = [r for r in joint.rows if r[1] == tag]
        assert len(rows) == len(alone.rows) > 60       # ~69 tag-anchor ranges each
        for a, b in zip(rows, alone.rows):
            assert a[0] == b[0]
            assert np.allclose(a[2], b[2], atol=1e-9) and np.allclose(a[3], b[3], atol=1e-9)


def test_that_trilateration_says_how_it_used_each_range():
    ranges = simulate(SEED, tag_tag=False)
    result = tb.trilaterate(ranges, anchors())
    counts = result.counts()
    assert len(result.status) == len(ranges)
    assert counts["fix"] + counts.get("fix_fixed_z", 0) == len(result.rows)
    assert counts["no_fix"] == 3 * 3                     # each tag's first three ranges: < 4 anchors


@pytest.mark.parametrize("below_anchors", [True, False])
def test_that_a_fix_on_the_mirror_side_of_coplanar_anchors_is_brought_below_them(below_anchors):
    # Anchors all at 2.0 m: a tag at 1.0 m and its mirror image at 3.0 m have the same ranges.
    # A solve started above them finds the mirror; the rule takes it back below.
    flat = {i: np.array([p[0], p[1], 2.0]) for i, p in ANCHORS_M.items()}
    true_p = np.array([4.0, 3.0, 1.0])
    fixer = tb._WindowFixer(flat, 2.0, 0.1, False, below_anchors)
    fixer.first_start_m = np.array([5.0, 4.0, 3.5])
    for k, (anchor, position) in enumerate(flat.items()):
        what, p, _ = fixer.add(0.01 * k, anchor, float(np.linalg.norm(true_p - position)))
    assert what == "fix"
    expected = true_p if below_anchors else true_p * [1, 1, -1] + [0, 0, 4.0]
    assert np.allclose(p, expected, atol=1e-5), p
    assert fixer.mirrored == (1 if below_anchors else 0)  # the first fix; the next ones start from it


def test_that_a_range_reading_far_long_is_rejected_by_the_gate():
    ranges = simulate(SEED, tag_tag=False)
    index = int(np.flatnonzero((ranges.from_ids == 10) & (ranges.to_ids == 3) & (ranges.t_s > 6.0))[0])
    ranges.range_m[index] += 2.0                          # NLOS: 2 m long
    result = tb.track_ekf(ranges, anchors())
    assert result.status[index] == "rejected"
    assert result.notes["rejected_by_tag"][10] >= 1
    huber = tb.track_ekf(ranges, anchors(), huber=True)
    assert huber.status[index] == "rejected"              # down-weighted, and counted the same way


def test_that_the_trajectory_file_holds_what_the_baseline_computed(tmp_path):
    result = tb.track_ekf(simulate(SEED), anchors(), cooperative=True)
    path = tmp_path / "coop.csv"
    tracking.write_trajectory(str(path), result.rows)
    bad = []
    tracks = tracking.read_node_tracks(str(path), bad)
    assert not bad and sorted(tracks) == sorted(TAGS)
    assert sum(len(t.t_s) for t in tracks.values()) == len(result.rows)
    last = [r for r in result.rows if r[1] == 20][-1]
    assert np.allclose(tracks[20].p_m[-1], last[2], atol=1e-4)
    assert np.allclose(tracks[20].cov_m2[-1], last[3], rtol=1e-5, atol=1e-9)


# ----------------------------------------------------------------------------- the real data

@pytest.fixture(scope="module")
def miluv(repo_root) -> pathlib.Path:
    data = pathlib.Path(os.environ.get("CDRO_DATA_DIR", repo_root.parent / "shared" / "data")) / "miluv"
    needed = [data / e / f for e in ("3robots_cirObstacles_random_0", "1robot_cirObstacles_random3_0")
              for f in ("ranges.csv", "ranges_detail.csv", "nodes.csv", "tag_truth.csv")]
    if not all(p.is_file() for p in needed):
        pytest.skip(f"MiLUV data not found at {data} (set CDRO_DATA_DIR to the folder that holds miluv/)")
    return data


def test_that_scripts_miluv_reproduces_the_recorded_figures(miluv, tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO / "tools") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    result = subprocess.run([sys.executable, str(REPO / "scripts" / "miluv.py"), "--data", str(miluv),
                             "--out", str(tmp_path)], check=False, capture_output=True, text=True, timeout=GUARD_S,
                            env=env)
    assert result.returncode == 0, result.stderr
    report = json.loads((tmp_path / "miluv.json").read_text())
    one = report["1robot_cirObstacles_random3_0"]["baselines"]
    three = report["3robots_cirObstacles_random_0"]["baselines"]
    # docs/results.md, "Moving nodes on real data: MiLUV" (horizontal RMSE, m; 0.02 m tolerance)
    assert one["trilateration"]["overall"]["rmse_h_m"] == pytest.approx(0.552, abs=0.02)
    assert one["ekf"]["overall"]["rmse_h_m"] == pytest.approx(1.426, abs=0.02)
    assert three["trilateration"]["overall"]["points"] == 12
    assert three["ekf"]["overall"]["rmse_h_m"] == pytest.approx(3.666, abs=0.02)
    assert three["coop-ekf"]["overall"]["rmse_h_m"] == pytest.approx(3.339, abs=0.02)
    for name in ("trilateration", "ekf", "coop-ekf"):
        assert (tmp_path / f"3robots_cirObstacles_random_0-{name}.csv").is_file()
    anchors_report = report["3robots_cirObstacles_random_0"]["anchors"]
    assert {a["anchor"] for a in anchors_report if a["obstructed"]} == {1, 3, 4}
    assert "| anchor |" in result.stdout
