"""cdro-hostd's offline 3D tracking of nodes that never stop, run as a user runs it:

    cdro-hostd --ranges-csv R --fixed-csv A --heights-csv H --moving 10,20 --out-csv N --out-trajectory T

- T has the documented columns, a row per range of a moving node once it heard four anchors,
  t non-decreasing, the covariance positive definite, the estimates near the truth of a seeded
  simulated flight (the engine's own test, tests/engine/test_motion_track_3d.cpp, states the
  bounds; here a loose one);
- bad input is refused with exit status 2, a message that names the problem, and no outputs:
  an id in --moving that has no range, a moving id that is also fixed (--fixed-csv) or has a
  known height, an id that is no node id, ranges without t, --moving without --out-trajectory,
  with the movement stage or with --trace-csv;
- the same input gives the same trajectory, byte for byte;
- --moving-body A:B:SEPARATION_M ties two moving nodes to one body; a malformed one, or one whose
  nodes are not in --moving, is refused;
- without --fixed-csv (the anchors' heights given) the anchors are calibrated from the tags' ranges
  (written to the log and --out-anchors), then the tags tracked: both near the truth after a rigid fit, the same
  input giving the same trajectory; without the heights either, in 3D; with fewer than 4 anchors
  it is refused by name;
- the per-anchor NLOS lines are in the log;
- the configuration's `calibration:` section (file or --set) reaches the calibration (its windows
  and iterations change), and a value out of range or a misspelt key is refused by name.

The binary is the native build's (CDRO_BUILD_DIR; default ./build). Seeded; CDRO_TEST_SEED
replays one."""
import csv
import math
import random
import re

import numpy as np
import pytest
import yaml
from offline_run import run, seed_of

TRAJECTORY_HEADER = "t,id,x,y,z,var_x,cov_xy,var_y,var_z,cov_xz,cov_yz"
ANCHORS = {1: (0.0, 0.0, 1.60), 2: (4.0, 0.0, 1.90), 3: (4.0, 4.0, 1.70), 4: (0.0, 4.0, 1.85),
           5: (2.0, -0.2, 1.75), 6: (2.0, 4.2, 1.65)}
TAGS = (10, 20)


def truth(k, t_s):
    phase = 1.7 * k
    return (2.0 + 1.3 * math.cos(0.45 * t_s + phase), 2.0 + 1.3 * math.sin(0.36 * t_s + phase),
            0.8 + 0.5 * math.sin(0.225 * t_s + phase))


def write_flight(folder, seed, duration_s=40.0):
    """ranges.csv (t,from,to,range_m: every 0.1 s a range, tags alternating over the anchors, every
    fifth a tag-to-tag one; noise 0.1 m), anchors.csv (id,x,y), heights.csv (id,z)."""
    rng = random.Random(seed)
    rows = ["t,from,to,range_m"]
    next_anchor = 0
    ids = sorted(ANCHORS)
    for slot in range(int(duration_s / 0.1)):
        t = slot * 0.1
        if slot % 5 == 4:
            d = math.dist(truth(0, t), truth(1, t))
            rows.append(f"{t:.3f},{TAGS[0]},{TAGS[1]},{d + rng.gauss(0, 0.1):.4f}")
            continue
        k = slot % 2
        a = ids[(next_anchor // 2) % len(ids)]
        next_anchor += 1
        d = math.dist(truth(k, t), ANCHORS[a])
        rows.append(f"{t:.3f},{TAGS[k]},{a},{d + rng.gauss(0, 0.1):.4f}")
    (folder / "ranges.csv").write_text("\n".join(rows) + "\n")
    (folder / "anchors.csv").write_text("id,x,y\n" + "".join(f"{i},{p[0]},{p[1]}\n" for i, p in ANCHORS.items()))
    (folder / "heights.csv").write_text("id,z\n" + "".join(f"{i},{p[2]}\n" for i, p in ANCHORS.items()))
    return folder


def moving_args(folder, moving="10,20", out="nodes.csv", trajectory="trajectory.csv"):
    return ["--ranges-csv", folder / "ranges.csv", "--fixed-csv", folder / "anchors.csv",
            "--heights-csv", folder / "heights.csv", "--moving", moving, "--out-csv", folder / out,
            "--out-trajectory", folder / trajectory]


def test_that_moving_writes_each_moving_nodes_3d_trajectory(hostd, tmp_path):
    folder = write_flight(tmp_path, seed_of(1))

    result = run(hostd, *moving_args(folder))

    assert result.returncode == 0, result.stderr
    assert "moving nodes tracked in 3D: 2 nodes" in result.stderr
    text = (folder / "trajectory.csv").read_text()
    assert text.split("\n", 1)[0] == TRAJECTORY_HEADER
    rows = list(csv.DictReader(text.splitlines()))
    ranges = list(csv.DictReader((folder / "ranges.csv").read_text().splitlines()))
    # A row per range of a moving node (two for a tag-to-tag range) once it heard 4 anchors: at
    # most that many, and all but the first few ranges of each tag.
    per_range = sum((r["from"] in ("10", "20")) + (r["to"] in ("10", "20")) for r in ranges)
    assert per_range - 20 <= len(rows) <= per_range
    assert {r["id"] for r in rows} == {"10", "20"}
    times = [float(r["t"]) for r in rows]
    assert times == sorted(times)
    errors = []
    for r in rows:
        cov = np.array([[float(r["var_x"]), float(r["cov_xy"]), float(r["cov_xz"])],
                        [float(r["cov_xy"]), float(r["var_y"]), float(r["cov_yz"])],
                        [float(r["cov_xz"]), float(r["cov_yz"]), float(r["var_z"])]])
        assert np.all(np.linalg.eigvalsh(cov) > 0.0), r
        t = float(r["t"])
        if t >= 10.0:
            p = np.array([float(r["x"]), float(r["y"]), float(r["z"])])
            errors.append(float(np.linalg.norm(p - truth(TAGS.index(int(r["id"])), t))))
    rmse = math.sqrt(sum(e * e for e in errors) / len(errors))
    print(f"RMSE 3D from 10 s: {rmse:.3f} m over {len(errors)} rows")
    assert rmse < 0.4
    # The moving nodes are not in NODES (not part of the static map; here nothing is: no range
    # between static nodes, so NODES is its header alone).
    nodes_text = (folder / "nodes.csv").read_text()
    assert nodes_text.startswith("id,x,y,")
    nodes = {r["id"] for r in csv.DictReader(nodes_text.splitlines())}
    assert not nodes & {"10", "20", "0x000A", "0x0014"}


def test_that_the_same_input_gives_the_same_trajectory(hostd, tmp_path):
    folder = write_flight(tmp_path, seed_of(2))
    first = run(hostd, *moving_args(folder, trajectory="a.csv"))
    second = run(hostd, *moving_args(folder, trajectory="b.csv"))
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    assert (folder / "a.csv").read_bytes() == (folder / "b.csv").read_bytes()


@pytest.mark.parametrize("moving, message", [
    ("10,20,99", "--moving: node 99 (0x0063) has no range in"),
    ("10,3", "--moving: node 3 is fixed: it cannot also be tracked as moving"),
    ("10,abc", "--moving: 'abc' is not a node id"),
    ("10,0", "--moving: '0' is not a node id"),
])
def test_that_a_bad_moving_list_is_refused_with_a_clear_message(hostd, tmp_path, moving, message):
    folder = write_flight(tmp_path, seed_of(3), duration_s=5.0)

    result = run(hostd, *moving_args(folder, moving=moving))

    assert result.returncode == 2
    assert message in result.stderr, result.stderr
    assert not (folder / "trajectory.csv").exists()
    assert not (folder / "nodes.csv").exists()


def test_that_a_moving_node_with_a_known_height_is_refused(hostd, tmp_path):
    folder = write_flight(tmp_path, seed_of(4), duration_s=5.0)
    with open(folder / "heights.csv", "a") as f:
        f.write("20,1.0\n")

    result = run(hostd, *moving_args(folder))

    assert result.returncode == 2
    assert "--moving: node 20 has a known height" in result.stderr, result.stderr
    assert not (folder / "trajectory.csv").exists()


def test_that_moving_needs_times_a_trajectory_and_no_movement_stage(hostd, tmp_path):
    folder = write_flight(tmp_path, seed_of(5), duration_s=5.0)
    untimed = tmp_path / "untimed"
    untimed.mkdir()
    for name in ("anchors.csv", "heights.csv"):
        (untimed / name).write_text((folder / name).read_text())
    lines = (folder / "ranges.csv").read_text().splitlines()[1:]
    (untimed / "ranges.csv").write_text("from,to,range_m\n"
                                        + "".join(",".join(line.split(",")[1:]) + "\n" for line in lines))

    no_time = run(hostd, *moving_args(untimed))
    no_trajectory = run(hostd, "--ranges-csv", folder / "ranges.csv", "--fixed-csv", folder / "anchors.csv",
                        "--heights-csv", folder / "heights.csv", "--moving", "10", "--out-csv", folder / "n.csv")
    with_odometry = run(hostd, *moving_args(folder), "--robot-id", "10")
    with_trace = run(hostd, *moving_args(folder), "--trace-csv", folder / "trace.csv")

    assert no_time.returncode == 2 and "--moving needs a t column in the ranges" in no_time.stderr, no_time.stderr
    assert no_trajectory.returncode == 2 and "--moving needs --out-trajectory" in no_trajectory.stderr
    assert with_odometry.returncode == 2 and "--moving is not for the movement stage" in with_odometry.stderr
    assert with_trace.returncode == 2 and "--trace-csv is not written with --moving" in with_trace.stderr
    assert not (folder / "trace.csv").exists()
    assert not (folder / "trajectory.csv").exists()


def test_that_moving_body_ties_two_moving_nodes_and_refuses_bad_input(hostd, tmp_path):
    folder = write_flight(tmp_path, seed_of(6), duration_s=10.0)

    good = run(hostd, *moving_args(folder), "--moving-body", "10:20:0.45")
    malformed = run(hostd, *moving_args(folder, trajectory="m.csv"), "--moving-body", "10:20")
    not_moving = run(hostd, *moving_args(folder, moving="10", trajectory="n.csv"), "--moving-body", "10:20:0.45")
    no_moving = run(hostd, "--ranges-csv", folder / "ranges.csv", "--out-csv", folder / "x.csv",
                    "--moving-body", "10:20:0.45")

    assert good.returncode == 0, good.stderr
    assert "one-body updates" in good.stderr and " 0 one-body updates" not in good.stderr
    assert malformed.returncode == 2 and "--moving-body: '10:20' is not A:B:SEPARATION_M" in malformed.stderr
    assert not_moving.returncode == 2 and "both must be in --moving" in not_moving.stderr, not_moving.stderr
    assert no_moving.returncode == 2 and "--moving-body needs --moving" in no_moving.stderr
    assert not (folder / "m.csv").exists() and not (folder / "n.csv").exists()


def calibrated_anchors(log):
    """The anchors cdro-hostd calibrated ("anchor N self-calibrated at x, y, z m (height ...)")."""
    out = {}
    for line in log.splitlines():
        if " self-calibrated at " in line:
            head, tail = line.split(" self-calibrated at ")
            out[int(head.split()[-1])] = np.array([float(v) for v in tail.split(" m ")[0].split(", ")])
    return out


def test_that_without_fixed_anchors_they_are_calibrated_then_the_tags_tracked(hostd, tmp_path):
    # Stated bounds (loose; the engine's test_moving_calibration.cpp states the calibration's own):
    # the anchors within 0.3 m RMSE after a rigid fit, the tracked tags within 0.6 m after one.
    from cdro_tools.evaluation import tracking
    from cdro_tools.evaluation.alignment import rigid_fit

    folder = write_flight(tmp_path, seed_of(7), duration_s=60.0)
    args = [a for a in moving_args(folder) if a not in ("--fixed-csv", folder / "anchors.csv")]

    result = run(hostd, *args, "--out-anchors", folder / "anchors-out.csv")
    again = run(hostd, *args[:-1], folder / "again.csv")
    given = run(hostd, *moving_args(folder, trajectory="given.csv"), "--out-anchors", folder / "given-anchors.csv")

    assert result.returncode == 0 and again.returncode == 0, result.stderr + again.stderr
    assert (folder / "trajectory.csv").read_bytes() == (folder / "again.csv").read_bytes()
    anchors = calibrated_anchors(result.stderr)
    assert sorted(anchors) == sorted(ANCHORS)
    assert "(height given)" in result.stderr and "anchors calibrated from the moving nodes' ranges" in result.stderr
    for i, p in anchors.items():
        assert p[2] == pytest.approx(ANCHORS[i][2], abs=1e-6)  # the heights given are held
    written = {int(r["id"]): r for r in csv.DictReader((folder / "anchors-out.csv").read_text().splitlines())}
    assert sorted(written) == sorted(anchors)
    for i, r in written.items():
        assert np.allclose([float(r["x"]), float(r["y"]), float(r["z"])], anchors[i], atol=1e-5)
        assert r["height_given"] == "1"
    assert given.returncode == 2 and "--out-anchors is written when the anchors are calibrated" in given.stderr
    assert not (folder / "given-anchors.csv").exists()
    ids = sorted(anchors)
    estimate, truth_m = np.array([anchors[i] for i in ids]), np.array([ANCHORS[i] for i in ids])
    rotation, translation = rigid_fit(estimate, truth_m, dim=3)
    anchor_rmse = float(np.sqrt(np.mean(np.sum((estimate @ rotation.T + translation - truth_m) ** 2, axis=1))))
    rows = list(csv.DictReader((folder / "trajectory.csv").read_text().splitlines()))
    tracks, truths = {}, {}
    for k, tag in enumerate(TAGS):
        mine = [r for r in rows if int(r["id"]) == tag]
        tracks[tag] = tracking.NodeTrack(np.array([float(r["t"]) for r in mine]),
                                         np.array([[float(r[c]) for c in "xyz"] for r in mine]))
        grid = np.arange(0.0, 60.0, 0.05)
        truths[tag] = tracking.NodeTrack(grid, np.array([truth(k, t) for t in grid]))
    tag_rmse = tracking.evaluate_tracking(tracks, truths, align=True)["overall"]["rmse_3d_m"]
    print(f"anchors' aligned RMSE {anchor_rmse:.3f} m, tags' aligned RMSE 3D {tag_rmse:.3f} m ({len(rows)} rows)")
    assert anchor_rmse < 0.3
    assert tag_rmse < 0.6
    for i in ANCHORS:
        assert f"NLOS ranges to anchor {i}: " in result.stderr
    assert "NLOS ranges between moving nodes: " in result.stderr


def test_that_without_heights_either_the_anchors_are_calibrated_in_3d(hostd, tmp_path):
    # No --fixed-csv, no --heights-csv: the anchors' heights are estimated too (their plane put
    # at 1.8 m). Stated: the anchors within 0.4 m 3D RMSE after a rigid fit (loose).
    from cdro_tools.evaluation.alignment import rigid_fit

    folder = write_flight(tmp_path, seed_of(9), duration_s=60.0)
    result = run(hostd, "--ranges-csv", folder / "ranges.csv", "--moving", "10,20", "--out-csv", folder / "n.csv",
                 "--out-trajectory", folder / "trajectory.csv")

    assert result.returncode == 0, result.stderr
    assert "(height estimated)" in result.stderr and "(height given)" not in result.stderr
    anchors = calibrated_anchors(result.stderr)
    ids = sorted(anchors)
    assert ids == sorted(ANCHORS)
    estimate, truth_m = np.array([anchors[i] for i in ids]), np.array([ANCHORS[i] for i in ids])
    rotation, translation = rigid_fit(estimate, truth_m, dim=3)
    rmse = float(np.sqrt(np.mean(np.sum((estimate @ rotation.T + translation - truth_m) ** 2, axis=1))))
    print(f"anchors' aligned RMSE 3D without heights {rmse:.3f} m")
    assert rmse < 0.4
    assert len((folder / "trajectory.csv").read_text().splitlines()) > 100


def test_that_calibration_with_three_anchors_is_refused_by_name(hostd, tmp_path):
    folder = write_flight(tmp_path, seed_of(8), duration_s=10.0)
    lines = (folder / "ranges.csv").read_text().splitlines()
    kept = [line for line in lines[1:] if line.split(",")[2] in ("1", "2", "3", "20")]
    (folder / "ranges.csv").write_text(lines[0] + "\n" + "\n".join(kept) + "\n")
    args = [a for a in moving_args(folder) if a not in ("--fixed-csv", folder / "anchors.csv")]

    result = run(hostd, *args)

    assert result.returncode == 2
    assert "--moving without --fixed-csv: calibrating anchors from moving nodes needs at least 4" in result.stderr
    assert not (folder / "trajectory.csv").exists()
    no_moving = run(hostd, "--ranges-csv", folder / "ranges.csv", "--out-csv", folder / "x.csv",
                    "--out-anchors", folder / "a.csv")
    assert no_moving.returncode == 2 and "--out-anchors needs --moving" in no_moving.stderr
    assert not (folder / "a.csv").exists()


CALIBRATION_SUMMARY = re.compile(r"(\d+) windows \(\d+ placed by the MDS\), \d+ epochs; (\d+) \+ (\d+) iterations")


def calibration_summary(log):
    """(windows, static iterations, batch iterations) of the calibration's summary line."""
    found = CALIBRATION_SUMMARY.search(log)
    assert found, log
    return tuple(int(v) for v in found.groups())


def test_that_the_calibration_section_reaches_the_calibration_and_bad_values_are_refused(hostd, tmp_path):
    folder = write_flight(tmp_path, seed_of(10), duration_s=30.0)
    args = [a for a in moving_args(folder) if a not in ("--fixed-csv", folder / "anchors.csv")]
    config = tmp_path / "calibration.yaml"
    config.write_text("calibration:\n  window_s: 2\n")

    default = run(hostd, *args[:-1], folder / "default.csv")
    short_windows = run(hostd, *args[:-1], folder / "w2.csv", "--set", "calibration.window_s=2")
    from_file = run(hostd, *args[:-1], folder / "w2-file.csv", "--config", config)
    few_iterations = run(hostd, *args[:-1], folder / "it1.csv", "--set", "calibration.max_iterations=1")
    zero_window = run(hostd, *args[:-1], folder / "zero.csv", "--set", "calibration.window_s=0")
    bad_huber = run(hostd, *args[:-1], folder / "huber.csv", "--set", "calibration.huber_sigmas=-1")
    misspelt = run(hostd, *args[:-1], folder / "typo.csv", "--set", "calibration.windows_s=2")
    printed = run(hostd, "--print-config", "--set", "engine.range.sigma_m=0.2", "--set", "calibration.window_s=3")

    for result in (default, short_windows, from_file, few_iterations):
        assert result.returncode == 0, result.stderr
    windows, static_iterations, batch_iterations = calibration_summary(default.stderr)
    print(f"default: {windows} windows, {static_iterations} + {batch_iterations} iterations")
    # 30 s of two tags in 4 s windows, then in 2 s windows: about twice as many.
    assert calibration_summary(short_windows.stderr)[0] > 1.5 * windows
    assert (folder / "w2.csv").read_bytes() == (folder / "w2-file.csv").read_bytes()
    assert (folder / "w2.csv").read_bytes() != (folder / "default.csv").read_bytes()
    assert static_iterations + batch_iterations > 2
    _, few_static, few_batch = calibration_summary(few_iterations.stderr)
    assert few_static + few_batch < static_iterations + batch_iterations
    assert zero_window.returncode == 2
    assert "calibration.window_s: must be between 0.001 and" in zero_window.stderr, zero_window.stderr
    assert bad_huber.returncode == 2 and "calibration.huber_sigmas: must be between" in bad_huber.stderr
    assert misspelt.returncode == 2 and "unknown key 'windows_s'" in misspelt.stderr, misspelt.stderr
    for name in ("zero.csv", "huber.csv", "typo.csv"):
        assert not (folder / name).exists()
    assert printed.returncode == 0, printed.stderr
    section = yaml.safe_load(printed.stdout)["calibration"]
    # range_sigma_m follows engine.range.sigma_m unless set.
    assert section == {"window_s": 3, "range_sigma_m": 0.2, "huber_sigmas": 2, "max_iterations": 1000,
                       "unknown_plane_height_m": 1.8}
