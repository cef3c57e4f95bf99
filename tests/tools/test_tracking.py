"""Moving nodes in 3D: the scorer (cdro_tools.evaluation.tracking, cdro-eval-motion
--tag-trajectory) on cases with a known answer."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from cdro_tools.evaluation import tracking

GUARD_S = 120


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
    assert "4 estimates" not in result.stdout
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
