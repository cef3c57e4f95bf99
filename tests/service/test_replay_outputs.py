"""Replays that lose nothing and touch nothing they were not asked to: a
replay at full speed publishes every MQTT message (or says what it dropped and why), writes no
checkpoint and opens no live map unless its command line asks, and a resumed run's time goes on
from where the checkpoint left it."""
from __future__ import annotations

import re
import socket
import threading
import time

from service_support import NODES, OWN, Harness, free_port, start_running, wait_until
from test_mqtt_e2e import Listener

RANGES = 900


def live_capture(build_dir, tmp_path):
    device, harness = start_running(build_dir, tmp_path, name="live")
    for i in range(RANGES):
        device.range_frame(OWN, NODES[i % 3], 3000 + i % 97)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= RANGES, "ranges delivered")
    assert harness.stop() == 0, harness.log()
    device.vanish()
    return harness


def last_health(harness):
    return [line for line in harness.jsonl_lines() if line["type"] == "health"][-1]


def test_a_replay_at_full_speed_publishes_every_message(build_dir, tmp_path, mosquitto):
    live = live_capture(build_dir, tmp_path)
    listener = None
    try:
        listener = Listener(build_dir, mosquitto.port, "cdro/#")
        wait_until(lambda: any(m.get("subscribed") for m in list(listener.messages)), "subscriber ready")
        # A JSON line per update, as MQTT publishes with rate_hz 0: jsonl's per-node limit off.
        replay = Harness(build_dir, tmp_path, name="replay",
                         extra_config="mqtt: {rate_hz: 0}\njsonl: {max_node_rate_hz: 0}",
                         args=["--replay", str(live.capture), "--speed", "max", "--mqtt",
                               f"mqtt://127.0.0.1:{mosquitto.port}", "--jsonl", str(tmp_path / "replay.jsonl")])
        assert replay.wait_exit() == 0, replay.log()
        counters = last_health(replay)["counters"]
        print(f"replay: {counters['mqtt_published']} published, {counters['mqtt_dropped']} dropped")
        assert counters["mqtt_dropped"] == 0, replay.log()
        assert counters["mqtt_published"] > RANGES
        # Everything published arrived (QoS 0 on loopback loses nothing): the broker got it all.
        node_topics = [m for m in listener.messages if m.get("topic", "").startswith("cdro/nodes/")]
        published_nodes = sum(1 for line in replay.jsonl_lines() if line["type"] == "node")
        wait_until(lambda: len([m for m in list(listener.messages) if m.get("topic", "").startswith("cdro/nodes/")])
                   >= published_nodes, "every node message at the subscriber")
        assert len(node_topics) <= published_nodes
    finally:
        if listener is not None:
            listener.stop()


class LateForwarder:
    """A TCP port that starts forwarding to the broker only when open() is called: the replay is
    told of it before anything listens there, the subscriber is on the broker from the start."""

    def __init__(self, broker_port):
        self.port = free_port()
        self.broker_port = broker_port
        self.server = None
        self.threads = []

    def open(self):
        self.server = socket.create_server(("127.0.0.1", self.port))
        thread = threading.Thread(target=self._accept, daemon=True)
        thread.start()

    def _accept(self):
        while True:
            try:
                client, _ = self.server.accept()
            except OSError:
                return
            upstream = socket.create_connection(("127.0.0.1", self.broker_port))
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(source, sink):
        try:
            while data := source.recv(65536):
                sink.sendall(data)
        except OSError:
            pass
        finally:
            for s in (source, sink):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    def close(self):
        if self.server is not None:
            self.server.close()


def test_a_replay_waits_for_a_broker_that_comes_late(build_dir, tmp_path, mosquitto):
    # The replay of a capture takes milliseconds; the broker connection is made in the loop,
    # after the start. A replay that does not wait is over before the broker answers: all dropped.
    live = live_capture(build_dir, tmp_path)
    forwarder = LateForwarder(mosquitto.port)
    listener = None
    try:
        listener = Listener(build_dir, mosquitto.port, "cdro/nodes/#")
        wait_until(lambda: any(m.get("subscribed") for m in list(listener.messages)), "subscriber ready")
        replay = Harness(build_dir, tmp_path, name="replay",
                         extra_config="mqtt: {rate_hz: 0, reconnect_min_s: 0.5, reconnect_max_s: 1.0}\n"
                                      "jsonl: {max_node_rate_hz: 0}",  # a JSON line per update, as MQTT
                         args=["--replay", str(live.capture), "--speed", "max", "--mqtt",
                               f"mqtt://127.0.0.1:{forwarder.port}", "--jsonl", str(tmp_path / "replay.jsonl")])
        time.sleep(1.0)
        forwarder.open()
        assert replay.wait_exit() == 0, replay.log()
        node_lines = sum(1 for line in replay.jsonl_lines() if line["type"] == "node")
        assert node_lines > RANGES
        wait_until(lambda: len([m for m in list(listener.messages) if "topic" in m]) >= node_lines,
                   f"{node_lines} node messages at the subscriber")
        assert len([m for m in listener.messages if "topic" in m]) == node_lines
    finally:
        if listener is not None:
            listener.stop()
        forwarder.close()


def test_a_replay_says_what_it_could_not_publish(build_dir, tmp_path):
    live = live_capture(build_dir, tmp_path)
    port = free_port()  # nobody listens
    replay = Harness(build_dir, tmp_path, name="replay",
                     extra_config="mqtt: {reconnect_min_s: 0.1, reconnect_max_s: 0.2}",
                     args=["--replay", str(live.capture), "--speed", "max", "--mqtt", f"mqtt://127.0.0.1:{port}",
                           "--jsonl", str(tmp_path / "replay.jsonl")])
    assert replay.wait_exit() == 0, replay.log()
    dropped = last_health(replay)["counters"]["mqtt_dropped"]
    assert dropped > 0
    match = re.search(r"mqtt: (\d+) messages? (?:were )?not published", replay.log())
    assert match, replay.log()
    assert int(match.group(1)) >= dropped - 2  # the last health and status come after the line


def test_a_replay_writes_no_checkpoint_and_opens_no_live_map_unless_asked(build_dir, tmp_path):
    live = live_capture(build_dir, tmp_path)
    # The harness's configuration names a checkpoint and a live map port, as a live one would.
    replay = Harness(build_dir, tmp_path, name="replay", args=["--replay", str(live.capture), "--speed", "max"])
    assert replay.wait_exit() == 0, replay.log()
    assert not replay.checkpoint.exists()
    assert "live map at" not in replay.log()
    assert not replay.jsonl.exists()  # JSON Lines go to stdout unless --jsonl says where
    assert "replay: writes" in replay.log()
    # Asked for on the command line, they are there.
    asked = Harness(build_dir, tmp_path, name="asked",
                    args=["--replay", str(live.capture), "--speed", "max", "--checkpoint",
                          str(tmp_path / "asked.cdrosog"), "--jsonl", str(tmp_path / "asked.jsonl")])
    assert asked.wait_exit() == 0, asked.log()
    assert (tmp_path / "asked.cdrosog").exists() and (tmp_path / "asked.jsonl").exists()


def test_time_goes_on_across_a_resume(build_dir, tmp_path):
    device, first = start_running(build_dir, tmp_path, name="first")
    for i in range(60):
        device.range_frame(OWN, NODES[i % 3], 3000 + i)
    first.wait_health(lambda h: h["counters"]["frames_delivered"] >= 60 and h["t_s"] > 1.0, "ranges and a second")
    assert first.stop() == 0
    end_s = max(line["t_s"] for line in first.jsonl_lines())
    resumed = Harness(build_dir, tmp_path, device=device.link_path, name="resumed",
                      args=["--resume", str(first.checkpoint)])
    device.boot()
    resumed.wait_connected()
    for i in range(10):
        device.range_frame(OWN, NODES[i % 3], 3000 + i)
    resumed.wait_health(lambda h: h["counters"]["frames_delivered"] >= 10, "ranges after the resume")
    assert resumed.stop() == 0
    device.vanish()
    lines = resumed.jsonl_lines()
    assert lines and min(line["t_s"] for line in lines) >= end_s, (end_s, lines[0])
