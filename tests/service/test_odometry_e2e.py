"""The robot's odometry end to end: cdro-service-harness (the real service with a recording
engine) takes UDP datagrams on loopback, and MQTT messages through a real mosquitto, while a
scripted device streams ranges on a pseudo-terminal. What the consumer gets is checked against
what was sent, rejections are counted and logged, the capture holds the odometry records among
the frames (cdro-decode shows them), and a --replay of the capture gives the consumer the
identical sequence, frames and odometry interleaved as they were, with the same values.
"""
from __future__ import annotations

import json
import random
import socket
import subprocess
import sys
import threading
import time

import pytest

from cdro_tools.codec import read_capture

from service_support import (DEADLOCK_GUARD_S, NODES, OWN, FakeDevice, Harness, free_udp_port,
                             start_running, wait_until)




def stream_ranges(device: FakeDevice, count: int, seed: int) -> threading.Thread:
    """The device streams in the background, in bursts, while the robot sends odometry."""
    rng = random.Random(seed)
    pairs = [(OWN, n) for n in NODES] + [(NODES[0], NODES[1])]

    def run():
        for i in range(count):
            a, b = pairs[i % len(pairs)]
            device.range_frame(a, b, 3000 + rng.randrange(2000))
            if i % 25 == 24:
                time.sleep(0.002)  # let the loop interleave; correctness never depends on it
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def step(t, d, h) -> bytes:
    return json.dumps({"t": t, "distance_m": d, "dheading_rad": h}).encode()


def odometry_lines(lines):
    return [line for line in lines if line["kind"] == "odometry"]


def test_udp_odometry_with_a_streaming_device_then_an_identical_replay(harness_bin, tmp_path):
    port = free_udp_port()
    device, harness = start_running(harness_bin, tmp_path, name="live",
                                    extra_config=f"odometry: {{udp_port: {port}}}\n")
    steps = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)      # the drive software: steps
    velocities = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # another sender: velocities
    target = ("127.0.0.1", port)
    ranges = 400
    streaming = stream_ranges(device, ranges, seed=7)

    steps.sendto(json.dumps({"distance_m": 0.01, "dheading_rad": 0.0}).encode(), target)  # t: receive time
    # Explicit times start 10 minutes from now (longer than any deadlock guard), so that the
    # receive-time message above comes first however slowly the service reads it.
    base = time.time() + 600.0
    sent_steps = [(None, 0.01, 0.0)]
    bad = [b"not json", b"[0.1, 0.0]", b'{"distance_m": 0.1}', b'{"distance_m": 50, "dheading_rad": 0}',
           b'{"distance_m": 0.1, "dheading_rad": 0, "v_mps": 1, "omega_radps": 0}']
    for i in range(40):
        t = base + 0.05 * i
        d, h = 0.1 + 0.001 * i, (-1) ** i * 0.002  # never near a converted step's 0.02 m
        steps.sendto(step(t, d, h), target)
        sent_steps.append((t, d, h))
        velocities.sendto(json.dumps({"t": t + 0.025, "v_mps": 0.4, "omega_radps": 0.1}).encode(), target)
        if i % 8 == 0:
            steps.sendto(bad[i // 8], target)
    steps.sendto(step(base + 1.5, 0.5, 0.0), target)  # 0.475 s before the last one taken: out of order
    received = 1 + 40 * 2 + len(bad) + 1
    streaming.join(timeout=DEADLOCK_GUARD_S)
    h = harness.wait_health(lambda h: h["counters"]["odometry_received"] == received and
                            h["counters"]["frames_delivered"] >= ranges + 1, "every message and range taken")
    assert harness.stop() == 0
    device.vanish()

    c = h["counters"]
    assert c["odometry_accepted"] == 1 + 40 + 39        # the first velocity only starts its clock
    assert c["odometry_clock_starts"] == 1
    assert c["odometry_rejected_not_json"] == 1 and c["odometry_rejected_not_object"] == 1
    assert c["odometry_rejected_field"] == 1 and c["odometry_rejected_absurd"] == 1
    assert c["odometry_rejected_both_forms"] == 1 and c["odometry_rejected_out_of_order"] == 1
    assert c["odometry_rejected_too_long"] == 0 and c["odometry_clock_steps"] == 0
    log = harness.log()
    assert "odometry: listening for UDP JSON on udp:127.0.0.1:" in log
    assert "odometry: dropped a message from udp:127.0.0.1:" in log and "distance_m 50 is beyond +-10 m" in log

    live = harness.received_lines()
    odometry = odometry_lines(live)
    assert len(odometry) == c["odometry_accepted"]
    assert sum(1 for line in live if line["kind"] == "range") == ranges
    # The steps arrive as sent, in order; the first one carries its receive time.
    # (The converted ones are 0.02 m up to the rounding of t, about 2e-7 s at today's epoch.)
    step_lines = [line for line in odometry if line["distance_m"] != pytest.approx(0.4 * 0.05, abs=1e-5)]
    assert [(line["distance_m"], line["dheading_rad"]) for line in step_lines] == [(d, h) for _, d, h in sent_steps]
    assert [line["t_s"] for line in step_lines[1:]] == [t for t, _, _ in sent_steps[1:]]
    assert abs(step_lines[0]["t_s"] - time.time()) < 3600
    # Velocities became trapezoid steps over the 0.05 s between messages.
    converted = [line for line in odometry if line not in step_lines]
    assert len(converted) == 39
    assert all(line["distance_m"] == pytest.approx(0.4 * 0.05, abs=1e-5) and
               line["dheading_rad"] == pytest.approx(0.1 * 0.05, abs=1e-5) for line in converted)
    # The outputs follow the odometry: the harness dead-reckons the robot.
    robot = [line for line in harness.jsonl_lines() if line["type"] == "robot"]
    assert robot and robot[-1]["id"] == OWN

    # The capture: every accepted message, where it was taken among the frames.
    capture = read_capture(harness.capture)
    assert capture.header.format_version == 3 and capture.corrupt_bytes == 0
    records = [r.odometry_message() for r in capture.records if r.odometry]
    assert [(m["t"], m["distance_m"], m["dheading_rad"]) for m in records] == [
        (line["t_s"], line["distance_m"], line["dheading_rad"]) for line in odometry]
    assert {m["source"].rsplit(":", 1)[0] for m in records} == {"udp:127.0.0.1"}
    assert len({m["source"] for m in records}) == 2
    decoded = subprocess.run([sys.executable, "-m", "cdro_tools.decode", str(harness.capture)], capture_output=True,
                             text=True, check=True)
    decoded_lines = [json.loads(line) for line in decoded.stdout.splitlines()]
    assert sum(1 for line in decoded_lines if line.get("type") == "ODOMETRY") == len(odometry)
    assert json.loads(decoded.stderr.splitlines()[0])["capture"]["odometry_records"] == len(odometry)

    # Replay, as fast as possible and paced: the same calls in the same order with the same values.
    live_outputs = [line for line in harness.jsonl_lines() if line["type"] in ("node", "robot")]
    for speed in ("max", "25"):
        replay = Harness(harness_bin, tmp_path, name=f"replay-{speed}",
                         extra_config=f"odometry: {{udp_port: {port}}}\n",
                         args=["--replay", str(harness.capture), "--speed", speed,
                               "--jsonl", str(tmp_path / f"replay-{speed}.jsonl")])
        assert replay.wait_exit() == 0, replay.log()
        assert replay.received_lines() == live, f"speed {speed}"
        replayed_outputs = [line for line in replay.jsonl_lines() if line["type"] in ("node", "robot")]
        assert replayed_outputs == live_outputs, f"speed {speed}"
        last_health = [line for line in replay.jsonl_lines() if line["type"] == "health"][-1]
        assert last_health["counters"]["replay_odometry_records"] == len(odometry)
        assert "listening for UDP" not in replay.log()  # no live input during a replay


def test_odometry_over_mqtt_reaches_the_consumer_and_the_capture(harness_bin, tmp_path, mosquitto):
    device, harness = start_running(
        harness_bin, tmp_path, name="live",
        extra_config=f"mqtt: {{url: 'mqtt://127.0.0.1:{mosquitto.port}', topic_prefix: lab}}\n")
    wait_until(lambda: "mqtt: subscribed to 'lab/odometry'" in harness.log(), "the odometry subscription")
    streaming = stream_ranges(device, 100, seed=3)
    base = time.time() + 600.0
    payloads = [json.dumps({"t": base + 0.1 * i, "distance_m": 0.02 * i, "dheading_rad": 0.0}) for i in range(20)]
    payloads.insert(10, '{"t": "soon"}')
    published = subprocess.run([str(harness_bin / "bin" / "cdro-mqtt-publish"), "127.0.0.1", str(mosquitto.port),
                                "lab/odometry"], input="\n".join(payloads) + "\n", capture_output=True, text=True,
                               timeout=DEADLOCK_GUARD_S)
    assert published.returncode == 0, published.stderr
    streaming.join(timeout=DEADLOCK_GUARD_S)
    h = harness.wait_health(lambda h: h["counters"]["odometry_received"] == 21 and
                            h["counters"]["frames_delivered"] >= 101, "the odometry and the ranges")
    assert harness.stop() == 0
    device.vanish()
    assert h["counters"]["odometry_accepted"] == 20 and h["counters"]["odometry_rejected_field"] == 1
    assert h["counters"]["mqtt_received"] == 21
    odometry = odometry_lines(harness.received_lines())
    assert [line["distance_m"] for line in odometry] == [0.02 * i for i in range(20)]
    records = [r.odometry_message() for r in read_capture(harness.capture).records if r.odometry]
    assert [m["t"] for m in records] == [line["t_s"] for line in odometry]
    assert {m["source"] for m in records} == {"mqtt:lab/odometry"}
    assert "dropped a message from mqtt:lab/odometry: 't' is a string" in harness.log()
