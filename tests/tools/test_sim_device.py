"""The simulated device against the "Device behaviour" contract of docs/protocol.md, driven in
simulated time in-process (the same device runs behind the pseudo-terminal; test_sim_pty.py
checks it end to end)."""
import collections
import json
import random

import pytest

from cdro_tools import codec
from cdro_tools.codec import CONSTANTS as C
from cdro_tools.simulation.device import SimDevice
from cdro_tools.simulation.scenario import parse_scenario
from cdro_tools.simulation.uwb import UwbModel
from cdro_tools.simulation.world import World

OWN, A, B, D = 0x6001, 0x6002, 0x6003, 0x6004


def scenario(**overrides):
    data = {
        "own_id": OWN,
        "nodes": [{"id": OWN, "x": 0, "y": 0, "z": 1.0, "accelerometer": True},
                  {"id": A, "x": 5, "y": 0, "z": 2.0},
                  {"id": B, "x": 5, "y": 5, "z": 1.5},
                  {"id": D, "x": 0, "y": 5, "z": 0.5, "accelerometer": True}],
        "duration_s": 30,
    }
    data.update(overrides)
    return parse_scenario(data, "test scenario")


class ListSink:
    def __init__(self):
        self.items = []          # (time_us, bytes, frame)
        self.refuse = False

    def offer(self, time_us, data, frame):
        if self.refuse:
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
    rng = {k: random.Random(f"{seed}:{k}") for k in ("links", "ranges", "durations", "accel")}
    uwb = UwbModel(sc, world, rng["links"], rng["ranges"], rng["durations"])
    sink = ListSink()
    return SimDevice(sc, world, uwb, rng["accel"], sink), sink


def advance(device, until_us):
    while device.next_due_us() <= until_us:
        device.idle_to(device.next_due_us())
        device.run_one()
    device.idle_to(until_us)


def command(device, frame_type, fields=None, sequence=0):
    device.receive(codec.encode_frame(codec.Frame(frame_type, sequence, fields or {})))


def booted(sc=None, seed=1):
    device, sink = make_device(sc or scenario(), seed)
    advance(device, 1_000_000)
    return device, sink


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
    assert hello["capabilities"] == 0x1F      # direct, remote, local accel, remote accel (0x6004), discovery
    assert hello["device_time_ms"] == 300
    node_list = sink.frames("NODE_LIST")[0]
    assert node_list["source"] == C["CDRO_NODE_SOURCE_DISCOVERY"] and node_list["node_ids"] == [A, B, D]
    assert not device.running and not sink.frames("RANGE")


def test_that_capabilities_follow_the_scenario():
    sc = scenario(nodes=[{"id": OWN, "x": 0, "y": 0}, {"id": A, "x": 5, "y": 0}], device={"discovery": False})
    device, sink = booted(sc)
    assert sink.frames("HELLO")[0]["capabilities"] == C["CDRO_CAP_DIRECT_RANGING"] | C["CDRO_CAP_REMOTE_RANGING"]
    assert not sink.frames("NODE_LIST")


def test_that_set_nodes_is_acked_then_echoed_as_a_host_node_list():
    device, sink = booted()
    sink.clear()
    command(device, "SET_NODES", {"node_ids": [D, A]}, sequence=41)
    ack, node_list = sink.frames()
    assert (ack.type, ack["acked_type"], ack["acked_sequence"], ack["value"]) == ("ACK", 0x41, 41, 0)
    assert node_list.type == "NODE_LIST" and node_list["source"] == C["CDRO_NODE_SOURCE_HOST"]
    assert node_list["node_ids"] == [D, A] and device.nodes == [D, A]


@pytest.mark.parametrize("fields, reason", [
    ({"node_ids": [A, OWN]}, "BAD_VALUE"),          # the device's own node is not a remote node
    ({"node_ids": [A, B, D]}, "TOO_MANY_NODES"),      # max_nodes 2 below
])
def test_that_a_set_nodes_the_device_cannot_take_is_nacked_and_changes_nothing(fields, reason):
    device, sink = booted(scenario(device={"max_nodes": 2, "discovery": False}))
    sink.clear()
    command(device, "SET_NODES", fields, sequence=9)
    (nack,) = sink.frames()
    assert nack.type == "NACK" and nack["reason"] == C[f"CDRO_NACK_{reason}"] and nack["nacked_sequence"] == 9
    assert device.nodes == [] and device.counters["commands_rejected"] == 1


def test_that_start_without_nodes_is_nacked_wrong_state():
    device, sink = booted(scenario(device={"discovery": False}))
    command(device, "START")
    assert sink.frames()[-1].type == "NACK" and sink.frames()[-1]["reason"] == C["CDRO_NACK_WRONG_STATE"]
    assert not device.running


def test_that_ping_echoes_the_nonce_and_hello_request_gets_hello_without_ack():
    device, sink = booted()
    sink.clear()
    command(device, "PING", {"nonce": 0xDEADBEEF}, sequence=5)
    command(device, "HELLO_REQUEST", sequence=6)
    ack, hello = sink.frames()
    assert ack.type == "ACK" and ack["value"] == 0xDEADBEEF and ack["acked_sequence"] == 5
    assert hello.type == "HELLO" and hello["reset_cause"] == C["CDRO_RESET_POWER_ON"]


def test_that_golden_rejections_get_the_documented_answers(golden_dir):
    # Fixture: the decoder's golden rejections, sent as host commands
    vectors = json.loads((golden_dir / "vectors.json").read_text())["decode_errors"]
    expected = {"cobs": None, "short": None, "crc": None, "too_long": None, "version": "MALFORMED",
                "type": "UNKNOWN_TYPE", "length": "MALFORMED"}
    device, sink = booted()
    for vector in vectors:
        sink.clear()
        rejected_before = device.counters["commands_rejected"]

        # Test
        device.receive(bytes.fromhex(vector["chunk"]) + b"\x00")

        # Assert
        result = vector["result"]
        if result == "value":
            # a device-to-host type is never taken; a host command out of range is BAD_VALUE
            reason = "UNKNOWN_TYPE" if vector["type"] < 0x40 else "BAD_VALUE"
        else:
            reason = expected[result]
        answers = sink.frames()
        if reason is None:
            assert answers == [], vector["name"]
        else:
            assert [(a.type, a["reason"], a["nacked_type"], a["nacked_sequence"]) for a in answers] == \
                [("NACK", C[f"CDRO_NACK_{reason}"], vector["type"], vector["sequence"])], vector["name"]
        assert device.counters["commands_rejected"] == rejected_before + 1, vector["name"]


def test_that_a_device_to_host_type_is_nacked_unknown_type():
    device, sink = booted()
    sink.clear()
    command(device, "STATUS", {"uptime_ms": 0, "ranges_ok_direct": 0, "ranges_ok_remote": 0, "ranges_failed_direct": 0,
                               "ranges_failed_remote": 0, "retries": 0, "bus_errors": 0, "timeouts": 0,
                               "frames_sent": 0, "frames_dropped": 0, "commands_rejected": 0, "longest_loop_us": 0,
                               "free_ram_bytes": 0, "running": 0, "node_count": 0}, sequence=3)
    assert [(f.type, f["reason"]) for f in sink.frames()] == [("NACK", C["CDRO_NACK_UNKNOWN_TYPE"])]


def ranged_pairs(sink):
    return collections.Counter((f["from_id"], f["to_id"]) for f in sink.frames("RANGE"))


@pytest.mark.parametrize("mode, pairs", [
    ("all_pairs", {(OWN, A), (OWN, B), (OWN, D), (A, B), (A, D), (B, D)}),
    ("direct_only", {(OWN, A), (OWN, B), (OWN, D)}),
])
def test_that_ranging_goes_round_robin_over_the_schedule_pairs(mode, pairs):
    # Fixture
    sc = scenario(schedule={"mode": mode, "motion_poll_ms": 0})
    device, sink = booted(sc)
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    command(device, "START")
    sink.clear()

    # Test
    advance(device, 11_000_000)

    # Assert: every pair, equally often (no NLOS, no dropouts), remote flag on remote pairs
    counts = ranged_pairs(sink)
    assert set(counts) == pairs
    assert max(counts.values()) - min(counts.values()) <= 1
    for f in sink.frames("RANGE"):
        assert bool(f["flags"] & C["CDRO_RANGE_FLAG_REMOTE"]) == (f["from_id"] != OWN)
    assert device.counters["ranges_ok_direct"] + device.counters["ranges_ok_remote"] == sum(counts.values())


def test_that_ranges_take_plausible_time():
    # direct 15-25 ms, remote 40-70 ms: a 4-node all-pairs round is 3 x 20 + 3 x 55 ms on average
    device, sink = booted(scenario(schedule={"motion_poll_ms": 0}))
    command(device, "SET_SCHEDULE", {**device.scenario.schedule.fields(), "motion_poll_ms": 0})
    command(device, "START")
    sink.clear()
    advance(device, 21_000_000)
    rate_hz = len(sink.frames("RANGE")) / 20.0
    assert 20.0 < rate_hz < 35.0, rate_hz


def test_that_a_slot_period_spaces_the_slots():
    device, sink = booted()
    command(device, "SET_SCHEDULE", {"slot_period_ms": 100, "mode": 1, "motion_poll_ms": 0, "moving_boost": 2,
                                     "status_period_ms": 1000, "max_retries": 1})
    command(device, "START")
    sink.clear()
    advance(device, 11_000_000)
    times = [f["device_time_ms"] for f in sink.frames("RANGE")]
    assert len(times) == pytest.approx(100, abs=2)
    assert all(b - a >= 30 for a, b in zip(times, times[1:]))


def test_that_the_moving_boost_spreads_extra_visits_without_starving_any_pair():
    # Fixture: B flagged moving
    device, _ = booted()
    device.schedule.moving_boost = 3
    device.motion[B] = type(device.motion[OWN])(next_poll_us=0, moving=True)

    # Test
    round_ = device.build_round()

    # Assert
    counts = collections.Counter(round_)
    assert {p: c for p, c in counts.items() if B in p} == {(OWN, B): 3, (A, B): 3, (B, D): 3}
    assert all(c == 1 for p, c in counts.items() if B not in p)
    positions = [i for i, p in enumerate(round_) if p == (OWN, B)]
    gaps = [b - a for a, b in zip(positions, positions[1:])]
    assert min(gaps) >= 2                   # spread through the round, not back to back


def test_that_failed_ranges_are_retried_and_a_streak_of_five_reports_one_error():
    # Fixture: everything drops out
    sc = scenario(uwb={"dropout_probability": 1.0}, schedule={"mode": "direct_only", "motion_poll_ms": 0,
                                                              "max_retries": 2})
    device, sink = booted(sc)
    command(device, "SET_NODES", {"node_ids": [A]})
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    command(device, "START")
    sink.clear()

    # Test
    advance(device, 3_000_000)

    # Assert: 3 attempts per slot, 2 of them retries; one ERROR RANGING for the whole streak
    c = device.counters
    assert c["ranges_failed_direct"] >= 15 and c["ranges_failed_direct"] % 3 == 0
    assert c["retries"] == c["ranges_failed_direct"] * 2 // 3
    errors = sink.frames("ERROR")
    assert [(e["code"], e["detail"], e["node_id"]) for e in errors] == [(C["CDRO_DEVICE_ERROR_RANGING"], 0x11, A)]


def test_that_a_range_that_succeeds_on_a_retry_has_the_retry_flag():
    seed = 20260301
    sc = scenario(uwb={"dropout_probability": 0.5}, schedule={"motion_poll_ms": 0, "max_retries": 3})
    device, sink = booted(sc, seed)
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    command(device, "START")
    advance(device, 6_000_000)
    flags = [f["flags"] for f in sink.frames("RANGE")]
    retried = sum(1 for f in flags if f & C["CDRO_RANGE_FLAG_RETRY"])
    assert 0.25 < retried / len(flags) < 0.75, (retried, len(flags))


def test_that_an_unknown_node_fails_ranging_with_a_timeout():
    device, sink = booted()
    command(device, "SET_NODES", {"node_ids": [0x7777]})
    command(device, "SET_SCHEDULE", {"slot_period_ms": 0, "mode": 0, "motion_poll_ms": 0, "moving_boost": 2,
                                     "status_period_ms": 1000, "max_retries": 0})
    command(device, "START")
    advance(device, 2_000_000)
    assert not sink.frames("RANGE")
    assert [(e["code"], e["detail"], e["node_id"]) for e in sink.frames("ERROR")] == \
        [(C["CDRO_DEVICE_ERROR_RANGING"], 0x12, 0x7777)]


def test_that_motion_follows_the_80_40_mg_hysteresis_and_is_reported_on_change_and_every_5_s():
    # Fixture: D is carried from 10 s to 14 s
    sc = scenario(motion=[{"node": D, "start_s": 10, "end_s": 14, "waypoints": [[4, 5]]}], duration_s=40)
    device, sink = booted(sc)
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    command(device, "START")

    # Test
    advance(device, 30_000_000)

    # Assert
    motion = [(f["device_time_ms"] / 1000, f["moving"], f["reason"]) for f in sink.frames("MOTION") if f["node_id"] == D]
    changes = [(t, moving) for t, moving, reason in motion if reason == C["CDRO_MOTION_REASON_CHANGE"]]
    assert [m for _, m in changes] == [1, 0]
    assert 10.0 <= changes[0][0] < 10.5                    # within a poll or two
    # still again after the 8-sample window has cleared and 16 samples stayed under 40 mg
    assert 14.0 + (8 + 16 - 2) * 0.2 <= changes[1][0] < 14.0 + (8 + 16 + 2) * 0.2
    periodic = [t for t, _, reason in motion if reason == C["CDRO_MOTION_REASON_PERIODIC"]]
    assert len(periodic) >= 4
    assert all(4.9 <= b - a <= 5.3 for a, b in zip(periodic, periodic[1:]) if b - a < 6)
    # ranges with D carry the moving flag only while D is flagged
    flagged = [f["device_time_ms"] / 1000 for f in sink.frames("RANGE") if f["flags"] & C["CDRO_RANGE_FLAG_MOVING"]]
    assert flagged and all(changes[0][0] <= t <= changes[1][0] + 0.2 for t in flagged)
    # the own node and the anchors are never flagged; anchors are not polled
    assert {f["node_id"] for f in sink.frames("MOTION")} == {OWN, D}


def test_that_status_comes_every_period_running_or_not():
    device, sink = booted()
    sink.clear()
    advance(device, 5_000_000)
    stopped = sink.frames("STATUS")
    command(device, "SET_SCHEDULE", {"slot_period_ms": 0, "mode": 1, "motion_poll_ms": 200, "moving_boost": 2,
                                     "status_period_ms": 250, "max_retries": 1})
    command(device, "START")
    sink.clear()
    advance(device, 7_000_000)
    running = sink.frames("STATUS")
    assert len(stopped) == 4 and all(s["running"] == 0 for s in stopped)
    assert len(running) == pytest.approx(8, abs=1) and all(s["running"] == 1 for s in running)
    last = running[-1]
    assert last["node_count"] == 3 and last["frames_sent"] > 0 and last["longest_loop_us"] > 15000


def test_that_stop_stops_ranging_but_not_status():
    device, sink = booted()
    command(device, "START")
    advance(device, 2_000_000)
    command(device, "STOP", sequence=8)
    sink.clear()
    advance(device, 4_000_000)
    assert not sink.frames("RANGE") and sink.frames("STATUS")[-1]["running"] == 0


def test_that_a_full_transmit_buffer_drops_frames_and_reports_them_once():
    # Fixture
    device, sink = booted()
    command(device, "START")
    advance(device, 2_000_000)

    # Test: the serial buffer takes nothing for 1 s
    sink.refuse = True
    advance(device, 3_000_000)
    dropped = device.counters["frames_dropped"]
    sink.refuse = False
    sink.clear()
    advance(device, 4_000_000)

    # Assert
    errors = [e for e in sink.frames("ERROR") if e["code"] == C["CDRO_DEVICE_ERROR_TX_OVERFLOW"]]
    assert dropped > 10
    assert [e["detail"] for e in errors] == [dropped]
    sequences = [f.sequence for f in sink.frames()]
    assert sequences == list(range(sequences[0], sequences[0] + len(sequences)))


def test_that_a_reset_restarts_sequence_and_time_and_waits_stopped():
    device, sink = booted()
    command(device, "START")
    advance(device, 5_000_000)
    sink.clear()
    device.reset(C["CDRO_RESET_WATCHDOG"])
    advance(device, 8_000_000)
    assert sink.items[0][1] == b"\x00"
    hello = sink.frames()[0]
    assert hello.type == "HELLO" and hello.sequence == 0 and hello["device_time_ms"] == 300
    assert hello["reset_cause"] == C["CDRO_RESET_WATCHDOG"]
    assert not sink.frames("RANGE") and sink.frames("STATUS")[-1]["running"] == 0


def test_that_commands_during_discovery_wait_and_bytes_before_hello_are_lost():
    device, sink = make_device(scenario())
    advance(device, 100_000)
    command(device, "PING", {"nonce": 1})              # the firmware is not running yet
    advance(device, 350_000)
    command(device, "PING", {"nonce": 2})              # discovery: waits in the receive buffer
    assert not sink.frames("ACK")
    advance(device, 1_000_000)
    assert [a["value"] for a in sink.frames("ACK")] == [2]
    assert device.host_bytes_lost_booting == len(codec.encode_frame(codec.Frame("PING", 0, {"nonce": 1})))


def test_that_a_missing_pozyx_reports_an_error_and_refuses_start():
    device, sink = booted(scenario(device={"pozyx_present": False}))
    command(device, "SET_NODES", {"node_ids": [A]})
    command(device, "START")
    assert sink.frames("HELLO")[0]["capabilities"] == 0
    assert sink.frames("ERROR")[0]["code"] == C["CDRO_DEVICE_ERROR_POZYX_ABSENT"]
    assert sink.frames()[-1].type == "NACK" and sink.frames()[-1]["reason"] == C["CDRO_NACK_WRONG_STATE"]
