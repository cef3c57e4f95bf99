"""cdro-plot: the rigid alignment, the RMSE numbers it prints, and the PNGs it writes."""
import json
import math
import random
import subprocess
import sys

import numpy as np
import pytest

from cdro_tools.plot import rigid_fit

GUARD_S = 60
SQUARE = {0x6001: (0.0, 0.0), 0x6002: (10.0, 0.0), 0x6003: (10.0, 10.0), 0x6004: (0.0, 10.0), 0x6005: (5.0, 5.0)}


def plot(*args):
    return subprocess.run([sys.executable, "-m", "cdro_tools.plot", *map(str, args)], capture_output=True, text=True,
                          timeout=GUARD_S)


def engine_frame(x, y):
    """The engine's own frame: reflected, rotated by 0.7 rad, shifted."""
    c, s = math.cos(0.7), math.sin(0.7)
    y = -y
    return c * x - s * y + 3.0, s * x + c * y - 1.0


def write_truth(path, nodes):
    path.write_text("id,x,y,z\n" + "".join(f"{i},{x},{y},1.0\n" for i, (x, y) in nodes.items()))


def node_line(t, node_id, x, y, var=0.01):
    ex, ey = engine_frame(x, y)
    return json.dumps({"type": "node", "t_s": t, "id": node_id, "x_m": ex, "y_m": ey, "var_x_m2": var,
                       "cov_xy_m2": var / 3, "var_y_m2": var / 2, "converged": t > 5, "moving": False, "placed": True})


def assert_png(path, width, height):
    import matplotlib.image
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(path)
    assert image.shape[:2] == (height, width)
    drawn = (image[..., :3] < 0.9).any(axis=2).mean()
    assert drawn > 0.005                                                          # not blank


def test_that_the_rigid_fit_recovers_a_reflection_a_rotation_and_a_shift():
    seed = 31
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    truth = rng.uniform(-10, 10, size=(8, 2))
    moved = np.array([engine_frame(*p) for p in truth])
    rotation, translation = rigid_fit(moved, truth)
    assert np.allclose(moved @ rotation.T + translation, truth, atol=1e-9)
    assert np.linalg.det(rotation) == pytest.approx(-1.0)
    rotation, translation = rigid_fit(truth, truth + [1.0, 2.0])
    assert np.allclose(rotation, np.eye(2)) and np.allclose(translation, [1.0, 2.0])


def test_that_the_aligned_rmse_is_the_error_a_rigid_motion_cannot_remove(tmp_path):
    # Fixture: estimates converge from 1 m to an outward 0.2 m error at the corners (a scale error,
    # which no rotation, reflection or shift removes), in the engine's frame; one bad line
    write_truth(tmp_path / "truth.csv", SQUARE)
    lines = []
    for k in range(21):
        t = k * 0.5
        for node_id, (x, y) in SQUARE.items():
            error = 0.2 + 0.8 * max(0.0, 1 - t / 5)
            dx, dy = x - 5.0, y - 5.0
            norm = math.hypot(dx, dy) or 1.0
            corner = 0.0 if node_id == 0x6005 else 1.0
            lines.append(node_line(t, node_id, x + corner * error * dx / norm, y + corner * error * dy / norm))
    lines.append("{not json")
    (tmp_path / "est.jsonl").write_text("\n".join(lines) + "\n")

    # Test
    result = plot(tmp_path / "est.jsonl", "--truth", tmp_path / "truth.csv", "--map", tmp_path / "map.png", "--rmse",
                  tmp_path / "rmse.png")

    # Assert
    assert result.returncode == 0, result.stderr
    numbers = json.loads(result.stdout)
    assert numbers["rmse_m"] == pytest.approx(math.sqrt(4 * 0.2 ** 2 / 5), abs=1e-6)
    assert numbers["per_node_error_m"]["0x6005"] == pytest.approx(0.0, abs=1e-6)
    assert numbers["reflected"] is True and numbers["nodes"] == 5
    assert numbers["rmse_over_time"]["points"] == 21
    assert numbers["rmse_over_time"]["first_m"] == pytest.approx(math.sqrt(4 * 1.0 ** 2 / 5), abs=1e-6)
    assert "dropped 1 line(s) that cannot be used: not JSON" in result.stderr
    assert_png(tmp_path / "map.png", 800, 700)
    assert_png(tmp_path / "rmse.png", 800, 400)


def test_that_simulator_truth_tracks_and_links_are_drawn_for_a_moving_node(tmp_path):
    # Fixture: the demo's truth, and estimates that follow it exactly (in the engine's frame)
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--duration", "40", "--truth-csv",
                    tmp_path / "truth.csv", "--tracks-csv", tmp_path / "tracks.csv", "--ranges-csv",
                    tmp_path / "ranges.csv"], check=True, capture_output=True, timeout=GUARD_S)
    truth = {}
    for row in (tmp_path / "truth.csv").read_text().splitlines()[1:]:
        i, x, y, _ = row.split(",")
        truth[int(i)] = (float(x), float(y))
    track = {}
    for row in (tmp_path / "tracks.csv").read_text().splitlines()[1:]:
        t, i, x, y = row.split(",")
        track[round(float(t), 1)] = (float(x), float(y))
    lines = []
    for k in range(0, 400, 5):
        t = k / 10
        for node_id, xy in truth.items():
            if node_id == 0x6006:
                xy = track[round(t, 1)]
            lines.append(node_line(t, node_id, *xy))
    lines.append(json.dumps({"type": "health", "t_s": 1.0, "link": "connected", "counters": {}}))
    (tmp_path / "est.jsonl").write_text("\n".join(lines) + "\n")

    # Test
    result = plot(tmp_path / "est.jsonl", "--truth", tmp_path / "truth.csv", "--tracks", tmp_path / "tracks.csv",
                  "--ranges", tmp_path / "ranges.csv", "--map", tmp_path / "map.png", "--rmse", tmp_path / "rmse.png")

    # Assert: the moving node is compared with its track, so everything aligns exactly
    assert result.returncode == 0, result.stderr
    numbers = json.loads(result.stdout)
    assert numbers["rmse_m"] == pytest.approx(0.0, abs=1e-6) and numbers["nodes_with_truth"] == 7
    assert numbers["rmse_over_time"]["last_m"] == pytest.approx(0.0, abs=1e-6)
    assert "dropped" not in result.stderr
    assert_png(tmp_path / "map.png", 800, 700)


def test_that_an_offline_nodes_csv_and_trajectory_give_a_robot_error(tmp_path):
    seed = 33
    print(f"seed {seed}")
    rng = random.Random(seed)
    write_truth(tmp_path / "truth.csv", SQUARE)
    rows = ["id,x,y,var_x,cov_xy,var_y,converged"]
    for node_id, (x, y) in SQUARE.items():
        rows.append(f"{node_id},{x + rng.gauss(0, 0.05)},{y + rng.gauss(0, 0.05)},0.01,0.0,0.02,1")
    (tmp_path / "nodes.csv").write_text("\n".join(rows) + "\n")
    tracks = ["t,id,x,y"] + [f"{t},24592,{t},{2.0}" for t in range(11)]
    (tmp_path / "tracks.csv").write_text("\n".join(tracks) + "\n")
    trajectory = ["t,x,y,heading_rad,var_x,cov_xy,var_y"] + [f"{t},{t},{2.3},0,0.01,0,0.01" for t in range(11)]
    (tmp_path / "trajectory.csv").write_text("\n".join(trajectory) + "\n")

    result = plot(tmp_path / "nodes.csv", "--trajectory", tmp_path / "trajectory.csv", "--robot-id", "0x6010",
                  "--truth", tmp_path / "truth.csv", "--tracks", tmp_path / "tracks.csv", "--map", tmp_path / "map.png",
                  "--rmse", tmp_path / "rmse.png")

    assert result.returncode == 0, result.stderr
    numbers = json.loads(result.stdout)
    assert numbers["robot_rmse_m"] == pytest.approx(0.3, abs=0.1)
    assert numbers["rmse_m"] < 0.1
    assert_png(tmp_path / "rmse.png", 800, 400)

    # The same trajectory with a frame column, after rows of dead reckoning in the odometry's
    # frame (the robot stood while the map formed): those are left out, and said so.
    framed = (["t,x,y,heading_rad,var_x,cov_xy,var_y,frame"] + [f"{t - 5},-40,-40,0,0,0,0,odometry" for t in range(5)]
              + [f"{t},{t},{2.3},0,0.01,0,0.01,map" for t in range(11)])
    (tmp_path / "framed.csv").write_text("\n".join(framed) + "\n")
    result = plot(tmp_path / "nodes.csv", "--trajectory", tmp_path / "framed.csv", "--robot-id", "0x6010",
                  "--truth", tmp_path / "truth.csv", "--tracks", tmp_path / "tracks.csv",
                  "--map", tmp_path / "map2.png")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["robot_rmse_m"] == pytest.approx(numbers["robot_rmse_m"])
    assert "note: 5 line(s) not drawn:" in result.stderr and "trajectory row in the odometry frame" in result.stderr
    assert "dropped" not in result.stderr


def test_that_unusable_input_is_a_clear_error(tmp_path):
    (tmp_path / "empty.jsonl").write_text('{"type": "health", "t_s": 0}\n')
    (tmp_path / "nodes.csv").write_text("id,x,y\n1,0,0\n")
    (tmp_path / "good.csv").write_text("id,x,y,var_x,cov_xy,var_y,converged\n1,0,0,0.1,0,0.1,1\n")
    for args, message in (
            ([tmp_path / "empty.jsonl", "--map", tmp_path / "m.png"], "no node estimates"),
            ([tmp_path / "nodes.csv", "--map", tmp_path / "m.png"], "the header has no column 'var_x'"),
            ([tmp_path / "good.csv", "--map", tmp_path / "m.png", "--rmse", tmp_path / "r.png"],
             "needs estimates over time"),
            ([tmp_path / "missing.jsonl", "--map", tmp_path / "m.png"], "No such file")):
        result = plot(*args)
        assert result.returncode == 2 and message in result.stderr, (args, result.stderr)
    assert "example" in plot("--help").stdout


def carried_node_fixture(tmp_path):
    """The square, and 0x6010 carried from (2, 2) to (8, 2) during the run; the offline nodes CSV
    (one row per node, no time) holds the final map, exact, in the engine's frame."""
    write_truth(tmp_path / "truth.csv", {**SQUARE, 0x6010: (2.0, 2.0)})
    tracks = ["t,id,x,y"] + [f"{t},{0x6010},{2.0 + 0.6 * t},2.0" for t in range(11)]
    (tmp_path / "tracks.csv").write_text("\n".join(tracks) + "\n")
    rows = ["id,x,y,var_x,cov_xy,var_y,converged"]
    for node_id, (x, y) in {**SQUARE, 0x6010: (8.0, 2.0)}.items():
        ex, ey = engine_frame(x, y)
        rows.append(f"{node_id},{ex},{ey},0.01,0.0,0.02,1")
    (tmp_path / "nodes.csv").write_text("\n".join(rows) + "\n")


def test_that_a_final_map_is_compared_with_where_a_carried_node_ended(tmp_path):
    # Fixture: a map that is exact at the end of the run
    carried_node_fixture(tmp_path)

    # Test
    result = plot(tmp_path / "nodes.csv", "--truth", tmp_path / "truth.csv", "--tracks", tmp_path / "tracks.csv",
                  "--map", tmp_path / "map.png")

    # Assert: nothing is off; the carried node is where its track ended, not where it started
    assert result.returncode == 0, result.stderr
    numbers = json.loads(result.stdout)
    assert numbers["per_node_error_m"]["0x6010"] == pytest.approx(0.0, abs=1e-6)
    assert numbers["rmse_m"] == pytest.approx(0.0, abs=1e-6)


def test_that_the_alignment_is_fitted_on_the_nodes_that_stood(tmp_path):
    # Fixture: the carried node's final estimate is 1 m off; the static nodes are exact
    carried_node_fixture(tmp_path)
    rows = (tmp_path / "nodes.csv").read_text().splitlines()
    ex, ey = engine_frame(8.0, 3.0)
    rows[-1] = f"{0x6010},{ex},{ey},0.01,0.0,0.02,1"
    (tmp_path / "nodes.csv").write_text("\n".join(rows) + "\n")

    result = plot(tmp_path / "nodes.csv", "--truth", tmp_path / "truth.csv", "--tracks", tmp_path / "tracks.csv",
                  "--map", tmp_path / "map.png")

    # Assert: the error stays with the node that has it, instead of being spread over the map
    assert result.returncode == 0, result.stderr
    errors = json.loads(result.stdout)["per_node_error_m"]
    assert errors["0x6010"] == pytest.approx(1.0, abs=1e-6)
    assert all(errors[f"0x{i:04X}"] == pytest.approx(0.0, abs=1e-6) for i in SQUARE)


def test_that_the_legend_names_only_what_is_drawn(tmp_path, monkeypatch):
    # Fixture: a final map (one estimate per node): there is no estimated track to draw
    from cdro_tools import plot as plot_module
    from cdro_tools.evaluation import drawing
    carried_node_fixture(tmp_path)
    legends = []

    def keep_legend(fig, ax, path, title, **kwargs):
        legends.append([t.get_text() for t in ax.legend().get_texts()])
        import matplotlib.pyplot as plt
        plt.close(fig)

    monkeypatch.setattr(drawing, "finish", keep_legend)

    # Test
    assert plot_module.main([str(tmp_path / "nodes.csv"), "--truth", str(tmp_path / "truth.csv"), "--tracks",
                             str(tmp_path / "tracks.csv"), "--map", str(tmp_path / "map.png")]) == 0

    # Assert
    assert legends and "true track" in legends[0]
    assert "estimated track" not in legends[0]


def test_that_schema_2_lines_are_read_unplaced_nodes_are_a_note_and_robot_lines_keep_the_map_frame(tmp_path):
    # Fixture: the service's lines of schema 2: unplaced nodes with null positions, then the
    # map; a robot that dead-reckoned in the odometry frame before it was localized in the map
    write_truth(tmp_path / "truth.csv", SQUARE)
    lines = [json.dumps({"type": "node", "schema": 2, "t_s": 0.5, "t_unix_s": 1700000000.5, "id": i,
                         "id_hex": f"0x{i:04X}", "x_m": None, "y_m": None, "z_m": 1.0, "var_x_m2": None,
                         "cov_xy_m2": None, "var_y_m2": None, "placed": False, "converged": False})
             for i in SQUARE]
    lines += [node_line(6.0, i, x, y) for i, (x, y) in SQUARE.items()]
    robot = {"type": "robot", "schema": 2, "id": 0x6010, "heading_rad": 0.0, "var_x_m2": 0.01, "cov_xy_m2": 0.0,
             "var_y_m2": 0.01}
    lines += [json.dumps({**robot, "t_s": 1.0 + k, "frame": "odometry", "x_m": -40.0, "y_m": -40.0}) for k in range(3)]
    ex, ey = engine_frame(5.0, 6.0)
    lines += [json.dumps({**robot, "t_s": 6.0, "frame": "map", "x_m": ex, "y_m": ey})]
    (tmp_path / "est.jsonl").write_text("\n".join(lines) + "\n")
    (tmp_path / "tracks.csv").write_text("t,id,x,y\n0,24592,5.0,6.0\n10,24592,5.0,6.0\n")

    result = plot(tmp_path / "est.jsonl", "--truth", tmp_path / "truth.csv", "--tracks", tmp_path / "tracks.csv",
                  "--map", tmp_path / "map.png")

    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["robot_rmse_m"] == pytest.approx(0.0, abs=1e-6)
    assert "note: 5 line(s) not drawn: node not placed yet" in result.stderr
    assert "note: 3 line(s) not drawn: robot line in the odometry frame" in result.stderr
    assert "dropped" not in result.stderr
