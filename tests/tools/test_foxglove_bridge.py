"""cdro-foxglove end to end: the real service (build/bin/cdro-hostd) on the simulated device
(cdro-sim on a pseudo-terminal, the demo scenario), the robot's odometry sent over UDP, its live
map followed by one bridge (--sse) and its MQTT topics (a real mosquitto) by another (--mqtt);
a WebSocket client speaking the Foxglove protocol (foxglove_support.py, from the spec) checks
what each bridge serves against the service's own JSON output; the run's capture then goes
through `cdro-export --ros2` and gives back the live run's robot path. A second test follows a
JSON Lines file as it grows, with bad lines in it.

Timeouts are hang guards only; nothing depends on how fast the machine is.
"""
from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request

import pytest

from foxglove_support import FoxgloveClient, read_mcap

GUARD_S = 120.0                    # s of wall clock: reached only when something is broken
ROBOT = 0x6001                     # the demo's own tag, made the robot (movement.robot_id)
EXPECTED_SCHEMAS = {
    "/cdro/nodes": ("foxglove.SceneUpdate", "protobuf"),
    "/cdro/links": ("foxglove.SceneUpdate", "protobuf"),
    "/cdro/robot/pose": ("foxglove.PoseInFrame", "protobuf"),
    "/cdro/robot/path": ("foxglove.PosesInFrame", "protobuf"),
    "/cdro/robot/scene": ("foxglove.SceneUpdate", "protobuf"),
    "/tf": ("foxglove.FrameTransforms", "protobuf"),
    "/cdro/health": ("cdro.Health", "json"),
}


def free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(predicate, what: str, timeout_s: float = GUARD_S):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def accepting(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1):
            return True
    except OSError:
        return False


def get_json(url: str):
    try:
        with urllib.request.urlopen(url, timeout=5) as response:
            return json.loads(response.read())
    except (urllib.error.URLError, ConnectionError, json.JSONDecodeError):
        return None


class Process:
    def __init__(self, name: str, command: list[str], tmp_path):
        self.name = name
        self.log_path = tmp_path / f"{name}.stderr.log"
        self._log = open(self.log_path, "w")
        self.process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=self._log)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def stop(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            return self.process.wait(timeout=GUARD_S)
        finally:
            self._log.close()

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self._log.close()


def bridge(tmp_path, name: str, *source: str) -> tuple[Process, int]:
    port = free_port()
    process = Process(name, [sys.executable, "-m", "cdro_tools.foxglove_bridge", *source, "--port", str(port),
                             "--republish-s", "0.5"], tmp_path)
    wait_until(lambda: accepting(port) or process.process.poll() is not None, f"{name} listening")
    assert process.process.poll() is None, process.log()
    return process, port


def connect(port: int) -> FoxgloveClient:
    client = FoxgloveClient(f"ws://127.0.0.1:{port}", GUARD_S)
    client.wait_for(lambda: set(EXPECTED_SCHEMAS) <= {c["topic"] for c in client.channels.values()},
                    "the channels advertised", GUARD_S)
    assert client.server_info and client.server_info["name"] == "cdro-foxglove"
    advertised = {c["topic"]: (c["schemaName"], c["encoding"]) for c in client.channels.values()}
    assert {t: advertised[t] for t in EXPECTED_SCHEMAS} == EXPECTED_SCHEMAS
    client.subscribe_all()
    return client


def entities_by_node(update: dict) -> dict[int, dict]:
    return {int(e["id"][len("node-"):], 16): e for e in update["entities"]}


def position(entity: dict) -> tuple[float, float]:
    p = entity["spheres"][0]["pose"]["position"]
    return p.get("x", 0.0), p.get("y", 0.0)


def check_scene_matches(update: dict, nodes: dict[int, dict], what: str) -> None:
    """The scene holds exactly the placed nodes, each where the service says (to the bit: the
    float travels as a protobuf double)."""
    placed = {i: n for i, n in nodes.items() if n["placed"]}
    drawn = entities_by_node(update)
    assert sorted(drawn) == sorted(placed), f"{what}: drawn {sorted(drawn)}, placed {sorted(placed)}"
    for node_id, entity in drawn.items():
        assert position(entity) == (placed[node_id]["x_m"], placed[node_id]["y_m"]), f"{what}: node {node_id:#06x}"
        assert placed[node_id]["status"] in entity["texts"][0]["text"]


@pytest.fixture
def broker(start_mosquitto) -> int:
    """The port of a real mosquitto (tests/conftest.py)."""
    # QoS 1 and no queue limit, so that the comparison below does not rest on QoS 0's "at most
    # once" or on the broker's queue limits for a subscriber that falls behind (the test passes at
    # QoS 0 too; nothing here relies on it).
    return start_mosquitto("allow_anonymous true\nmax_queued_messages 0\n").port


def test_live_service_in_foxglove_over_sse_and_mqtt(build_dir, tmp_path, broker):
    hostd_bin = build_dir / "bin" / "cdro-hostd"
    assert hostd_bin.exists(), f"{hostd_bin} missing: build the native tree first"
    seed = int(os.environ.get("CDRO_TEST_SEED", "1"))
    print(f"cdro-sim demo, seed {seed} (set CDRO_TEST_SEED to change it)")
    link, jsonl, capture = tmp_path / "tty", tmp_path / "live.jsonl", tmp_path / "live.cdrocap"
    http_port, odometry_port = free_port(), free_port(socket.SOCK_DGRAM)
    config = tmp_path / "hostd.yaml"
    config.write_text(f"""
serial: {{device: {link}, reconnect_min_s: 0.05, reconnect_max_s: 0.4, hello_timeout_s: 0.3, hello_retries: 20}}
nodes: {{ids: [], unknown: reject}}
capture: {{path: {capture}}}
output: {{jsonl: {jsonl}, health_period_s: 0.5}}
jsonl: {{max_node_rate_hz: 0}}   # every update: the file is compared with the live map while the service runs
http: {{port: {http_port}, update_period_s: 0.1}}
mqtt: {{url: 'mqtt://127.0.0.1:{broker}', rate_hz: 0, qos: 1}}
checkpoint: {{path: ''}}
odometry: {{udp_port: {odometry_port}}}
movement: {{robot_id: {ROBOT}}}
""")
    processes: list[Process] = []
    clients: list[FoxgloveClient] = []
    stop_odometry = threading.Event()
    try:
        sim = Process("sim", [sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--seed", str(seed),
                              "--pty", str(link), "--speed", "4", "--duration", "24"], tmp_path)
        processes.append(sim)
        wait_until(link.is_symlink, "the simulator's pseudo-terminal")
        hostd = Process("hostd", [str(hostd_bin), "--config", str(config)], tmp_path)
        processes.append(hostd)
        wait_until(lambda: accepting(http_port) or hostd.process.poll() is not None, "the live map")
        assert hostd.process.poll() is None, hostd.log()
        sse, sse_port = bridge(tmp_path, "bridge-sse", "--sse", f"http://127.0.0.1:{http_port}/")
        mqtt, mqtt_port = bridge(tmp_path, "bridge-mqtt", "--mqtt", f"mqtt://127.0.0.1:{broker}")
        processes += [sse, mqtt]
        sse_client, mqtt_client = connect(sse_port), connect(mqtt_port)
        clients += [sse_client, mqtt_client]

        def odometry():
            # The robot rocks 1 cm back and forth: it moves (the movement stage starts) and stays
            # where the simulator has it.
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                k = 0
                while not stop_odometry.wait(0.1):
                    k += 1
                    message = {"distance_m": 0.01 if k % 2 else -0.01, "dheading_rad": 0.0}
                    s.sendto(json.dumps(message).encode(), ("127.0.0.1", odometry_port))

        threading.Thread(target=odometry, daemon=True).start()
        # Updates arrive while the device streams.
        while sim.process.poll() is None:
            sse_client.pump(0.2)
            mqtt_client.pump(0.2)
        assert sim.stop() == 0, sim.log()
        stop_odometry.set()
        live_updates = len(sse_client.of_topic("/cdro/nodes"))

        # The map holds still once the device is gone: take the service's final word.
        def settled():
            # The live map stamps every node with the map's time (t_s and t_unix_s go on while
            # nothing changes): compare the rest.
            clock = ("t_s", "t_unix_s")

            def estimates(m):
                return ([{k: v for k, v in n.items() if k not in clock} for n in m["nodes"]],
                        m["robot"] and {k: v for k, v in m["robot"].items() if k not in clock}, m["links"])
            first = get_json(f"http://127.0.0.1:{http_port}/api/map")
            time.sleep(0.5)
            second = get_json(f"http://127.0.0.1:{http_port}/api/map")
            return second if first and second and estimates(first) == estimates(second) else None
        final = wait_until(settled, "the service's map to settle")
        api_nodes = {n["id"]: n for n in final["nodes"]}
        lines = [json.loads(line) for line in jsonl.read_text().splitlines() if line.strip()]
        jsonl_nodes = {line["id"]: line for line in lines if line["type"] == "node"}
        robot_lines = [line for line in lines if line["type"] == "robot"]
        assert {i: (n["x_m"], n["y_m"]) for i, n in jsonl_nodes.items()} == \
               {i: (n["x_m"], n["y_m"]) for i, n in api_nodes.items()}
        assert sum(n["placed"] for n in api_nodes.values()) >= 6 and final["robot"] and final["links"]
        assert robot_lines and (robot_lines[-1]["x_m"], robot_lines[-1]["y_m"]) == (final["robot"]["x_m"],
                                                                                   final["robot"]["y_m"])

        settled_ns = time.time_ns()
        for client, what in ((sse_client, "sse"), (mqtt_client, "mqtt")):
            # What the client has not read yet includes scenes sent before the map settled: wait
            # for one the bridge stamped after (a repeat for late viewers carries the time it was sent).
            def republished(client=client):
                return [d for t, stamp_ns, d in client.messages
                        if t == "/cdro/nodes" and stamp_ns > settled_ns and len(d["entities"]) >= 6]
            scene = client.wait_for(republished, f"{what}: the whole map again", GUARD_S)[-1]
            check_scene_matches(scene, jsonl_nodes, f"{what} bridge against the JSON Lines")
            poses = client.of_topic("/cdro/robot/pose")
            assert poses, f"{what}: no robot pose"
            p = poses[-1]["pose"]["position"]
            assert (p["x"], p["y"]) == (final["robot"]["x_m"], final["robot"]["y_m"]) and poses[-1]["frame_id"] == "map"
            q = poses[-1]["pose"]["orientation"]
            assert math.remainder(2 * math.atan2(q["z"], q["w"]) - final["robot"]["heading_rad"], 2 * math.pi) == \
                pytest.approx(0.0, abs=1e-12)
            transforms = client.of_topic("/tf")[-1]["transforms"]
            assert [(t["parent_frame_id"], t["child_frame_id"]) for t in transforms] == [("map", "odom"),
                                                                                        ("odom", "base_link")]
            assert (transforms[1]["translation"]["x"], transforms[1]["translation"]["y"]) == (p["x"], p["y"])
            health = client.of_topic("/cdro/health")
            assert health and set(health[-1]["counters"]) == set(final["health"]["counters"])
            assert len(client.of_topic("/cdro/robot/path")[-1]["poses"]) >= 1

        # Only the live map's events carry links: drawn from the service's list, between placed nodes.
        links = sse_client.of_topic("/cdro/links")[-1]["entities"][0]["lines"][0]["points"]
        placed = {i for i, n in api_nodes.items() if n["placed"]}
        expected = [(api_nodes[e]["x_m"], api_nodes[e]["y_m"]) for link in final["links"]
                    if link["a"] in placed and link["b"] in placed for e in (link["a"], link["b"])]
        assert [(p["x"], p["y"]) for p in links] == expected and expected
        assert not mqtt_client.of_topic("/cdro/links")
        assert live_updates >= 5, f"only {live_updates} map updates while the device streamed"

        for process in (sse, mqtt):
            assert process.stop() == 0, process.log()
            assert "0 dropped" in process.log() or "none dropped" in process.log(), process.log()
        assert hostd.stop() == 0, hostd.log()
    finally:
        stop_odometry.set()
        for client in clients:
            client.close()
        for process in reversed(processes):
            process.kill()
    # The run's capture (odometry records included) as a ROS 2 recording: every robot line of the
    # live run, in order, the replay giving the live run's lines (docs/service.md).
    recording = tmp_path / "live-ros2.mcap"
    done = subprocess.run([sys.executable, "-m", "cdro_tools.export.cli", str(capture), "-o", str(recording), "--ros2",
                           "--rate-hz", "0", "--hostd", str(hostd_bin)], capture_output=True, text=True,
                          timeout=GUARD_S)
    assert done.returncode == 0, done.stderr
    _, messages = read_mcap(recording)
    poses = [m for topic, _, _, _, m in messages if topic == "/cdro/robot/pose"]
    assert [(p.pose.pose.position.x, p.pose.pose.position.y) for p in poses] == \
           [(r["x_m"], r["y_m"]) for r in robot_lines]


def test_a_growing_json_lines_file_with_bad_lines(tmp_path):
    path = tmp_path / "grow.jsonl"
    node = {"type": "node", "t_s": 1.0, "id": 0x6002, "x_m": 1.5, "y_m": -2.25, "var_x_m2": 0.01, "cov_xy_m2": 0.0,
            "var_y_m2": 0.02, "converged": True, "moving": False, "placed": True, "foldable": False,
            "status": "converged", "reason": "", "hinge": []}
    path.write_text(json.dumps(node) + "\n" + "garbage\n")
    process, port = bridge(tmp_path, "bridge-jsonl", "--jsonl", str(path))
    client = None
    try:
        client = connect(port)
        first = client.wait_for(lambda: [d for d in client.of_topic("/cdro/nodes") if d["entities"]],
                                "the first node", GUARD_S)[-1]
        check_scene_matches(first, {node["id"]: node}, "first")
        # Lines appended later arrive too: the node moves, another one is placed, one is cut short,
        # and the robot comes with a newer service's keys (epoch time, frame).
        moved = dict(node, t_s=2.0, x_m=3.0, y_m=4.0)
        other = dict(node, id=0x6003, t_s=2.0, x_m=-1.0, y_m=0.5, status="placed", converged=False)
        robot = {"type": "robot", "t_s": 2.1, "t_unix_s": 1_764_000_002.1, "frame": "odometry", "id": 0x6001,
                 "x_m": 0.5, "y_m": 0.25, "heading_rad": 0.3, "var_x_m2": 0.01, "cov_xy_m2": 0.0, "var_y_m2": 0.01}
        with open(path, "a") as f:
            # Values that are JSON but no time, heading or position: dropped, the bridge goes on.
            hostile = ['{"type": "robot", "t_s": 2, "t_unix_s": NaN, "id": 24577, "x_m": 1, "y_m": 2}',
                       '{"type": "robot", "t_s": 2, "id": 24577, "x_m": 1, "y_m": 2, "heading_rad": "north"}']
            f.write("\n".join(hostile + [json.dumps(o) for o in (moved, other, robot)]) + "\n" +
                    '{"type": "node", "id": 24' + "\n")
        latest = client.wait_for(lambda: [d for d in client.of_topic("/cdro/nodes") if len(d["entities"]) == 2],
                                 "both nodes", GUARD_S)[-1]
        check_scene_matches(latest, {moved["id"]: moved, other["id"]: other}, "after the append")
        poses = client.wait_for(lambda: len(client.of_topic("/cdro/robot/pose")) >= 3
                                and client.of_topic("/cdro/robot/pose"),
                                "the robot, then repeated for late viewers", GUARD_S)
        for pose in poses:
            assert pose["frame_id"] == "odom"  # a robot in its odometry's frame (no map yet)
            assert pose["timestamp"] == "2025-11-24T16:00:02.100Z"  # its t_unix_s, not the arrival time
        # Repeats do not grow the robot's path; a new robot line does.
        assert {len(trail["poses"]) for trail in client.of_topic("/cdro/robot/path")} == {1}
        with open(path, "a") as f:
            f.write(json.dumps(dict(robot, t_s=2.2, t_unix_s=1_764_000_002.2, x_m=0.75)) + "\n")
        paths = client.wait_for(lambda: [p for p in client.of_topic("/cdro/robot/path") if len(p["poses"]) == 2],
                                "the path's second pose", GUARD_S)
        assert [p["position"]["x"] for p in paths[-1]["poses"]] == [0.5, 0.75]
    finally:
        if client is not None:
            client.close()
        code = process.stop()
    assert code == 0, process.log()
    assert "4 dropped" in process.log() and "not JSON" in process.log() and "not a time" in process.log(), process.log()
