"""The service's MQTT output end to end: a real mosquitto started on a free loopback port, the
harness publishing what a scripted device streams, a libmosquitto subscriber (cdro-mqtt-listen)
reading the documented topics, and the last will when the service is killed."""
from __future__ import annotations

import json
import signal
import subprocess
import threading

from service_support import DEADLOCK_GUARD_S, NODES, OWN, FakeDevice, Harness, free_port, wait_until



class Listener:
    """cdro-mqtt-listen in the background; messages collected as they come."""

    def __init__(self, build_dir, port, topic_filter):
        self.messages: list[dict] = []
        self._lock = threading.Lock()
        self.process = subprocess.Popen([str(build_dir / "bin" / "cdro-mqtt-listen"), "127.0.0.1", str(port),
                                         topic_filter], stdout=subprocess.PIPE, text=True)
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        for line in self.process.stdout:
            with self._lock:
                self.messages.append(json.loads(line))

    def latest(self, topic):
        with self._lock:
            for message in reversed(self.messages):
                if message.get("topic") == topic:
                    return message
        return None

    def stop(self):
        self.process.terminate()
        self.process.wait(timeout=DEADLOCK_GUARD_S)


def test_nodes_health_and_last_will_over_mqtt(build_dir, tmp_path, mosquitto):
    listener = Listener(build_dir, mosquitto.port, "lab/#")
    wait_until(lambda: any(m.get("subscribed") for m in list(listener.messages)), "subscriber ready")
    link = tmp_path / "ttyPOZYX"
    device = FakeDevice(link)
    harness = Harness(build_dir, tmp_path, device=link, nodes=NODES,
                      extra_config=f"mqtt: {{url: 'mqtt://{mosquitto.host}:{mosquitto.port}', topic_prefix: lab, "
                                   "rate_hz: 0}")
    device.boot()
    harness.wait_connected()
    for i in range(60):
        device.range_frame(OWN, NODES[i % 3], 3000 + i)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 60, "ranges delivered")

    wait_until(lambda: listener.latest("lab/status") and listener.latest("lab/status")["payload"] == "online",
               "status online")
    for node in [OWN, *NODES]:
        message = wait_until(lambda n=node: listener.latest(f"lab/nodes/0x{n:04X}"), f"node {node}")
        payload = json.loads(message["payload"])
        assert payload["type"] == "node" and payload["id"] == node and payload["id_hex"] == f"0x{node:04X}"
        assert set(payload) >= {"t_s", "x_m", "y_m", "var_x_m2", "cov_xy_m2", "var_y_m2", "converged", "moving",
                                "placed", "foldable", "status", "reason", "hinge"}
    health = wait_until(lambda: listener.latest("lab/health"), "health")
    assert json.loads(health["payload"])["link"] in ("connected", "handshaking")
    h = harness.health()
    assert h["counters"]["mqtt_connects"] == 1 and h["counters"]["mqtt_published"] > 4

    # Killed without a word: the broker publishes the last will.
    harness.stop(signal.SIGKILL)
    wait_until(lambda: listener.latest("lab/status")["payload"] == "offline", "last will: offline")
    listener.stop()
    device.vanish()


def test_broker_down_at_start_does_not_stop_the_service(build_dir, tmp_path):
    port = free_port()  # nothing listens there
    link = tmp_path / "ttyPOZYX"
    device = FakeDevice(link)
    harness = Harness(build_dir, tmp_path, device=link,
                      extra_config=f"mqtt: {{url: 'mqtt://127.0.0.1:{port}', reconnect_min_s: 0.05, "
                                   f"reconnect_max_s: 0.2}}")
    device.boot()
    harness.wait_connected()
    for i in range(20):
        device.range_frame(OWN, NODES[i % 3], 3000 + i)
    h = harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 20, "ranges delivered")
    assert h["counters"]["mqtt_dropped"] > 0 and h["counters"]["mqtt_connects"] == 0
    assert "mqtt: broker" in harness.log()
    assert harness.stop() == 0
    device.vanish()
