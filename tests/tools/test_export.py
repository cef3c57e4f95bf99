"""cdro-export: JSON Lines and captures into MCAP (Foxglove's schemas, or ROS 2 messages) and a
capture into ranges.csv; every file read back with an independent reader (tests/tools/
foxglove_support.py: mcap's reader, protobuf from the file's own descriptors, rosbags for CDR)
and checked against the input.

Streams are generated from a printed seed (CDRO_TEST_SEED). The capture tests need the native
build (cdro-hostd: CDRO_BUILD_DIR); the simulator runs offline, in simulated time.
"""
from __future__ import annotations

import json
import math
import os
import random
import subprocess
import sys

import numpy as np
import pytest

from foxglove_support import read_mcap

from cdro_tools.codec import read_capture

GUARD_S = 120.0                    # s of wall clock: a hang guard, never an expectation
START_UNIX_S = 1_764_000_000      # --start-unix-s given to the exports of JSON Lines
NODE_IDS = [0x6001, 0x6002, 0x6003, 0x6004, 0x6005, 0x6006]
ROBOT_ID = 0x6001


def export(*args, check=True) -> subprocess.CompletedProcess:
    done = subprocess.run([sys.executable, "-m", "cdro_tools.export.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=GUARD_S)
    if check:
        assert done.returncode == 0, done.stderr
    return done


def random_covariance(rng: random.Random) -> tuple[float, float, float]:
    """A positive definite 2x2 (m^2) with sigmas 0.02..0.5 m at a random angle."""
    s1, s2, angle = rng.uniform(0.02, 0.5), rng.uniform(0.02, 0.5), rng.uniform(0, math.pi)
    c, s = math.cos(angle), math.sin(angle)
    vx = c * c * s1 * s1 + s * s * s2 * s2
    vy = s * s * s1 * s1 + c * c * s2 * s2
    cxy = c * s * (s1 * s1 - s2 * s2)
    return vx, cxy, vy


def make_stream(seed: int) -> tuple[list[str], list[dict]]:
    """(the file's lines, the usable objects in order): node lines (some unplaced, some placed
    then unplaced again), robot lines, health lines, and three lines a reader must drop."""
    rng = random.Random(seed)
    lines, objects = [], []
    t_s = 0.0
    for step in range(60):
        t_s += rng.uniform(0.05, 0.4)
        kind = rng.choices(["node", "robot", "health"], weights=[6, 2, 1])[0]
        if kind == "node":
            node_id = rng.choice(NODE_IDS)
            placed = rng.random() > 0.15
            vx, cxy, vy = random_covariance(rng)
            status = rng.choice(["placed", "converged", "moving", "settling"]) if placed else "unplaced"
            obj = {"type": "node", "t_s": round(t_s, 3), "id": node_id,
                   "x_m": rng.uniform(-10, 10) if placed else 0, "y_m": rng.uniform(-10, 10) if placed else 0,
                   "var_x_m2": vx if placed else 0, "cov_xy_m2": cxy if placed else 0, "var_y_m2": vy if placed else 0,
                   "converged": status == "converged", "moving": status == "moving", "placed": placed,
                   "foldable": False, "status": status, "reason": "" if status != "placed" else "too few links",
                   "hinge": []}
        elif kind == "robot":
            vx, cxy, vy = random_covariance(rng)
            obj = {"type": "robot", "t_s": round(t_s, 3), "id": ROBOT_ID, "x_m": rng.uniform(-5, 5),
                   "y_m": rng.uniform(-5, 5), "heading_rad": rng.uniform(-math.pi, math.pi), "var_x_m2": vx,
                   "cov_xy_m2": cxy, "var_y_m2": vy}
            if step % 2:  # a newer service's heading terms (optional keys)
                obj.update(var_heading_rad2=rng.uniform(0.001, 0.1), cov_x_heading_m_rad=rng.uniform(-1e-3, 1e-3),
                           cov_y_heading_m_rad=rng.uniform(-1e-3, 1e-3), frame=rng.choice(["map", "odometry"]))
                if step % 4 == 1:  # position-heading terms that make it no covariance (docs/outputs.md)
                    obj["cov_x_heading_m_rad"] = 10 * math.sqrt(vx * obj["var_heading_rad2"])
        else:
            obj = {"type": "health", "t_s": round(t_s, 3), "link": "connected",
                   "counters": {"frames_delivered": step * 10, "crc_errors": step % 3}}
        lines.append(json.dumps(obj))
        objects.append(obj)
        if step == 20:
            lines.append("{this is not json")
        if step == 40:
            lines.append(json.dumps({"type": "node", "t_s": t_s, "x_m": 1.0, "y_m": 2.0}))  # no id
    lines.append(json.dumps(objects[-1])[:25])  # a last line cut short (the writer was killed)
    return lines, objects


@pytest.fixture
def stream(tmp_path):
    seed = int(os.environ.get("CDRO_TEST_SEED", "1"))
    print(f"stream seed {seed} (set CDRO_TEST_SEED to change it)")
    lines, objects = make_stream(seed)
    path = tmp_path / "stream.jsonl"
    path.write_text("\n".join(lines) + "\n")
    return path, objects


def t_ns(obj: dict) -> int:
    return START_UNIX_S * 10**9 + round(obj["t_s"] * 1e9)


def mahalanobis2(point, centre, cov) -> float:
    vx, cxy, vy = cov
    dx, dy = point[0] - centre[0], point[1] - centre[1]
    det = vx * vy - cxy * cxy
    return (vy * dx * dx - 2 * cxy * dx * dy + vx * dy * dy) / det


def xyz(d: dict) -> tuple[float, float, float]:
    return (d.get("x", 0.0), d.get("y", 0.0), d.get("z", 0.0))


def yaw_of(q: dict) -> float:
    return 2.0 * math.atan2(q.get("z", 0.0), q.get("w", 0.0))


def angle_close(a: float, b: float, tol: float = 1e-9) -> bool:
    return abs(math.remainder(a - b, 2 * math.pi)) <= tol


def check_node_entity(entity: dict, node: dict) -> None:
    """One placed node drawn: where the line says, its ellipse at 2 sigma, its label and colour."""
    assert entity["id"] == f"node-0x{node['id']:04x}" and entity["frame_id"] == "map"
    (sphere,) = entity["spheres"]
    assert xyz(sphere["pose"]["position"]) == pytest.approx((node["x_m"], node["y_m"], 0.0), abs=1e-12)
    (ellipse,) = entity["lines"]
    assert ellipse["type"] == "LINE_LOOP" and len(ellipse["points"]) >= 16
    cov = (node["var_x_m2"], node["cov_xy_m2"], node["var_y_m2"])
    for point in ellipse["points"]:  # every vertex 2 sigma from the node (Mahalanobis distance 2)
        assert mahalanobis2(xyz(point), (node["x_m"], node["y_m"]), cov) == pytest.approx(4.0, rel=1e-6)
    (label,) = entity["texts"]
    assert f"0x{node['id']:04x}" in label["text"] and node["status"] in label["text"]
    metadata = {kv["key"]: kv["value"] for kv in entity["metadata"]}
    assert metadata["status"] == node["status"] and metadata["id"] == str(node["id"])
    colour = sphere["color"]
    if node["status"] == "converged":
        assert colour["g"] > colour["r"] and colour["g"] > colour["b"]  # green
    elif node["status"] == "moving":
        assert colour["r"] > colour["g"] > colour["b"]                  # orange


def test_jsonl_to_foxglove_mcap_a_message_per_line(stream, tmp_path):
    path, objects = stream
    out = tmp_path / "out.mcap"
    done = export(path, "-o", out, "--rate-hz", "0", "--start-unix-s", START_UNIX_S)
    # Three lines dropped, each reason counted, and the export went on past them.
    assert "3 dropped" in done.stderr and "not JSON" in done.stderr and "without a node id" in done.stderr, done.stderr
    _, messages = read_mcap(out)
    by_topic: dict[str, list] = {}
    for topic, schema, encoding, log_time, decoded in messages:
        by_topic.setdefault(topic, []).append((schema, encoding, log_time, decoded))
    schemas = {topic: {(s, e) for s, e, _, _ in items} for topic, items in by_topic.items()}
    assert schemas == {"/cdro/nodes": {("foxglove.SceneUpdate", "protobuf")},
                       "/cdro/robot/pose": {("foxglove.PoseInFrame", "protobuf")},
                       "/cdro/robot/path": {("foxglove.PosesInFrame", "protobuf")},
                       "/cdro/robot/scene": {("foxglove.SceneUpdate", "protobuf")},
                       "/tf": {("foxglove.FrameTransforms", "protobuf")},
                       "/cdro/health": {("cdro.Health", "jsonschema")}}

    nodes = [o for o in objects if o["type"] == "node"]
    robots = [o for o in objects if o["type"] == "robot"]
    healths = [o for o in objects if o["type"] == "health"]
    assert len(by_topic["/cdro/nodes"]) == len(nodes)
    assert len(by_topic["/cdro/robot/pose"]) == len(by_topic["/tf"]) == len(robots)
    assert [d for _, _, _, d in by_topic["/cdro/health"]] == healths

    drawn = set()
    for node, (_, _, log_time, update) in zip(nodes, by_topic["/cdro/nodes"]):
        assert log_time == t_ns(node)
        entity_id = f"node-0x{node['id']:04x}"
        if node["placed"]:
            (entity,) = update["entities"]
            check_node_entity(entity, node)
            assert not update["deletions"]
            drawn.add(node["id"])
        else:  # an unplaced node is never drawn at the origin; one that was drawn is deleted
            assert not update["entities"]
            expected = [entity_id] if node["id"] in drawn else []
            assert [d["id"] for d in update["deletions"]] == expected
            drawn.discard(node["id"])

    for index, (robot, (_, _, log_time, pose)) in enumerate(zip(robots, by_topic["/cdro/robot/pose"])):
        assert log_time == t_ns(robot)
        assert pose["frame_id"] == ("odom" if robot.get("frame") == "odometry" else "map")
        assert xyz(pose["pose"]["position"]) == pytest.approx((robot["x_m"], robot["y_m"], 0.0), abs=1e-12)
        assert angle_close(yaw_of(pose["pose"]["orientation"]), robot["heading_rad"])
        path = by_topic["/cdro/robot/path"][index][3]
        assert len(path["poses"]) == index + 1  # the trail so far
        assert xyz(path["poses"][-1]["position"]) == xyz(pose["pose"]["position"])
        transforms = by_topic["/tf"][index][3]["transforms"]
        assert [(t["parent_frame_id"], t["child_frame_id"]) for t in transforms] == [("map", "odom"),
                                                                                     ("odom", "base_link")]
        assert xyz(transforms[0]["translation"]) == (0.0, 0.0, 0.0)
        assert xyz(transforms[1]["translation"]) == pytest.approx((robot["x_m"], robot["y_m"], 0.0), abs=1e-12)
        assert angle_close(yaw_of(transforms[1]["rotation"]), robot["heading_rad"])


def test_rate_limited_export_gives_the_whole_map_once_per_period(stream, tmp_path):
    path, objects = stream
    out = tmp_path / "out.mcap"
    rate_hz = 2.0
    export(path, "-o", out, "--rate-hz", rate_hz, "--start-unix-s", START_UNIX_S)
    _, messages = read_mcap(out)
    updates = [(log_time, d) for topic, _, _, log_time, d in messages if topic == "/cdro/nodes"]
    # One update per period of stream time with a node line in it, at the period's last node line,
    # holding every node placed at that moment.
    state: dict[int, dict] = {}
    expected = []
    for node in (o for o in objects if o["type"] == "node"):
        period = math.floor(node["t_s"] * rate_hz)
        state[node["id"]] = node
        snapshot = {i: n for i, n in state.items() if n["placed"]}
        if expected and expected[-1][0] == period:
            expected[-1] = (period, t_ns(node), snapshot)
        else:
            expected.append((period, t_ns(node), snapshot))
    assert len(updates) == len(expected)
    for (log_time, update), (_, when, snapshot) in zip(updates, expected):
        assert log_time == when
        assert sorted(e["id"] for e in update["entities"]) == sorted(f"node-0x{i:04x}" for i in snapshot)
        for entity in update["entities"]:
            check_node_entity(entity, snapshot[int(entity["id"][5:], 16)])


def test_jsonl_to_ros2_mcap(stream, tmp_path):
    path, objects = stream
    out = tmp_path / "ros2.mcap"
    export(path, "-o", out, "--ros2", "--rate-hz", "0", "--start-unix-s", START_UNIX_S)
    profile, messages = read_mcap(out)
    assert profile == "ros2"
    schemas = {(topic, schema, encoding) for topic, schema, encoding, _, _ in messages}
    assert schemas == {("/cdro/markers", "visualization_msgs/msg/MarkerArray", "ros2msg"),
                       ("/cdro/robot/pose", "geometry_msgs/msg/PoseWithCovarianceStamped", "ros2msg"),
                       ("/tf", "tf2_msgs/msg/TFMessage", "ros2msg"),
                       ("/cdro/health", "std_msgs/msg/String", "ros2msg")}
    nodes = [o for o in objects if o["type"] == "node"]
    robots = [o for o in objects if o["type"] == "robot"]
    markers = [(t, m) for topic, _, _, t, m in messages if topic == "/cdro/markers"]
    poses = [(t, m) for topic, _, _, t, m in messages if topic == "/cdro/robot/pose"]
    tfs = [m for topic, _, _, _, m in messages if topic == "/tf"]
    healths = [m for topic, _, _, _, m in messages if topic == "/cdro/health"]
    assert len(markers) == len(nodes) and len(poses) == len(tfs) == len(robots)
    assert [json.loads(h.data) for h in healths] == [o for o in objects if o["type"] == "health"]

    for node, (log_time, array) in zip(nodes, markers):
        assert log_time == t_ns(node)
        by_ns = {m.ns: m for m in array.markers}
        assert set(by_ns) == {"cdro/nodes", "cdro/ellipses", "cdro/labels"}
        assert all(m.id == node["id"] and m.header.frame_id == "map" for m in array.markers)
        if not node["placed"]:
            assert all(m.action == 2 for m in array.markers)  # DELETE
            continue
        sphere = by_ns["cdro/nodes"]
        assert sphere.type == 2 and sphere.action == 0
        assert (sphere.pose.position.x, sphere.pose.position.y) == pytest.approx((node["x_m"], node["y_m"]), abs=1e-12)
        cov = (node["var_x_m2"], node["cov_xy_m2"], node["var_y_m2"])
        strip = by_ns["cdro/ellipses"].points
        assert (strip[0].x, strip[0].y) == (strip[-1].x, strip[-1].y)  # closed
        for p in strip:
            assert mahalanobis2((p.x, p.y), (node["x_m"], node["y_m"]), cov) == pytest.approx(4.0, rel=1e-6)
        assert node["status"] in by_ns["cdro/labels"].text

    not_psd_seen = []
    for robot, (log_time, message), tf in zip(robots, poses, tfs):
        assert log_time == t_ns(robot)
        assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == t_ns(robot)
        assert message.header.frame_id == ("odom" if robot.get("frame") == "odometry" else "map")
        p = message.pose.pose
        assert (p.position.x, p.position.y, p.position.z) == pytest.approx((robot["x_m"], robot["y_m"], 0.0), abs=1e-12)
        assert angle_close(2 * math.atan2(p.orientation.z, p.orientation.w), robot["heading_rad"])
        cov = np.asarray(message.pose.covariance).reshape(6, 6)
        assert cov[0, 0] == robot["var_x_m2"] and cov[1, 1] == robot["var_y_m2"]
        assert cov[0, 1] == cov[1, 0] == robot["cov_xy_m2"]
        given = np.array([[robot["var_x_m2"], robot["cov_xy_m2"], robot.get("cov_x_heading_m_rad", 0)],
                          [robot["cov_xy_m2"], robot["var_y_m2"], robot.get("cov_y_heading_m_rad", 0)],
                          [robot.get("cov_x_heading_m_rad", 0), robot.get("cov_y_heading_m_rad", 0),
                           robot.get("var_heading_rad2", 0)]])
        if "var_heading_rad2" in robot and np.linalg.eigvalsh(given).min() >= 0:  # x, y, yaw: rows 0, 1, 5
            assert cov[5, 5] == robot["var_heading_rad2"]
            assert cov[0, 5] == cov[5, 0] == robot["cov_x_heading_m_rad"]
            assert cov[1, 5] == cov[5, 1] == robot["cov_y_heading_m_rad"]
        elif "var_heading_rad2" in robot:  # no covariance as given: the cross terms are left out
            assert cov[5, 5] == robot["var_heading_rad2"] and cov[0, 5] == cov[1, 5] == 0.0
            not_psd_seen.append(robot["t_s"])
        else:
            assert cov[5, 5] >= 1e6 and cov[0, 5] == cov[1, 5] == 0.0  # unknown, not certain
        assert np.count_nonzero(cov[2:5, :]) == 0  # z, roll, pitch: not estimated
        assert np.linalg.eigvalsh(cov).min() >= -1e-12
        frames = [(t.header.frame_id, t.child_frame_id) for t in tf.transforms]
        assert frames == [("map", "odom"), ("odom", "base_link")]
        base = tf.transforms[1].transform
        assert (base.translation.x, base.translation.y) == pytest.approx((robot["x_m"], robot["y_m"]), abs=1e-12)
    assert not_psd_seen, "the stream should hold a robot line whose 3x3 is no covariance"


def test_bad_input_is_refused_with_a_reason(tmp_path):
    empty = tmp_path / "none.jsonl"
    empty.write_text("")
    missing = export(tmp_path / "absent.jsonl", "-o", tmp_path / "x.mcap", check=False)
    assert missing.returncode == 2 and "absent.jsonl" in missing.stderr
    nowhere = export(empty, "-o", tmp_path / "no-such-dir" / "x.mcap", check=False)
    assert nowhere.returncode == 2 and "no-such-dir/x.mcap" in nowhere.stderr, nowhere.stderr
    ranges = export(empty, "--format", "ranges-csv", "-o", tmp_path / "r.csv", check=False)
    assert ranges.returncode == 2 and "ranges come from a capture" in ranges.stderr


# ----------------------------------------------------------------------------- captures

def simulate(tmp_path, name: str, *faults: str, duration_s: int = 20, seed: int = 3):
    capture, ranges = tmp_path / f"{name}.cdrocap", tmp_path / f"{name}-sim-ranges.csv"
    report = tmp_path / f"{name}-faults.json"
    args = [a for fault in faults for a in ("--fault", fault)]
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--seed", str(seed), "--duration",
                    str(duration_s), "--capture", str(capture), "--ranges-csv", str(ranges), "--fault-report",
                    str(report), *args], check=True, capture_output=True, timeout=GUARD_S)
    return capture, ranges, json.loads(report.read_text())


def csv_rows(path) -> list[list[str]]:
    lines = path.read_text().splitlines()
    assert lines[0] == "t,from,to,range_m"
    return [line.split(",") for line in lines[1:]]


def test_ranges_csv_from_a_capture_round_trips_through_cdro_hostd(build_dir, tmp_path):
    hostd = build_dir / "bin" / "cdro-hostd"
    assert hostd.exists(), f"{hostd} missing: build the native tree first"
    capture, sim_ranges, _ = simulate(tmp_path, "clean")
    exported = tmp_path / "exported.csv"
    done = export(capture, "--format", "ranges-csv", "-o", exported)
    sim_rows, rows = csv_rows(sim_ranges), csv_rows(exported)
    # Every range the simulated device reported, in order, to the mm; times to the simulator's ms.
    assert [r[1:] for r in rows] == [r[1:] for r in sim_rows] and len(rows) > 200
    assert max(abs(float(a[0]) - float(b[0])) for a, b in zip(rows, sim_rows)) <= 0.0006
    assert f"{len(rows)} ranges" in done.stderr
    # cdro-hostd reads it as it reads the simulator's own file: the same map.
    outputs = []
    for source in (sim_ranges, exported):
        out = tmp_path / f"{source.stem}-estimates.csv"
        run = subprocess.run([str(hostd), "--ranges-csv", str(source), "--out-csv", str(out)], capture_output=True,
                             text=True, timeout=GUARD_S)
        assert run.returncode == 0, run.stderr
        outputs.append(out.read_text())
    assert outputs[0] == outputs[1] and outputs[0].count("\n") >= 7


def test_ranges_csv_of_a_damaged_capture_counts_what_it_dropped(tmp_path):
    capture, _, report = simulate(tmp_path, "faults", "absurd@5", "garbage@8,bytes=40", "bit_flip@11,frames=2")
    cut = tmp_path / "cut.cdrocap"
    data = capture.read_bytes()
    cut.write_bytes(data[:len(data) - 7])  # the last record cut short
    out = tmp_path / "cut.csv"
    done = export(cut, "--format", "ranges-csv", "-o", out)
    decoded = report["link"]["host_decoder"]
    # What the intake would reject, as the simulator counted what it delivered.
    assert f"{decoded['cobs_errors']} cobs" in done.stderr and f"{decoded['value_errors']} value" in done.stderr
    assert decoded["crc_errors"] == 0 or f"{decoded['crc_errors']} crc" in done.stderr
    unknown = report["counts"]["absurd"]["unknown_node"]
    assert unknown > 0 and f"{unknown} ranges naming a node outside" in done.stderr
    assert "cut-short last record" in done.stderr
    rows = csv_rows(out)
    # The cut file gives what the whole one gives, less the ranges of its last record.
    full = tmp_path / "full.csv"
    export(capture, "--format", "ranges-csv", "-o", full)
    full_rows = csv_rows(full)
    last = read_capture(capture).records[-1]
    assert rows == full_rows[:len(rows)] and len(full_rows) - len(rows) <= last.data.count(b"\x00") + 1
    assert all(1 <= int(r[1]) <= 0xFFFF and int(r[1]) != int(r[2]) for r in rows)


def test_a_capture_to_mcap_carries_the_replayed_estimates_and_the_ranges(build_dir, tmp_path):
    hostd = build_dir / "bin" / "cdro-hostd"
    assert hostd.exists(), f"{hostd} missing: build the native tree first"
    capture, sim_ranges, _ = simulate(tmp_path, "demo", duration_s=25)
    out = tmp_path / "demo.mcap"
    env_build = ["--hostd", hostd]
    export(capture, "-o", out, *env_build)
    # The service's own estimates for the same capture, every update (as cdro-export replays it).
    jsonl = tmp_path / "replay.jsonl"
    run = subprocess.run([str(hostd), "--replay", str(capture), "--speed", "max", "--jsonl", str(jsonl), "--capture",
                          "", "--checkpoint", "", "--set", "jsonl.max_node_rate_hz=0"], capture_output=True, text=True,
                         timeout=GUARD_S)
    assert run.returncode == 0, run.stderr
    final = {}
    lines = [json.loads(line) for line in jsonl.read_text().splitlines()]
    for line in lines:
        if line["type"] == "node":
            final[line["id"]] = line
    placed = {i: n for i, n in final.items() if n["placed"]}
    assert len(placed) >= 5
    created_us = read_capture(capture).header.created_unix_us
    _, messages = read_mcap(out)
    updates = [(t, d) for topic, _, _, t, d in messages if topic == "/cdro/nodes"]
    last_time, last = updates[-1]
    last_node_t = max(n["t_s"] for n in final.values())
    assert last_time == created_us * 1000 + round(last_node_t * 1e9)
    assert sorted(e["id"] for e in last["entities"]) == sorted(f"node-0x{i:04x}" for i in placed)
    for entity in last["entities"]:
        check_node_entity(entity, placed[int(entity["id"][5:], 16)])
    # Links: every pair ranged, between the placed nodes, drawn from where the nodes are.
    pairs = {tuple(sorted((int(a), int(b)))) for _, a, b, _ in csv_rows(sim_ranges)}
    last_links = [d for topic, _, _, _, d in messages if topic == "/cdro/links"][-1]
    points = last_links["entities"][0]["lines"][0]["points"]
    drawn_pairs = set()
    for start, end in zip(points[0::2], points[1::2]):
        ends = []
        for point in (start, end):
            ends += [i for i, n in placed.items() if (n["x_m"], n["y_m"]) == (point["x"], point["y"])]
        drawn_pairs.add(tuple(sorted(ends)))
    assert drawn_pairs == {p for p in pairs if p[0] in placed and p[1] in placed}
    assert len(points) == 2 * len(drawn_pairs)
    ranges = [d for topic, _, _, _, d in messages if topic == "/cdro/ranges"]
    sim_rows = csv_rows(sim_ranges)
    assert [(r["from"], r["to"], r["range_m"]) for r in ranges] == [(int(a), int(b), float(m))
                                                                    for _, a, b, m in sim_rows]
    healths = [d for topic, _, _, _, d in messages if topic == "/cdro/health"]
    assert healths == [line for line in lines if line["type"] == "health"]


def test_schema_2_keys_are_used_when_present(tmp_path):
    """A newer service's lines (docs/outputs.md schema 2: t_unix_s, z_m, null positions of an
    unplaced node, the robot's frame and 3x3): stamps from t_unix_s, heights from z_m, the unplaced
    node never drawn, nothing dropped."""
    lines = [
        {"type": "node", "schema": 2, "t_s": 12.5, "t_unix_s": 1700000012.5, "id": 24577, "id_hex": "0x6001",
         "x_m": 3.214, "y_m": -0.502, "z_m": 1.25, "var_x_m2": 0.0041, "cov_xy_m2": -0.0003, "var_y_m2": 0.0052,
         "converged": True, "moving": False, "placed": True, "foldable": False, "status": "converged", "reason": "",
         "hinge": [], "hinge_hex": []},
        {"type": "node", "schema": 2, "t_s": 12.6, "t_unix_s": 1700000012.625, "id": 24582, "id_hex": "0x6006",
         "x_m": None, "y_m": None, "z_m": None, "var_x_m2": None, "cov_xy_m2": None, "var_y_m2": None,
         "converged": False, "moving": False, "placed": False, "foldable": False, "status": "unplaced", "reason": "",
         "hinge": [], "hinge_hex": []},
        {"type": "robot", "schema": 2, "t_s": 12.7, "t_unix_s": 1700000012.75, "id": 24600, "id_hex": "0x6018",
         "frame": "map", "x_m": 1.5, "y_m": 2.5, "heading_rad": 0.25, "var_x_m2": 0.01, "cov_xy_m2": 0.0,
         "var_y_m2": 0.02, "var_heading_rad2": 0.003, "cov_x_heading_m_rad": 0.001, "cov_y_heading_m_rad": -0.002,
         "heading_hypotheses": 1, "range_scale": 1.0625, "range_scale_sigma": 0.0125, "range_offset_m": 0.25,
         "range_offset_sigma_m": 0.05},
    ]
    path = tmp_path / "schema2.jsonl"
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))
    for ros2 in (False, True):
        out = tmp_path / f"schema2-{ros2}.mcap"
        done = export(path, "-o", out, "--rate-hz", "0", *(["--ros2"] if ros2 else []))
        assert "none dropped" in done.stderr and "no t_unix_s" not in done.stderr, done.stderr
        _, messages = read_mcap(out)
        stamps = {topic: t for topic, _, _, t, _ in messages}
        if ros2:
            markers = [m for topic, _, _, _, m in messages if topic == "/cdro/markers"]
            sphere = next(m for m in markers[0].markers if m.ns == "cdro/nodes")
            assert sphere.pose.position.z == 1.25
            assert all(m.action == 2 for m in markers[1].markers)  # the unplaced node: DELETE only
            pose = next(m for topic, _, _, _, m in messages if topic == "/cdro/robot/pose")
            assert pose.pose.covariance[5] == 0.001 and pose.pose.covariance[35] == 0.003
            assert stamps["/cdro/robot/pose"] == 1700000012750000000
        else:
            updates = [d for topic, _, _, _, d in messages if topic == "/cdro/nodes"]
            assert updates[0]["entities"][0]["spheres"][0]["pose"]["position"]["z"] == 1.25
            assert not updates[1]["entities"] and not updates[1]["deletions"]  # never drawn: nothing to delete
            assert stamps["/cdro/robot/pose"] == 1700000012750000000
        assert min(t for _, _, _, t, _ in messages) == 1700000012500000000


HOSTILE_LINES = [
    '{"type": "node", "t_s": 1, "t_unix_s": NaN, "id": 24577, "x_m": 1, "y_m": 2, "placed": true}',
    '{"type": "node", "t_s": -5, "id": 24577, "x_m": 1, "y_m": 2, "placed": true}',
    '{"type": "node", "t_s": 1, "t_unix_s": 1e20, "id": 24577, "x_m": 1, "y_m": 2, "placed": true}',
    '{"type": "robot", "t_s": 1, "id": 24577, "x_m": 1, "y_m": 2, "heading_rad": "north"}',
    '{"type": "robot", "t_s": 1, "id": 24577, "x_m": Infinity, "y_m": 2, "heading_rad": 0}',
    '{"type": "node", "t_s": 1, "id": 24577, "x_m": "1", "y_m": 2, "placed": true}',
    '{"type": "node", "t_s": 1, "id": 0, "x_m": 1, "y_m": 2, "placed": true}',
    '{"type": "node", "t_s": 1, "id": 70000, "x_m": 1, "y_m": 2, "placed": true}',
    '{"type": "node", "t_s": 1, "id": true, "x_m": 1, "y_m": 2, "placed": true}',
    '{"t_s": 1, "id": 24577, "x_m": 1, "y_m": 2}',
    '[1, 2]',
    '{"type": "health", "t_s": 1, "counters": [1, 2]}',
]


def test_hostile_lines_are_dropped_counted_and_the_export_goes_on(tmp_path):
    good = {"type": "node", "t_s": 2.0, "id": 0x6003, "x_m": 4.0, "y_m": 5.0, "var_x_m2": 0.01, "cov_xy_m2": 0.0,
            "var_y_m2": 0.01, "placed": True, "status": "converged"}
    path = tmp_path / "hostile.jsonl"
    path.write_text("\n".join(HOSTILE_LINES + [json.dumps(good)]) + "\n")
    for ros2 in (False, True):
        out = tmp_path / f"hostile-{ros2}.mcap"
        done = export(path, "-o", out, "--rate-hz", "0", *(["--ros2"] if ros2 else []))
        assert f"1 object(s) taken, {len(HOSTILE_LINES)} dropped" in done.stderr, done.stderr
        assert "Traceback" not in done.stderr
        _, messages = read_mcap(out)
        assert [topic for topic, *_ in messages] == ["/cdro/markers" if ros2 else "/cdro/nodes"]
