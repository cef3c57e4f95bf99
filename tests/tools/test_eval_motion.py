"""cdro-eval-motion's path figures (cdro_tools.evaluation.movement): the trajectory's `frame`
column, which says whether a row is dead reckoning in the odometry's frame (before a map
existed) or in the map's, and which rows the rigid fit takes."""

import json
import math
import subprocess
import sys

import pytest

from cdro_tools.evaluation.movement import evaluate_path, last_frame_rows, read_path

HEADER = "t,x,y,heading_rad,var_x,cov_xy,var_y,frame"


def write_truth(path, times_s):
    """A robot driving along y = 2 at 1 m/s from x = 0."""
    path.write_text("t,x,y,heading_rad\n" + "".join(f"{t:.1f},{t:.4f},2.0,0.0\n" for t in times_s))


def trajectory_rows(times_s, frame, offset_m=(0.0, 0.0), noise_m=0.0):
    """Rows on the truth of write_truth, in the map's frame shifted by offset_m, with an
    alternating lateral error of noise_m."""
    rows = []
    for k, t in enumerate(times_s):
        y = 2.0 + offset_m[1] + (noise_m if k % 2 else -noise_m)
        rows.append(f"{t:.1f},{t + offset_m[0]:.4f},{y:.4f},0.0,0.01,0.0,0.01,{frame}")
    return rows


def stood_then_drove(tmp_path, rows, standing, noise_m):
    """A truth of `rows` times, and a trajectory whose first `standing` rows are dead reckoning at
    the odometry's origin (the map's frame is 7 m away), the rest in the map's frame, noise_m off
    the truth. Returns (truth, trajectory)."""
    times_s = [0.1 * k for k in range(rows)]
    truth, trajectory = tmp_path / "truth.csv", tmp_path / "trajectory.csv"
    write_truth(truth, times_s)
    odometry = [f"{t:.1f},0.0,0.0,0.0,0.0,0.0,0.0,odometry" for t in times_s[:standing]]
    map_rows = trajectory_rows(times_s[standing:], "map", noise_m=noise_m)
    trajectory.write_text("\n".join([HEADER] + odometry + map_rows) + "\n")
    return truth, trajectory


def test_that_only_the_rows_in_the_final_frame_are_fitted(tmp_path):
    # Fixture: 20 rows of dead reckoning, then 80 rows in the map's frame, 5 cm off the truth.
    truth, trajectory = stood_then_drove(tmp_path, 100, 20, noise_m=0.05)
    bad = []

    # Test
    estimate = read_path(str(trajectory), bad)
    kept, dropped = last_frame_rows(estimate)
    report = evaluate_path(estimate, read_path(str(truth), bad))["report"]

    # Assert
    assert not bad
    assert estimate.frames[:20] == ["odometry"] * 20 and estimate.frames[20:] == ["map"] * 80
    assert dropped == 20 and len(kept.t_s) == 80 and kept.t_s[0] == pytest.approx(2.0)
    assert report["points"] == 80 and report["other_frame_points"] == 20
    assert report["frame"] == "map" and report["frame_from_s"] == pytest.approx(2.0)
    assert report["rmse_m"] == pytest.approx(0.05, abs=0.005)


def test_that_all_rows_count_when_the_trajectory_has_one_frame_or_no_frame_column(tmp_path):
    times_s = [0.1 * k for k in range(50)]
    truth = tmp_path / "truth.csv"
    write_truth(truth, times_s)
    for name, header, rows in (("one-frame", HEADER, trajectory_rows(times_s, "odometry", offset_m=(3.0, -1.0))),
                               ("old-format", HEADER.rsplit(",", 1)[0],
                                [r.rsplit(",", 1)[0] for r in trajectory_rows(times_s, "map", offset_m=(3.0, -1.0))])):
        trajectory = tmp_path / f"{name}.csv"
        trajectory.write_text("\n".join([header] + rows) + "\n")
        bad = []
        report = evaluate_path(read_path(str(trajectory), bad), read_path(str(truth), bad))["report"]
        assert not bad, name
        assert report["points"] == 50 and report["other_frame_points"] == 0, name
        assert report["frame_from_s"] is None, name
        assert report["rmse_m"] < 1e-6, name  # a pure translation: the fit takes it out
    assert report["frame"] is None  # the old format says no frame


def test_that_a_row_with_an_unknown_frame_is_a_bad_row(tmp_path):
    times_s = [0.1 * k for k in range(10)]
    rows = trajectory_rows(times_s, "map")
    rows[4] = rows[4].rsplit(",", 1)[0] + ",world"
    trajectory = tmp_path / "trajectory.csv"
    trajectory.write_text("\n".join([HEADER] + rows) + "\n")
    bad = []

    estimate = read_path(str(trajectory), bad)

    assert len(estimate.t_s) == 9 and len(estimate.frames) == 9
    assert len(bad) == 1 and bad[0].line == 6 and "frame 'world' is not one of odometry, map" in bad[0].reason


def test_the_command_line_names_the_rows_left_out(tmp_path):
    truth, trajectory = stood_then_drove(tmp_path, 60, 15, noise_m=0.1)
    report_path = tmp_path / "report.json"

    result = subprocess.run([sys.executable, "-m", "cdro_tools.eval_motion", "--trajectory", str(trajectory),
                             "--robot-truth", str(truth), "--json", str(report_path)],
                            capture_output=True, text=True)

    assert result.returncode == 0, result.stderr
    assert "15 earlier poses are in another frame" in result.stdout, result.stdout
    assert "the map frame starts at t = 1.500 s" in result.stdout, result.stdout
    path = json.loads(report_path.read_text())["path"]
    assert path["points"] == 45 and path["other_frame_points"] == 15
    assert math.isclose(path["rmse_m"], 0.1, abs_tol=0.01)


def carried_node_files(tmp_path, statuses):
    """Node 6 carried along y = 0 at 1 m/s from t = 10 s to t = 14 s among still nodes 1-3 (all
    placed where they are), and a trace with one row of node 6 every 0.1 s from t = 9 s to 16 s
    whose status is statuses(t). Returns the cdro-eval-motion arguments."""
    truth = tmp_path / "truth.csv"
    truth.write_text("id,x,y,z\n1,0,5,0\n2,8,5,0\n3,4,-6,0\n6,0,0,0\n")
    tracks = tmp_path / "tracks.csv"
    tracks.write_text("t,id,x,y\n" + "".join(f"{t / 10:.1f},6,{min(max(t / 10 - 10, 0), 4):.2f},0\n"
                                             for t in range(0, 200)))
    motion = tmp_path / "motion.csv"
    motion.write_text("t,id,moving\n0,6,0\n10,6,1\n14,6,0\n")
    rows = []
    for k in range(90, 160):
        t = k / 10
        x = min(max(t - 10, 0), 4)
        for node, (nx, ny) in {1: (0, 5), 2: (8, 5), 3: (4, -6)}.items():
            rows.append(f"{k},{node},{nx},{ny},1,converged,{t:.1f}")
        status = statuses(t)
        rows.append(f"{k},6,{x:.2f},0,{1 if status == 'converged' else 0},{status},{t:.1f}")
    trace = tmp_path / "trace.csv"
    trace.write_text("ranges,id,x,y,converged,status,t\n" + "\n".join(rows) + "\n")
    return ["--trace", str(trace), "--tracks", str(tracks), "--truth", str(truth), "--motion", str(motion),
            "--node", "6", "--json", "-"]


def eval_track(args):
    result = subprocess.run([sys.executable, "-m", "cdro_tools.eval_motion", *args], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)["track"]


def test_the_track_says_how_late_the_start_and_the_stop_were_seen(tmp_path):
    def statuses(t):
        if 10.5 <= t < 15.2:
            return "moving"
        return "settling" if 15.2 <= t < 15.5 else ("placed" if 15.5 <= t < 15.8 else "converged")

    track = eval_track(carried_node_files(tmp_path, statuses))
    assert track["start_seen_after_s"] == [pytest.approx(0.5)]
    assert track["stop_seen_after_s"] == [pytest.approx(1.2)]  # settling counts: no longer moving
    assert track["reconverged_after_s"] == [pytest.approx(1.8)]
    assert track["rmse_m"] == pytest.approx(0.0, abs=1e-9)


def test_a_motion_never_seen_has_no_start_and_no_stop(tmp_path):
    track = eval_track(carried_node_files(tmp_path, lambda t: "converged"))
    assert track["start_seen_after_s"] == [None]
    assert track["stop_seen_after_s"] == [None]  # never seen moving: no stop to see either
