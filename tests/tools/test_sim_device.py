"""The simulated device against the "Device behaviour" contract of docs/protocol.md, driven in
simulated time in-process (the same device runs behind the pseudo-terminal; test_sim_pty.py
checks it end to end)."""
import collections
import json
import random
import struct

import pytest

from cdro_tools import codec
from cdro_tools.codec import CONSTANTS as C
from cdro_tools.simulation.device import SimDevice
from cdro_tools.simulation.scheduler import Scheduler
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


def test_that_ping_echoes_the_nonce_and_hello_request_gets_hello_and_the_node_list_without_ack():
    device, sink = booted()
    sink.clear()
    command(device, "PING", {"nonce": 0xDEADBEEF}, sequence=5)
    command(device, "HELLO_REQUEST", sequence=6)
    ack, hello, node_list = sink.frames()
    assert ack.type == "ACK" and ack["value"] == 0xDEADBEEF and ack["acked_sequence"] == 5
    assert hello.type == "HELLO" and hello["reset_cause"] == C["CDRO_RESET_POWER_ON"]
    # A host that opened the link of a running device learns the list it missed at boot.
    assert node_list.type == "NODE_LIST" and node_list["node_ids"] == device.nodes
    assert node_list["source"] == C["CDRO_NODE_SOURCE_DISCOVERY"]
    sink.clear()
    command(device, "SET_NODES", {"node_ids": device.nodes[:1]}, sequence=7)
    command(device, "HELLO_REQUEST", sequence=8)
    assert [f.type for f in sink.frames()] == ["ACK", "NODE_LIST", "HELLO", "NODE_LIST"]
    assert sink.frames()[-1]["source"] == C["CDRO_NODE_SOURCE_HOST"] and sink.frames()[-1]["node_ids"] == device.nodes


def test_that_hello_request_without_nodes_gets_hello_only():
    device, sink = booted(scenario(device={"discovery": False}))
    sink.clear()
    command(device, "HELLO_REQUEST", sequence=3)
    assert [f.type for f in sink.frames()] == ["HELLO"]


def test_that_golden_rejections_get_the_documented_answers(golden_dir):
    # Fixture: the decoder's golden rejections, sent as host commands, one status period apart
    vectors = json.loads((golden_dir / "vectors.json").read_text())["decode_errors"]
    expected = {"cobs": None, "short": None, "crc": None, "too_long": None, "version": "MALFORMED",
                "type": "UNKNOWN_TYPE", "length": "MALFORMED"}
    device, sink = booted()
    for vector in vectors:
        advance(device, device.now_us + 1_000_000)
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
            # not answered; reported by ERROR COMMAND, detail = the cdro_result_t as 16-bit two's complement
            detail = int(codec.Result[result.upper()]) & 0xFFFF
            assert [(a.type, a["code"], a["detail"], a["node_id"]) for a in answers] == \
                [("ERROR", C["CDRO_DEVICE_ERROR_COMMAND"], detail, 0)], vector["name"]
        else:
            assert [(a.type, a["reason"], a["nacked_type"], a["nacked_sequence"]) for a in answers] == \
                [("NACK", C[f"CDRO_NACK_{reason}"], vector["type"], vector["sequence"])], vector["name"]
        assert device.counters["commands_rejected"] == rejected_before + 1, vector["name"]


def raw_chunk(type_id, payload=b"", sequence=7, version=codec.PROTOCOL_VERSION, length=None, crc_xor=0):
    """A chunk with whatever header the test wants (and a good CRC unless crc_xor), with its delimiter."""
    raw = struct.pack("<BBHB", version, type_id, sequence, len(payload) if length is None else length) + payload
    return codec.cobs_encode(raw + struct.pack("<H", codec.crc16(raw) ^ crc_xor)) + b"\x00"


@pytest.mark.parametrize("name, chunk, reason", [
    ("host type, other version", raw_chunk(0x43, version=codec.PROTOCOL_VERSION + 1), "MALFORMED"),
    ("device-to-host type, payload not its layout", raw_chunk(0x04, b"\x01\x02\x03"), "MALFORMED"),
    ("unknown type, length field disagrees", raw_chunk(0x7E, b"\x01", length=3), "MALFORMED"),
    ("unknown type", raw_chunk(0x7E, b"\x01"), "UNKNOWN_TYPE"),
    ("device-to-host type, well formed", raw_chunk(0x06, struct.pack("<BHI", 0x45, 1, 0)), "UNKNOWN_TYPE"),
    ("device-to-host type, a value out of range", raw_chunk(0x07, struct.pack("<BHB", 0x45, 1, 99)), "UNKNOWN_TYPE"),
    ("host type, a value out of range", raw_chunk(0x42, struct.pack("<HBHBHB", 0, 1, 200, 9, 1000, 1)), "BAD_VALUE"),
])
def test_that_nacks_follow_the_documented_order(name, chunk, reason):
    device, sink = booted()
    sink.clear()
    device.receive(chunk)
    assert [(f.type, f["nacked_type"], f["nacked_sequence"], f["reason"]) for f in sink.frames()] == \
        [("NACK", codec.cobs_decode(chunk[:-1])[1], 7, C[f"CDRO_NACK_{reason}"])], name
    assert device.counters["commands_rejected"] == 1


def test_that_undecodable_chunks_are_reported_by_error_command_at_most_once_per_status_period():
    # Fixture
    device, sink = booted()
    bad_crc = raw_chunk(0x45, struct.pack("<I", 5), crc_xor=0x0100)
    bad_cobs = b"\x09\x01\x02\x00"
    sink.clear()

    # Test: a bad CRC, then a bad COBS chunk 0.2 s later, then nothing for 2.5 s
    first_us = device.now_us
    device.receive(bad_crc)
    advance(device, first_us + 200_000)
    device.receive(bad_cobs)
    advance(device, first_us + 2_500_000)

    # Assert: the first reported at once; the second held back until a status period has
    # passed (reported at the next step), with the detail of the latest rejection; no answers
    reports = [(t, f["detail"], f["node_id"]) for t, _, f in sink.items
               if f is not None and f.type == "ERROR" and f["code"] == C["CDRO_DEVICE_ERROR_COMMAND"]]
    assert [(d, n) for _, d, n in reports] == [(0xFFFC, 0), (0xFFFE, 0)]
    assert reports[0][0] == first_us and first_us + 1_000_000 <= reports[1][0] <= first_us + 1_400_000
    assert not sink.frames("NACK") and not sink.frames("ACK")
    assert device.counters["commands_rejected"] == 2


def test_that_a_device_to_host_type_is_nacked_unknown_type():
    device, sink = booted()
    sink.clear()
    command(device, "STATUS", {"uptime_ms": 0, "ranges_ok_direct": 0, "ranges_ok_remote": 0, "ranges_failed_direct": 0,
                               "ranges_failed_remote": 0, "retries": 0, "bus_errors": 0, "timeouts": 0,
                               "frames_sent": 0, "frames_dropped": 0, "commands_rejected": 0, "longest_loop_us": 0,
                               "free_ram_bytes": 0, "running": 0, "node_count": 0, "bus_recoveries": 0}, sequence=3)
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


def scheduler(nodes=(A, B, D), boost=2, mode=C["CDRO_SCHEDULE_ALL_PAIRS"]):
    sched = Scheduler()
    sched.configure(mode, boost)
    sched.set_nodes(OWN, list(nodes))
    return sched


def test_that_a_round_is_boost_passes_and_a_pair_with_a_moving_end_is_visited_in_every_pass():
    # Fixture: pairs 0 (O,A) 1 (O,B) 2 (O,D) 3 (A,B) 4 (A,D) 5 (B,D); B flagged moving, boost 3
    sched = scheduler(boost=3)
    moving = {B}.__contains__

    # Test: two rounds
    visits = [sched.next(moving) for _ in range(24)]

    # Assert: in pass k, position p when an end moves or p mod 3 = k
    one_round = [0, 1, 3, 5] + [1, 3, 4, 5] + [1, 2, 3, 5]
    assert visits == one_round * 2
    assert sched.pairs()[1] == (OWN, B) and sched.pairs()[3] == (A, B) and sched.pairs()[5] == (B, D)


def test_that_without_moving_nodes_every_pair_is_visited_once_per_round_in_the_pass_of_its_position():
    sched = scheduler(boost=4)
    assert [sched.next(lambda node: False) for _ in range(12)] == [0, 4, 1, 5, 2, 3] * 2


def test_that_a_pair_whose_slots_fail_backs_off_0_1_3_4_4_rounds_and_a_success_resets_it():
    # Fixture: direct pairs 0 (O,A), 1 (O,B); pair 1 fails every slot
    sched = scheduler(nodes=(A, B), boost=1, mode=C["CDRO_SCHEDULE_DIRECT_ONLY"])
    rounds_of_pair_1 = []
    round_ = 0

    # Test: 30 rounds (pair 0 is visited once in each)
    while round_ < 30:
        p = sched.next(lambda node: False)
        if p == 0:
            round_ += 1
        else:
            rounds_of_pair_1.append(round_)
        sched.slot_done(p, ok=p == 0)

    # Assert: sits out 0, 1, 3, 4, 4, ... further rounds after its 1st, 2nd, 3rd, 4th, 5th failed slot
    assert rounds_of_pair_1 == [1, 2, 4, 8, 13, 18, 23, 28]
    sched.slot_done(1, ok=True)
    assert sched.states[1].failed_slots == 0 and sched.states[1].sitting_out == 0


def test_that_a_pair_with_a_moving_end_stays_in_after_one_failed_slot_and_sits_out_after_two():
    # Fixture: boost 3, B moving: pair 1 (O,B) is due in every pass
    sched = scheduler(boost=3)
    moving = {B}.__contains__
    assert [sched.next(moving) for _ in range(2)] == [0, 1]

    # Test: its first slot fails (n = 1: no further rounds, so it does not sit out)
    sched.slot_done(1, ok=False)
    rest_of_round = [sched.next(moving) for _ in range(2 + 4 + 4)]

    # Assert: still visited in passes 1 and 2 of this round
    assert rest_of_round == [3, 5] + [1, 3, 4, 5] + [1, 2, 3, 5]

    # Test: its next slot (pass 1 of the next round) fails too (n = 2: one further round)
    assert [sched.next(moving) for _ in range(5)] == [0, 1, 3, 5, 1]
    sched.slot_done(1, ok=False)
    after = [sched.next(moving) for _ in range(3 + 3 + 3 + 3 + 3)]

    # Assert: it sits out the rest of this round and the whole next round, then comes back
    assert after == [3, 4, 5] + [2, 3, 5] + [0, 3, 5] + [3, 4, 5] + [2, 3, 5]
    assert sched.next(moving) == 0 and sched.next(moving) == 1


def test_that_the_device_backs_off_a_dead_link_and_keeps_ranging_the_others():
    # Fixture: E is 150 m away: direct ranges to it time out
    E = 0x6005
    sc = scenario(nodes=[{"id": OWN, "x": 0, "y": 0}, {"id": A, "x": 5, "y": 0}, {"id": E, "x": 150, "y": 0}],
                  device={"discovery": False}, schedule={"mode": "direct_only", "motion_poll_ms": 0, "max_retries": 1})
    device, sink = booted(sc)
    command(device, "SET_NODES", {"node_ids": [A, E]})
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    measured = []
    measure = device.uwb.measure
    device.uwb.measure = lambda a, b, t_s, remote: (measured.append(b), measure(a, b, t_s, remote))[1]
    command(device, "START")

    # Test
    advance(device, 4_000_000)

    # Assert: slots to E (2 attempts each) in rounds 0, 1, 3, 7, 12, ... of the rounds that range A
    rounds, round_ = [], -1
    for index, node in enumerate(measured):
        if node == A:
            round_ += 1
        elif index == 0 or measured[index - 1] != E:
            rounds.append(round_)
    assert len(measured) > 40 and rounds[:5] == [0, 1, 3, 7, 12]
    assert device.counters["ranges_failed_direct"] == 2 * len(rounds)
    assert device.counters["ranges_ok_direct"] == measured.count(A)


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


def test_that_motion_follows_the_80_40_mg_hysteresis_and_is_reported_on_change():
    # Fixture: D is carried from 10 s to 14 s
    sc = scenario(motion=[{"node": D, "start_s": 10, "end_s": 14, "waypoints": [[4, 5]]}], duration_s=40)
    device, sink = booted(sc)
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    command(device, "START")

    # Test
    advance(device, 30_000_000)

    # Assert
    motion = [(f["device_time_ms"] / 1000, f["moving"], f["reason"]) for f in sink.frames("MOTION")
              if f["node_id"] == D]
    changes = [(t, moving) for t, moving, reason in motion if reason == C["CDRO_MOTION_REASON_CHANGE"]]
    assert [m for _, m in changes] == [1, 0]
    assert 10.0 <= changes[0][0] < 10.5                    # within a poll or two
    # still again after the 8-sample window has cleared and 16 samples stayed at or below 40 mg
    assert 14.0 + (8 + 16 - 3) * 0.2 <= changes[1][0] < 14.0 + (8 + 16 + 2) * 0.2
    # ranges with D carry the moving flag only while D is flagged
    flagged = [f["device_time_ms"] / 1000 for f in sink.frames("RANGE") if f["flags"] & C["CDRO_RANGE_FLAG_MOVING"]]
    assert flagged and all(changes[0][0] <= t <= changes[1][0] + 0.2 for t in flagged)
    # the own node and the tags report; anchors are asked their kind once, then left alone
    assert {f["node_id"] for f in sink.frames("MOTION")} == {OWN, D}
    assert all(not state.tag and state.kind_known for node, state in device.motion.items() if node in (A, B))


def test_that_periodic_motion_follows_one_device_wide_5_s_timer_started_at_start():
    # Fixture: D is carried from 10 s to 14 s (its changes must not shift its periodic reports)
    sc = scenario(motion=[{"node": D, "start_s": 10, "end_s": 14, "waypoints": [[4, 5]]}], duration_s=40)
    device, sink = booted(sc)
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    start_s = device.now_us / 1e6
    command(device, "START")

    # Test
    advance(device, 32_000_000)

    # Assert: PERIODIC frames come in bursts, one report per accelerometer node: the first
    # samples after START, then the next sample of every node once the timer has run 5 s
    frames = [(t / 1e6, f["node_id"], f["reason"]) for t, _, f in sink.items if f is not None and f.type == "MOTION"]
    periodic = [(t, node) for t, node, reason in frames if reason == C["CDRO_MOTION_REASON_PERIODIC"]]
    bursts = []
    for t, node in periodic:
        if not bursts or t - bursts[-1][0][0] > 1.0:
            bursts.append([])
        bursts[-1].append((t, node))
    starts = [burst[0][0] for burst in bursts]
    assert start_s <= starts[0] < start_s + 0.3
    assert len(bursts) == 7 and all(4.95 <= b - a <= 5.3 for a, b in zip(starts, starts[1:])), starts
    changes = [t for t, node, reason in frames if node == D and reason == C["CDRO_MOTION_REASON_CHANGE"]]
    for burst in bursts:
        nodes = [node for _, node in burst]
        assert nodes.count(OWN) == 1 and nodes.count(D) <= 1 and burst[-1][0] - burst[0][0] < 0.3
        if D not in nodes:                  # D's sample in that burst was a change, reported as such
            assert any(abs(t - burst[0][0]) < 0.3 for t in changes), burst


def test_that_the_reported_norm_is_capped_at_16_g():
    device, sink = booted(scenario(device={"discovery": False}))
    device.world.accel_norm_mg = lambda node_id, t_s, rng: 20000
    command(device, "SET_NODES", {"node_ids": [A]})
    command(device, "START")
    advance(device, 1_500_000)
    first = sink.frames("MOTION")[0]
    assert (first["node_id"], first["accel_norm_mg"], first["deviation_mg"], first["moving"]) == (OWN, 16000, 19000, 1)
    assert first["reason"] == C["CDRO_MOTION_REASON_CHANGE"]


def test_that_a_moving_node_becomes_still_after_16_samples_below_40_mg():
    # Fixture: the own node reads 1100 mg once, then exactly 1039 mg
    samples = []
    device, sink = booted(scenario(device={"discovery": False}))
    device.world.accel_norm_mg = lambda node_id, t_s, rng: (samples.append(t_s), 1100 if len(samples) == 1 else 1039)[1]
    command(device, "SET_NODES", {"node_ids": [A]})
    command(device, "START")

    # Test
    advance(device, 8_000_000)

    # Assert: moving at the 1st sample; the window holds 100 mg for 8 samples, then 16 at 39 mg
    changes = [(f["moving"], f["deviation_mg"]) for f in sink.frames("MOTION")
               if f["reason"] == C["CDRO_MOTION_REASON_CHANGE"]]
    assert changes == [(1, 100), (0, 39)]
    still_ms = [f["device_time_ms"] for f in sink.frames("MOTION") if f["moving"] == 0][0]
    assert int(samples[8 + 16 - 1] * 1000) - device.boot_us // 1000 == still_ms


def test_that_a_moving_node_at_exactly_40_mg_stays_moving():
    # Fixture: the own node reads 1100 mg once, then exactly 1040 mg
    samples = []
    device, sink = booted(scenario(device={"discovery": False}))
    device.world.accel_norm_mg = lambda node_id, t_s, rng: (samples.append(t_s), 1100 if len(samples) == 1 else 1040)[1]
    command(device, "SET_NODES", {"node_ids": [A]})
    command(device, "START")

    # Test
    advance(device, 8_000_000)

    # Assert: 40 mg is not below 40 mg, so it never becomes still
    changes = [f["moving"] for f in sink.frames("MOTION") if f["reason"] == C["CDRO_MOTION_REASON_CHANGE"]]
    assert changes == [1]


def test_that_a_node_that_does_not_answer_gets_one_error_accel_and_its_polls_back_off():
    # Fixture: 0x7777 is not in the network; A is an anchor
    device, sink = booted(scenario(device={"discovery": False}))
    reads = collections.Counter()
    remote_read = device._remote_read
    device._remote_read = lambda node_id: (reads.update([node_id]), remote_read(node_id))[1]
    command(device, "SET_NODES", {"node_ids": [A, 0x7777]})
    command(device, "SET_SCHEDULE", {"slot_period_ms": 0, "mode": 0, "motion_poll_ms": 200, "moving_boost": 2,
                                     "status_period_ms": 1000, "max_retries": 0})
    command(device, "START")

    # Test: 5 s, 25 poll periods
    advance(device, device.now_us + 5_000_000)

    # Assert: polls of 0x7777 in periods 0, 1, 3, 7, 12, 17, 22; A asked once (an anchor)
    errors = [(e["code"], e["detail"], e["node_id"]) for e in sink.frames("ERROR")
              if e["code"] == C["CDRO_DEVICE_ERROR_ACCEL"]]
    assert errors == [(C["CDRO_DEVICE_ERROR_ACCEL"], 0x12, 0x7777)]
    assert reads == {A: 1, 0x7777: 7}


def test_that_remote_timeouts_are_counted_and_reported_at_most_once_per_status_period():
    # Fixture: A and E are 120 m apart, both 60 m from the own node: (A, E) ranged by A times out
    E = 0x6005
    sc = scenario(nodes=[{"id": OWN, "x": 0, "y": 0}, {"id": A, "x": -60, "y": 0}, {"id": E, "x": 60, "y": 0}],
                  device={"discovery": False}, schedule={"motion_poll_ms": 0, "max_retries": 1})
    device, sink = booted(sc)
    command(device, "SET_NODES", {"node_ids": [A, E]})
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    command(device, "START")

    # Test
    advance(device, 12_000_000)

    # Assert: ERROR TIMEOUT (detail DO_RANGING 0xB5) at least a status period apart; STATUS
    # counts every timeout; ERROR RANGING for the pair has no Pozyx code (detail 0)
    errors = sink.frames("ERROR")
    timeouts = [e["device_time_ms"] for e in errors if e["code"] == C["CDRO_DEVICE_ERROR_TIMEOUT"]]
    assert all(e["detail"] == 0xB5 and e["node_id"] == 0 for e in errors if e["code"] == C["CDRO_DEVICE_ERROR_TIMEOUT"])
    assert len(timeouts) >= 5 and all(b - a >= 1000 for a, b in zip(timeouts, timeouts[1:]))
    assert device.counters["timeouts"] > len(timeouts)
    assert sink.frames("STATUS")[-1]["timeouts"] > len(timeouts)
    ranging = [(e["detail"], e["node_id"]) for e in errors if e["code"] == C["CDRO_DEVICE_ERROR_RANGING"]]
    assert ranging == [(0, E)]


def test_that_set_schedule_keeps_the_status_timer_and_motion_state_unless_they_change():
    # Fixture: D carried from 2 s to 6 s, flagged moving at 4 s
    sc = scenario(motion=[{"node": D, "start_s": 2, "end_s": 6, "waypoints": [[4, 5]]}])
    device, sink = booted(sc)
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    command(device, "START")
    advance(device, 4_000_000)
    assert device.flagged_moving(D)
    due_us = device.next_status_us

    # Test 1: another poll period and boost, the same status period
    command(device, "SET_SCHEDULE", {**sc.schedule.fields(), "motion_poll_ms": 100, "moving_boost": 3})

    # Assert 1: the status timer and the motion state are kept
    assert device.next_status_us == due_us and device.flagged_moving(D)

    # Test 2: another status period
    command(device, "SET_SCHEDULE", {**sc.schedule.fields(), "status_period_ms": 500})

    # Assert 2: the next STATUS one new period from now
    assert device.next_status_us == device.now_us + 500_000


def test_that_set_nodes_restarts_the_listed_nodes_still_and_clears_the_pair_streaks():
    # Fixture: D carried from 2 s to 6 s, flagged moving at 4 s; a streak on (O, A)
    sc = scenario(motion=[{"node": D, "start_s": 2, "end_s": 6, "waypoints": [[4, 5]]}])
    device, sink = booted(sc)
    command(device, "SET_SCHEDULE", sc.schedule.fields())
    command(device, "START")
    advance(device, 4_000_000)
    assert device.flagged_moving(D)
    device.scheduler.states[0].failed_attempts = 4
    sink.clear()

    # Test
    command(device, "SET_NODES", {"node_ids": [A, B, D]})
    advance(device, 4_500_000)

    # Assert: D starts still again, its first sample reported PERIODIC (or a change); the
    # own node keeps its state (no first-sample report); streaks cleared
    assert all(state.failed_attempts == 0 for state in device.scheduler.states[1:])
    first_d = [f for f in sink.frames("MOTION") if f["node_id"] == D][0]
    assert (first_d["moving"], first_d["reason"]) in ((0, C["CDRO_MOTION_REASON_PERIODIC"]),
                                                      (1, C["CDRO_MOTION_REASON_CHANGE"]))
    assert not [f for f in sink.frames("MOTION") if f["node_id"] == OWN]


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
    last_sequence = sink.frames()[-1].sequence

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
    assert sequences[0] == last_sequence + dropped + 1      # the drops show as a gap


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
    hello, error = sink.frames()[:2]
    assert hello.type == "HELLO"
    assert (hello["node_id"], hello["pozyx_firmware"], hello["capabilities"]) == (0xFFFF, 0, 0)
    assert error.type == "ERROR" and (error["code"], error["node_id"]) == (C["CDRO_DEVICE_ERROR_POZYX_ABSENT"], 0)
    assert sink.frames()[-1].type == "NACK" and sink.frames()[-1]["reason"] == C["CDRO_NACK_WRONG_STATE"]
    # the own node is 0xFFFF: a list naming it is refused
    command(device, "SET_NODES", {"node_ids": [A, 0xFFFF]})
    assert sink.frames()[-1].type == "NACK" and sink.frames()[-1]["reason"] == C["CDRO_NACK_BAD_VALUE"]


def test_that_motion_state_is_kept_across_stop_and_start_and_the_first_sample_is_periodic():
    # Fixture: the own node shakes (1100 mg) all the time, so it is moving
    device, sink = booted(scenario(device={"discovery": False}))
    device.world.accel_norm_mg = lambda node_id, t_s, rng: 1100
    command(device, "SET_NODES", {"node_ids": [A]})
    command(device, "START")
    advance(device, 3_000_000)
    assert device.flagged_moving(device.own_id)

    # Test: stop, then start again
    command(device, "STOP")
    advance(device, 4_000_000)
    before = len(sink.frames("MOTION"))
    command(device, "START")
    advance(device, 5_000_000)

    # Assert: the first MOTION after START is PERIODIC and still says moving (no reset to still)
    after = sink.frames("MOTION")[before:]
    assert after and after[0]["reason"] == C["CDRO_MOTION_REASON_PERIODIC"] and after[0]["moving"] == 1
    assert all(f["reason"] != C["CDRO_MOTION_REASON_CHANGE"] for f in after)
