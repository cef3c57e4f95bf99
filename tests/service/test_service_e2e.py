"""End-to-end tests of the service (cdro-service-harness: the real event loop, serial link,
session, intake, capture, outputs, live map and checkpoints, with a recording consumer) against
a scripted device on a real pseudo-terminal. Each link fault is played on the wire; in
every case the service does not crash, the counters say what happened, nothing invalid reaches
the consumer, and the capture stays readable.
"""
from __future__ import annotations

import os
import random
import signal

import pytest

from cdro_tools.codec import Frame, StreamDecoder, decode_sog, encode_frame, read_capture
from cdro_tools.codec.capture_file import FLAG_TO_DEVICE, RECORD_OVERHEAD
from cdro_tools.codec.frames import LAYOUT_HASH, PROTOCOL_VERSION, Result

from service_support import NODES, OWN, FakeDevice, Harness, start_running, wait_until



def seed_for(name: str) -> int:
    seed = int(os.environ.get("CDRO_TEST_SEED", "20261122"))
    print(f"{name}: seed {seed} (replay with CDRO_TEST_SEED={seed})")
    return seed



def send_ranges(device: FakeDevice, count: int, rng: random.Random | None = None) -> list[bytes]:
    rng = rng or random.Random(1)
    sent = []
    pairs = [(OWN, n) for n in NODES] + [(NODES[0], NODES[1]), (NODES[1], NODES[2])]
    for i in range(count):
        a, b = pairs[i % len(pairs)]
        sent.append(device.range_frame(a, b, 3000 + rng.randrange(2000)))
    return sent


def ranges_delivered(harness: Harness) -> int:
    return sum(1 for line in harness.received_lines() if line["kind"] == "range")


def test_handshake_stream_and_sigterm(harness_bin, tmp_path):
    device, harness = start_running(harness_bin, tmp_path)
    types = device.host_types()
    configure = [t for t in types if t in ("SET_NODES", "SET_SCHEDULE", "START")]
    assert configure[:3] == ["SET_NODES", "SET_SCHEDULE", "START"]
    set_nodes = next(f for f in device.host_frames if f.type == "SET_NODES")
    assert set_nodes["node_ids"] == NODES
    send_ranges(device, 300)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 300, "300 ranges delivered")
    assert harness.stop(signal.SIGTERM) == 0
    log = harness.log()
    assert "final checkpoint" in log

    assert ranges_delivered(harness) == 300
    # The final checkpoint is whole and holds the consumer's state.
    snapshot = decode_sog(harness.checkpoint.read_bytes())
    assert sorted(n["id"] for n in snapshot.nodes) == sorted([OWN] + NODES)
    assert snapshot.header["ranges_processed"] == 300
    # The capture holds every chunk received and every frame sent, readable to the end.
    capture = read_capture(harness.capture)
    assert capture.corrupt_bytes == 0 and capture.truncated_tail_bytes == 0
    received = [r for r in capture.records if not r.flags & FLAG_TO_DEVICE]
    sent = [r for r in capture.records if r.flags & FLAG_TO_DEVICE]
    decoded = StreamDecoder()
    kinds = [e.frame.type for r in received for e in decoded.feed(r.data + b"\x00") if e.result == Result.OK]
    assert kinds.count("RANGE") == 300
    assert len(sent) >= 3
    # JSON Lines: node lines for every node, health lines with the counters.
    lines = harness.jsonl_lines()
    assert {line["id"] for line in lines if line["type"] == "node"} == {OWN, *NODES}
    health = [line for line in lines if line["type"] == "health"]
    assert health and health[-1]["counters"]["frames_delivered"] >= 300
    device.vanish()


def test_garbage_bit_flips_cut_frames_and_absurd_values(harness_bin, tmp_path):
    rng = random.Random(seed_for("test_garbage_bit_flips_cut_frames_and_absurd_values"))
    device, harness = start_running(harness_bin, tmp_path)
    stream = bytearray()
    absurd = 0
    for i in range(1500):
        device.device_time_ms += 10
        distance = 2500 + rng.randrange(3000)
        dice = rng.randrange(12)
        if dice == 0:
            distance = 200_001 + rng.randrange(10_000_000)  # beyond the 200 m bound
            absurd += 1
        frame = encode_frame(Frame("RANGE", device.sequence & 0xFFFF, dict(
            device_time_ms=device.device_time_ms, from_id=OWN, to_id=NODES[i % 3], distance_mm=distance,
            rss_dbm=-80, flags=0)))
        device.sequence += 1
        if dice == 1:
            flipped = bytearray(frame)
            flipped[rng.randrange(len(frame) - 1)] ^= 1 << rng.randrange(8)
            frame = bytes(flipped)
        elif dice == 2:
            frame = frame[: len(frame) // 2]  # cut in half, runs into the next frame
        elif dice == 3:
            stream += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
        stream += frame
    stream += b"\x00"
    # What the service must conclude, by the same rules (the Python twin of the C decoder).
    expected = StreamDecoder()
    good_ranges = [e.frame for e in expected.feed(bytes(stream)) if e.result == Result.OK]
    value_errors = expected.counters["value_errors"]
    # Most absurd frames arrive whole (some are hit by the garbage or cut frame before them).
    assert absurd * 3 // 4 <= value_errors <= absurd
    for offset in range(0, len(stream), 997):  # in pieces, as a UART would deliver them
        device.write(bytes(stream[offset:offset + 997]))
    harness.wait_health(lambda h: h["counters"]["frames_ok"] + h["counters"]["chunks_rejected"] >=
                        len(good_ranges) + sum(v for k, v in expected.counters.items()
                                               if k.endswith("_errors")), "every chunk accounted for")
    h = harness.health()
    assert harness.stop() == 0
    counters = h["counters"]
    assert counters["value_errors"] == value_errors
    assert counters["crc_errors"] >= expected.counters["crc_errors"]
    assert counters["chunks_rejected"] == sum(counters[k] for k in counters if k.endswith("_errors")
                                              and k not in ("write_errors", "capture_write_errors",
                                                            "jsonl_write_errors", "checkpoint_errors"))
    delivered = [line for line in harness.received_lines() if line["kind"] == "range"]
    assert all(line["distance_mm"] <= 200_000 and line["from"] != line["to"] for line in delivered)
    stream_distances = [f["distance_mm"] for f in good_ranges if f.type == "RANGE"]
    assert [line["distance_mm"] for line in delivered][-len(stream_distances):] == stream_distances
    # The capture replays through the same decoder to the same verdicts.
    capture = read_capture(harness.capture)
    assert capture.corrupt_bytes == 0
    # Each drop is logged with what and why.
    log = harness.log()
    assert "intake: dropped RANGE seq" in log and "a field is out of its documented range" in log
    assert "(corrupted in transit)" in log
    device.vanish()


def test_incompatible_device_is_named_and_left_alone(harness_bin, tmp_path):
    link = tmp_path / "ttyPOZYX"
    device = FakeDevice(link, layout_hash=0x1234)
    harness = Harness(harness_bin, tmp_path, device=link)
    device.boot()
    h = harness.wait_health(lambda h: h["link"] == "incompatible", "link incompatible")
    assert "0x1234" in h["detail"] and f"0x{LAYOUT_HASH:04X}" in h["detail"], h["detail"]
    assert f"protocol version {PROTOCOL_VERSION}" in h["detail"]
    send_ranges(device, 20)
    harness.wait_health(lambda h: h["counters"]["frames_dropped_incompatible"] >= 20, "data frames dropped")
    assert not [t for t in device.host_types() if t in ("SET_NODES", "SET_SCHEDULE", "START")]
    assert harness.process.poll() is None  # still running, still saying so
    assert "incompatible device" in harness.log()
    assert harness.stop() == 0
    assert ranges_delivered(harness) == 0
    device.vanish()


def test_other_protocol_version_in_frame_headers(harness_bin, tmp_path):
    link = tmp_path / "ttyPOZYX"
    device = FakeDevice(link, header_version=PROTOCOL_VERSION + 1)
    harness = Harness(harness_bin, tmp_path, device=link)
    device.boot()  # (if this HELLO is lost before the port opens, the HELLO_REQUEST brings another)
    h = harness.wait_health(lambda h: h["link"] == "incompatible", "link incompatible")
    assert f"protocol version {PROTOCOL_VERSION + 1}" in h["detail"]
    assert f"protocol version {PROTOCOL_VERSION}" in h["detail"]
    assert h["counters"]["version_errors"] >= 1
    assert not [t for t in device.host_types() if t in ("SET_NODES", "SET_SCHEDULE", "START")]
    assert harness.stop() == 0
    device.vanish()


def test_a_port_streaming_bytes_that_are_not_our_frames_is_named(harness_bin, tmp_path):
    # Another sketch's text on the port. The link says so (within 2 s of the first
    # byte), before the session has even given up waiting for a HELLO.
    # A pseudo-terminal that only ever writes text (FakeDevice would answer HELLO_REQUEST).
    master, slave = os.openpty()
    link = tmp_path / "ttyPOZYX"
    link.symlink_to(os.ttyname(slave))
    harness = Harness(harness_bin, tmp_path, device=link)
    try:
        harness.wait_health(lambda h: h["counters"]["link_connects"] >= 1, "port opened")
        for _ in range(5):
            os.write(master, b"Pozyx ready_to_range: 4235 mm\r\n")
        wait_until(lambda: "not our frames" in harness.log(), "the foreign-bytes message")
        line = next(line for line in harness.log().splitlines() if "not our frames" in line)
        assert "bytes that are not our frames (wrong firmware or baud?)" in line
        assert 'text "Pozyx ready_to_range' in line and "115200" in line
        assert harness.stop() == 0
    finally:
        os.close(master)
        os.close(slave)


def test_device_vanishes_and_returns(harness_bin, tmp_path):
    device, harness = start_running(harness_bin, tmp_path)
    send_ranges(device, 50)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 50, "ranges before the unplug")
    device.write(encode_frame(Frame("RANGE", device.sequence, dict(device_time_ms=1, from_id=OWN, to_id=NODES[0],
                                                                   distance_mm=1, rss_dbm=0, flags=0)))[:9])
    device.vanish()  # unplugged in the middle of a frame
    h = harness.wait_health(lambda h: h["link"] == "disconnected", "link disconnected")
    assert h["counters"]["link_disconnects"] == 1
    # The map is kept while the device is away.
    assert len(harness.api("/api/map")["nodes"]) == 4
    wait_until(lambda: harness.health()["counters"]["link_open_failures"] >= 2, "retries while unplugged")
    device = FakeDevice(tmp_path / "ttyPOZYX")  # plugged in again (a new PTY at the same path)
    # Boot once the port is open again: the boot HELLO (sequence 0) is how a host learns that
    # the device restarted (one sent before the open would be flushed by it).
    harness.wait_health(lambda h: h["counters"]["link_connects"] == 2, "port reopened")
    device.boot()
    harness.wait_connected(handshakes=2)
    send_ranges(device, 50)
    h = harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 100, "ranges after the return")
    assert h["counters"]["link_connects"] == 2
    assert h["counters"]["device_resets"] == 1  # the boot HELLO of the returning device
    assert harness.stop() == 0
    assert ranges_delivered(harness) == 100
    capture = read_capture(harness.capture)
    assert capture.corrupt_bytes == 0 and capture.truncated_tail_bytes == 0
    assert "lost" in harness.log() and "retrying with backoff" in harness.log()
    device.vanish()


def test_firmware_reset_mid_stream(harness_bin, tmp_path):
    device, harness = start_running(harness_bin, tmp_path)
    send_ranges(device, 40)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 40, "ranges before the reset")
    device.boot()  # watchdog reset: 0x00, HELLO seq 0, device time from 0, stopped
    h = harness.wait_connected(handshakes=2)
    assert h["counters"]["device_resets"] == 1
    send_ranges(device, 40)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 80, "ranges after the reset")
    assert harness.stop() == 0
    kinds = [line["kind"] for line in harness.received_lines()]
    assert kinds.count("reset") == 1
    assert kinds.index("reset") > 40
    assert device.host_types().count("START") == 2
    device.vanish()


def test_silent_device_gets_hello_requests(harness_bin, tmp_path):
    link = tmp_path / "ttyPOZYX"
    device = FakeDevice(link)
    harness = Harness(harness_bin, tmp_path, device=link)
    # The boot HELLO went out before the port was opened (lost): the host asks for it.
    wait_until(lambda: "HELLO_REQUEST" in device.host_types(), "HELLO_REQUEST")
    harness.wait_connected()
    assert harness.stop() == 0
    device.vanish()


def test_kill_9_then_replay_the_capture(harness_bin, tmp_path):
    device, harness = start_running(harness_bin, tmp_path, name="live")
    send_ranges(device, 400)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 200, "some ranges delivered")
    harness.wait_health(lambda h: h["counters"]["checkpoints_written"] >= 1, "a periodic checkpoint")
    harness.stop(signal.SIGKILL)
    device.vanish()
    # The periodic checkpoint survives the kill whole (it is written to a temporary, then renamed;
    # a kill during a write may leave the temporary, never a half checkpoint).
    assert decode_sog(harness.checkpoint.read_bytes()).header["ranges_processed"] > 0
    live = [line for line in harness.received_lines() if line["kind"] == "range"]
    capture = read_capture(harness.capture)
    assert capture.corrupt_bytes == 0
    assert capture.truncated_tail_bytes < RECORD_OVERHEAD + 73  # at most the last record
    decoder = StreamDecoder()
    captured = [e.frame for r in capture.records if not r.flags & FLAG_TO_DEVICE
                for e in decoder.feed(r.data + b"\x00") if e.result == Result.OK and e.frame.type == "RANGE"]
    assert len(captured) >= len(live)
    # Replay: the consumer gets what was captured, in order, with the recorded times.
    replay = Harness(harness_bin, tmp_path, name="replay", args=["--replay", str(harness.capture), "--speed", "max"])
    assert replay.wait_exit() == 0, replay.log()
    replayed = [line for line in replay.received_lines() if line["kind"] == "range"]
    assert len(replayed) == len(captured)
    assert replayed[: len(live)] == live
    assert not replay.capture.exists()  # a replay does not capture itself


def test_replay_is_identical_at_any_speed(harness_bin, tmp_path):
    device, harness = start_running(harness_bin, tmp_path, name="live")
    rng = random.Random(seed_for("test_replay_is_identical_at_any_speed"))
    for block in range(6):
        send_ranges(device, 50, rng)
        device.motion(NODES[1], block % 2)
        device.write(bytes(rng.randrange(256) for _ in range(20)) + b"\x00")  # some garbage too
        harness.wait_health(lambda h, n=block: h["counters"]["frames_delivered"] >= 51 * (n + 1),
                            f"block {block}")
    assert harness.stop() == 0
    device.vanish()
    live_received = harness.received_lines()
    live_nodes = [line for line in harness.jsonl_lines() if line["type"] == "node"]
    for speed in ("max", "25"):
        replay = Harness(harness_bin, tmp_path, name=f"replay-{speed}",
                         args=["--replay", str(harness.capture), "--speed", speed,
                               "--jsonl", str(tmp_path / f"replay-{speed}.jsonl")])
        assert replay.wait_exit() == 0, replay.log()
        assert replay.received_lines() == live_received, f"speed {speed}"
        assert [line for line in replay.jsonl_lines() if line["type"] == "node"] == live_nodes, f"speed {speed}"
        assert replay.jsonl.read_text().count('"link":"replay"') >= 1


def test_resume_from_the_checkpoint(harness_bin, tmp_path):
    device, harness = start_running(harness_bin, tmp_path, name="first")
    send_ranges(device, 120)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 120, "ranges")
    first_map = harness.api("/api/map")
    assert harness.stop() == 0
    device.vanish()
    # Resuming gives the state the first run ended with (the harness state is exact counts).
    resumed = Harness(harness_bin, tmp_path, name="resumed", args=["--resume", str(harness.checkpoint)])
    wait_until(lambda: resumed.api("/api/map") and len(resumed.api("/api/map")["nodes"]) == 4, "resumed map")
    resumed_map = resumed.api("/api/map")
    for before, after in zip(first_map["nodes"], resumed_map["nodes"]):
        assert before["id"] == after["id"]
        assert before["var_x_m2"] == pytest.approx(after["var_x_m2"], rel=1e-12)
    assert resumed.stop() == 0
    assert "resume:" in resumed.log()


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage"])
def test_damaged_checkpoint_is_refused(harness_bin, tmp_path, damage):
    device, harness = start_running(harness_bin, tmp_path, name="first")
    send_ranges(device, 30)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 30, "ranges")
    assert harness.stop() == 0
    device.vanish()
    data = bytearray(harness.checkpoint.read_bytes())
    if damage == "truncate":
        data = data[: len(data) - 7]
    elif damage == "flip":
        data[len(data) // 2] ^= 0x04
    else:
        data = bytearray(b"this is not a checkpoint")
    bad = tmp_path / "bad.cdrosog"
    bad.write_bytes(bytes(data))
    refused = Harness(harness_bin, tmp_path, name="refused", args=["--resume", str(bad)])
    assert refused.wait_exit() == 2
    message = refused.log()
    assert str(bad) in message
    assert ("CRC-32" in message) if damage != "garbage" else ("not a SoG snapshot" in message)
    assert not refused.received.exists() or refused.received.read_text() == ""


def test_bad_config_is_a_clear_error(harness_bin, tmp_path):
    harness = Harness(harness_bin, tmp_path, extra_config="mqtt:\n  urll: mqtt://127.0.0.1:1\n")
    assert harness.wait_exit() == 2
    assert "unknown key 'urll' in section 'mqtt'" in harness.log()
