"""cdro-sim's device is the firmware itself (firmware/core built for the host with
sim/pozyx_sim as its Pozyx: sim/host_device), driven in simulated time in-process
against the "Device behaviour" contract of docs/protocol.md. What these tests add to the
firmware's own (tests/firmware: its scheduler, motion detector, commands, each in C) is the
joint: the Python world answering the firmware's Pozyx (positions, the UWB error model, the
accelerometer), the serial port, resets and the faults cdro-sim injects. test_sim_pty.py runs
the same device behind a pseudo-terminal end to end."""
import collections
import ctypes
import json
import random
import struct

import pytest

from cdro_tools import codec
from cdro_tools.codec import CONSTANTS as C
from cdro_tools.simulation import host_device
from cdro_tools.simulation.device import FirmwareDevice
from cdro_tools.simulation.scenario import parse_scenario
from cdro_tools.simulation.uwb import UwbModel
from cdro_tools.simulation.world import World

OWN, A, B, D = 0x6001, 0x6002, 0x6003, 0x6004


def scenario(**overrides):
    data = {
        "own_id": OWN,
        "nodes": [{"id": OWN, "x_m": 0, "y_m": 0, "z_m": 1.0, "accelerometer": True},
                  {"id": A, "x_m": 5, "y_m": 0, "z_m": 2.0},
                  {"id": B, "x_m": 5, "y_m": 5, "z_m": 1.5},
                  {"id": D, "x_m": 0, "y_m": 5, "z_m": 0.5, "accelerometer": True}],
        "duration_s": 30,
    }
    data.update(overrides)
    return parse_scenario(data, "test scenario")


class ListSink:
    def __init__(self):
        self.items = []          # (time_us, bytes, frame)
        self.capacity = 0xFFFF

    def room(self):
        return self.capacity

    def offer(self, time_us, data, frame):
        if len(data) > self.capacity:
            return False
        self.items.append((time_us, data, frame))
        return True

    def frames(self, frame_type=None):
        return [f for _, _, f in self.items if f is not None and (frame_type is None or f.type == frame_type)]

    def clear(self):
        self.items.clear()


def make_device(sc, seed=1):
    print(f"seed {seed}")
    world = World(sc)
    rng = {k: random.Random(f"{seed}:{k}") for k in ("links", "ranges", "accel")}
    uwb = UwbModel(sc, world, rng["links"], rng["ranges"])
    sink = ListSink()
    return FirmwareDevice(sc, world, uwb, rng["accel"], sink, seed=seed), sink


def advance(device, until_us):
    while device.next_due_us() <= until_us:
        device.idle_to(device.next_due_us())
        device.run_one()
    device.idle_to(until_us)


def command(device, frame_type, fields=None, sequence=0):
    """Sends a command and lets the firmware take it: the step after its last byte arrived
    (at 115200 baud) reads it first."""
    data = codec.encode_frame(codec.Frame(frame_type, sequence, fields or {}))
    device.receive(data)
    device.idle_to(device.now_us + len(data) * 87 + 1)
    device.run_one()


def booted(sc=None, seed=1):
    device, sink = make_device(sc or scenario(), seed)
    advance(device, 1_000_000)
    return device, sink


def started(sc, seed=1):
    """Booted, scheduled and started; the sink holds what came from START on."""
    device, sink = booted(sc, seed)
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    advance(device, device.now_us + 10_000)
    sink.clear()
    command(device, "START")
    return device, sink


def test_that_the_constants_are_the_firmwares():
    # Python holds none of them: they come from the library built from firmware/core
    assert host_device.constant("MOVING_ABOVE_MG") == 80 and host_device.constant("STILL_BELOW_MG") == 40
    assert host_device.constant("RANGING_ERROR_STREAK") == 5 and host_device.constant("BACKOFF_MAX_ROUNDS") == 4
    with pytest.raises(KeyError):
        host_device.constant("NO_SUCH_CONSTANT")


def test_that_the_device_is_booting_until_the_firmware_leaves_its_boot_state():
    # the state is the firmware's (cdro_fw_state_t), read from the library like the constants
    device, sink = make_device(scenario())
    boot_us = host_device.constant("POZYX_BOOT_MS") * 1000
    advance(device, device.boot_us + boot_us // 2)
    assert device.booting and not sink.frames("HELLO")
    advance(device, 1_000_000)
    assert sink.frames("HELLO") and not device.booting


def test_that_the_structures_match_the_c_structs_and_a_wrong_one_is_named():
    # Fixture: the same fields in the wrong order, and one field too few
    lib = host_device.library()  # loading checks the real ones

    class Reordered(ctypes.Structure):
        _fields_ = [("max_range_m", ctypes.c_double), ("seed", ctypes.c_uint64), ("pozyx_firmware", ctypes.c_uint8),
                    ("pozyx_present", ctypes.c_uint8), ("free_ram_bytes", ctypes.c_uint16)]

    class Short(ctypes.Structure):
        _fields_ = [(name, ctypes.c_uint32) for name in host_device.COUNTER_FIELDS[:-1]]

    # Test and verify
    host_device.check_layouts(lib)
    with pytest.raises(host_device.LayoutMismatch, match=r"Reordered .*cdro_hd_config_t.*field max_range_m at byte 0"):
        host_device.check_layouts(lib, {"cdro_hd_config_t": Reordered})
    with pytest.raises(host_device.LayoutMismatch, match=r"Short .*cdro_hd_counters_t.*52 bytes here, 56 in C"):
        host_device.check_layouts(lib, {"cdro_hd_counters_t": Short})
    with pytest.raises(host_device.LayoutMismatch, match="no struct cdro_hd_nothing_t"):
        host_device.check_layouts(lib, {"cdro_hd_nothing_t": Short})


def test_that_loading_the_library_checks_the_structures(monkeypatch):
    # Fixture: Counters one field short, as if a counter were added in C only
    class Counters(ctypes.Structure):
        _fields_ = [(name, ctypes.c_uint32) for name in host_device.COUNTER_FIELDS[:-1]]

    monkeypatch.setitem(host_device.STRUCTURES, "cdro_hd_counters_t", Counters)
    host_device.library.cache_clear()

    # Test and verify
    try:
        with pytest.raises(host_device.LayoutMismatch, match="cdro_hd_counters_t"):
            host_device.library()
    finally:
        monkeypatch.undo()
        host_device.library.cache_clear()
    host_device.library()


def test_that_a_missing_library_says_how_to_build_it(monkeypatch, tmp_path):
    monkeypatch.setattr(host_device, "candidates", lambda: [tmp_path / host_device.LIBRARY])
    host_device.library.cache_clear()
    try:
        with pytest.raises(host_device.HostDeviceMissing, match="--target cdro_host_device"):
            host_device.library()
    finally:
        monkeypatch.undo()
        host_device.library.cache_clear()


def test_that_boot_sends_a_delimiter_then_hello_then_the_discovered_nodes():
    # Fixture
    device, sink = make_device(scenario())

    # Test
    advance(device, 1_000_000)

    # Assert
    assert sink.items[0][1] == b"\x00"
    hello = sink.items[1][2]
    assert hello.type == "HELLO" and hello.sequence == 0
    assert hello["node_id"] == OWN and hello["reset_cause"] == C["CDRO_RESET_POWER_ON"]
    assert hello["protocol_version"] == codec.PROTOCOL_VERSION and hello["layout_hash"] == codec.LAYOUT_HASH
    assert hello["firmware_version"] == host_device.constant("VERSION")
    assert hello["max_nodes"] == host_device.constant("MAX_REMOTE_NODES")
    assert hello["device_time_ms"] == host_device.constant("POZYX_BOOT_MS")
    node_list = sink.frames("NODE_LIST")[0]
    assert node_list["source"] == C["CDRO_NODE_SOURCE_DISCOVERY"] and sorted(node_list["node_ids"]) == [A, B, D]
    # the firmware reads every node's settings (NODE_INFO), all alike in the model
    assert sorted(f["node_id"] for f in sink.frames("NODE_INFO")) == [OWN, A, B, D]
    assert not device.running and not sink.frames("RANGE")


def test_that_discovery_finds_only_the_nodes_in_range():
    sc = scenario(uwb={"max_range_m": 6.0})          # D at 5.0 m, A at 5.1 m, B at 7.1 m
    device, sink = booted(sc)
    assert sorted(sink.frames("NODE_LIST")[0]["node_ids"]) == [A, D]


def test_that_commands_are_answered_and_set_nodes_is_echoed_as_a_host_node_list():
    device, sink = booted()
    sink.clear()
    command(device, "SET_NODES", {"node_ids": [D, A]}, sequence=41)
    command(device, "PING", {"nonce": 0xDEADBEEF}, sequence=42)
    ack, node_list = sink.frames()[:2]
    pong = sink.frames("ACK")[-1]               # after the new nodes' NODE_INFO step
    assert (ack.type, ack["acked_type"], ack["acked_sequence"], ack["value"]) == ("ACK", 0x41, 41, 0)
    assert node_list.type == "NODE_LIST" and node_list["source"] == C["CDRO_NODE_SOURCE_HOST"]
    assert node_list["node_ids"] == [D, A]
    assert pong.type == "ACK" and pong["value"] == 0xDEADBEEF and pong["acked_sequence"] == 42


def test_that_set_nodes_beyond_the_firmwares_maximum_is_nacked():
    device, sink = booted()
    sink.clear()
    too_many = list(range(0x7001, 0x7001 + host_device.constant("MAX_REMOTE_NODES") + 1))
    command(device, "SET_NODES", {"node_ids": too_many}, sequence=9)
    (nack,) = sink.frames()
    assert nack.type == "NACK" and nack["reason"] == C["CDRO_NACK_TOO_MANY_NODES"] and nack["nacked_sequence"] == 9
    assert device.counters["commands_rejected"] == 1


def test_that_golden_rejections_get_the_documented_answers(golden_dir):
    # Fixture: the decoder's golden rejections, sent as host commands, one status period apart
    vectors = json.loads((golden_dir / "vectors.json").read_text())["decode_errors"]
    expected = {"cobs": None, "short": None, "crc": None, "too_long": None, "version": "MALFORMED",
                "type": "UNKNOWN_TYPE", "length": "MALFORMED"}
    device, sink = booted()
    for vector in vectors:
        advance(device, device.now_us + 1_100_000)
        sink.clear()
        rejected_before = device.counters["commands_rejected"]

        # Test
        device.receive(bytes.fromhex(vector["chunk"]) + b"\x00")
        advance(device, device.now_us + 20_000)

        # Assert
        result = vector["result"]
        if result == "value":
            reason = "UNKNOWN_TYPE" if vector["type"] < 0x40 else "BAD_VALUE"
        else:
            reason = expected[result]
        answers = [f for f in sink.frames() if f.type != "STATUS"]
        if reason is None:
            detail = int(codec.Result[result.upper()]) & 0xFFFF
            assert [(a.type, a["code"], a["detail"], a["node_id"]) for a in answers] == \
                [("ERROR", C["CDRO_DEVICE_ERROR_COMMAND"], detail, 0)], vector["name"]
        else:
            assert [(a.type, a["reason"], a["nacked_type"], a["nacked_sequence"]) for a in answers] == \
                [("NACK", C[f"CDRO_NACK_{reason}"], vector["type"], vector["sequence"])], vector["name"]
        assert device.counters["commands_rejected"] == rejected_before + 1, vector["name"]


def raw_chunk(type_id, payload=b"", sequence=7, version=codec.PROTOCOL_VERSION, length=None, crc_xor=0):
    raw = struct.pack("<BBHB", version, type_id, sequence, len(payload) if length is None else length) + payload
    return codec.cobs_encode(raw + struct.pack("<H", codec.crc16(raw) ^ crc_xor)) + b"\x00"


def test_that_undecodable_chunks_are_reported_by_error_command_at_most_once_per_status_period():
    device, sink = booted()
    sink.clear()
    first_us = device.now_us
    device.receive(raw_chunk(0x45, struct.pack("<I", 5), crc_xor=0x0100))
    advance(device, first_us + 200_000)
    device.receive(b"\x09\x01\x02\x00")
    advance(device, first_us + 2_500_000)
    reports = [(t, f["detail"]) for t, _, f in sink.items
               if f is not None and f.type == "ERROR" and f["code"] == C["CDRO_DEVICE_ERROR_COMMAND"]]
    assert [d for _, d in reports] == [0xFFFC, 0xFFFE]
    assert reports[1][0] - reports[0][0] >= 1_000_000
    assert not sink.frames("NACK") and device.counters["commands_rejected"] == 2


@pytest.mark.parametrize("mode, pairs", [
    ("all_pairs", {(OWN, A), (OWN, B), (OWN, D), (A, B), (A, D), (B, D)}),
    ("direct_only", {(OWN, A), (OWN, B), (OWN, D)}),
])
def test_that_ranging_goes_round_robin_over_the_schedule_pairs(mode, pairs):
    device, sink = started(scenario(schedule={"mode": mode, "motion_poll_ms": 0}))
    advance(device, 11_000_000)
    counts = collections.Counter((f["from_id"], f["to_id"]) for f in sink.frames("RANGE"))
    assert set(counts) == {(min(p), max(p)) if p[0] != OWN else p for p in pairs} or set(counts) == pairs
    assert max(counts.values()) - min(counts.values()) <= 2
    for f in sink.frames("RANGE"):
        assert bool(f["flags"] & C["CDRO_RANGE_FLAG_REMOTE"]) == (f["from_id"] != OWN)
    assert device.counters["ranges_ok_direct"] + device.counters["ranges_ok_remote"] == sum(counts.values())


def test_that_the_ranges_are_the_worlds_distances_with_its_error_model():
    # the world's geometry through the UWB model (noise 0.1 m), not the Pozyx model's own
    sc = scenario(schedule={"motion_poll_ms": 0}, uwb={"noise_std_m": 0.0, "scale": 1.1})
    device, sink = started(sc)
    advance(device, 3_000_000)
    world = World(sc)
    for f in sink.frames("RANGE"):
        true_m = world.distance_m(f["from_id"], f["to_id"], 0.0)
        assert f["distance_mm"] == round(1.1 * true_m * 1000), f


def test_that_a_dead_link_fails_with_retries_one_error_ranging_and_backs_off_while_the_others_go_on():
    sc = scenario(schedule={"mode": "direct_only", "motion_poll_ms": 0, "max_retries": 1},
                  uwb={"nlos": {"links": []}, "max_range_m": 6.0})   # B (7.1 m) out of reach
    device, sink = booted(sc)
    command(device, "SET_NODES", {"node_ids": [A, B, D]})
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    command(device, "START")
    sink.clear()
    advance(device, 20_000_000)
    ranged = collections.Counter(f["to_id"] for f in sink.frames("RANGE"))
    errors = [f for f in sink.frames("ERROR") if f["code"] == C["CDRO_DEVICE_ERROR_RANGING"]]
    assert ranged[B] == 0 and ranged[A] > 50 and ranged[D] > 50
    assert [f["node_id"] for f in errors] == [B]                 # once per streak
    c = device.counters
    assert c["ranges_failed_direct"] >= host_device.constant("RANGING_ERROR_STREAK") and c["retries"] > 0
    # backoff: B's slots (two attempts each) sit out up to BACKOFF_MAX_ROUNDS rounds
    assert c["ranges_failed_direct"] < ranged[A] / 2


def test_that_dropouts_are_retried_and_a_success_on_a_retry_has_the_retry_flag():
    sc = scenario(schedule={"mode": "direct_only", "motion_poll_ms": 0, "max_retries": 2},
                  uwb={"dropout_probability": 0.3})
    device, sink = started(sc)
    advance(device, 10_000_000)
    flags = [f["flags"] for f in sink.frames("RANGE")]
    assert any(f & C["CDRO_RANGE_FLAG_RETRY"] for f in flags)
    assert device.counters["retries"] > 0 and device.counters["ranges_failed_direct"] > 0


def test_that_a_carried_node_is_flagged_moving_then_still_again():
    # D is carried from 4 s to 8 s; the own tag and D are polled every 100 ms
    sc = scenario(schedule={"mode": "direct_only", "motion_poll_ms": 100},
                  motion=[{"node": D, "start_s": 4.0, "waypoints_m": [[2.0, 5.0]], "end_s": 8.0}])
    device, sink = started(sc)
    advance(device, 16_000_000)
    changes = [(t, f["moving"]) for t, _, f in sink.items
               if f is not None and f.type == "MOTION" and f["node_id"] == D
               and f["reason"] == C["CDRO_MOTION_REASON_CHANGE"]]
    assert [m for _, m in changes] == [1, 0]
    assert 4_000_000 < changes[0][0] < 5_500_000 and changes[1][0] > 8_000_000
    moving_ranges = [f for t, _, f in sink.items if f is not None and f.type == "RANGE" and f["to_id"] == D
                     and 5_500_000 < t < 8_000_000]
    assert moving_ranges and all(f["flags"] & C["CDRO_RANGE_FLAG_MOVING"] for f in moving_ranges)


def test_that_anchors_are_not_polled_and_tags_report_periodically():
    sc = scenario(schedule={"mode": "direct_only", "motion_poll_ms": 200})
    device, sink = started(sc)
    advance(device, 12_000_000)
    periodic = collections.Counter(f["node_id"] for f in sink.frames("MOTION")
                                   if f["reason"] == C["CDRO_MOTION_REASON_PERIODIC"])
    assert set(periodic) == {OWN, D}                  # A and B are anchors
    # every tag reports its first sample, then every MOTION_PERIODIC_MS
    period_s = host_device.constant("MOTION_PERIODIC_MS") / 1000
    assert all(count >= 1 + int(11 / period_s) for count in periodic.values()), periodic


def test_that_status_comes_every_period_with_the_firmwares_counters():
    device, sink = booted()
    sink.clear()
    advance(device, device.now_us + 5_000_000)
    statuses = sink.frames("STATUS")
    assert len(statuses) in (4, 5, 6)
    last = statuses[-1]
    assert last["frames_sent"] <= device.counters["frames_sent"] and last["free_ram_bytes"] == 612
    assert last["running"] == 0 and last["node_count"] == 3


def test_that_a_full_transmit_path_drops_frames_and_reports_them_once():
    device, sink = started(scenario(schedule={"mode": "direct_only", "motion_poll_ms": 0}))
    sink.clear()
    sink.capacity = 0
    advance(device, device.now_us + 2_000_000)
    dropped = device.counters["frames_dropped"]
    assert dropped > 0 and not sink.items
    sink.capacity = 0xFFFF
    advance(device, device.now_us + 500_000)
    overflow = [f for f in sink.frames("ERROR") if f["code"] == C["CDRO_DEVICE_ERROR_TX_OVERFLOW"]]
    assert len(overflow) == 1 and overflow[0]["detail"] == dropped


def test_that_a_reset_restarts_sequence_and_time_and_waits_stopped():
    device, sink = started(scenario())
    advance(device, 3_000_000)
    sink.clear()
    device.reset(C["CDRO_RESET_WATCHDOG"])
    advance(device, device.now_us + 1_000_000)
    hello = sink.frames("HELLO")[0]
    assert hello.sequence == 0 and hello["reset_cause"] == C["CDRO_RESET_WATCHDOG"]
    assert hello["device_time_ms"] == host_device.constant("POZYX_BOOT_MS")
    assert not device.running and device.boots == 2 and not sink.frames("RANGE")


def test_that_commands_during_boot_wait_in_the_receive_buffer_and_what_overflows_it_is_lost():
    device, sink = make_device(scenario())
    ping = codec.encode_frame(codec.Frame("PING", 3, {"nonce": 77}))
    device.receive(ping)
    device.receive(bytes(200))                       # beyond the Uno's 63-byte receive buffer
    advance(device, 1_000_000)
    assert [f["value"] for f in sink.frames("ACK")] == [77]
    assert device.host_bytes_lost_booting == len(ping) + 200 - host_device.constant("SERIAL_RX_BUFFER")


def test_that_a_missing_pozyx_reports_an_error_and_refuses_start():
    device, sink = booted(scenario(pozyx={"present": False}))
    hello = sink.frames("HELLO")[0]
    assert (hello["node_id"], hello["pozyx_firmware"], hello["capabilities"]) == \
        (host_device.constant("NODE_ID_UNKNOWN"), 0, 0)
    assert sink.frames("ERROR")[0]["code"] == C["CDRO_DEVICE_ERROR_POZYX_ABSENT"]
    command(device, "SET_NODES", {"node_ids": [A]})
    command(device, "START")
    assert sink.frames()[-1].type == "NACK" and sink.frames()[-1]["reason"] == C["CDRO_NACK_WRONG_STATE"]


def test_that_absurd_frames_are_numbered_and_counted_as_the_firmwares_own():
    device, sink = booted()
    sent = device.counters["frames_sent"]
    last = sink.frames()[-1].sequence
    device.send_absurd("self_range", 0xBEEF)
    frame = sink.frames()[-1]
    assert frame.type == "RANGE" and frame["to_id"] == OWN and frame.sequence == last + 1
    assert device.counters["frames_sent"] == sent + 1
    command(device, "PING", {"nonce": 1})
    assert sink.frames()[-1].sequence == last + 2


def test_that_the_same_seed_gives_the_same_conversation():
    sc = scenario(uwb={"dropout_probability": 0.1})
    runs = []
    for _ in range(2):
        device, sink = started(sc, seed=5)
        advance(device, 5_000_000)
        runs.append([(t, data) for t, data, _ in sink.items])
    assert runs[0] == runs[1]
