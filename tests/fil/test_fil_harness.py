"""Firmware in the loop, end to end: the unmodified Uno .elf runs in simavr (cdro-fil) against the
simulated Pozyx network of tests/fil/office_60s.yaml (7 nodes, one carried, faults), its UART on
a pseudo-terminal, and the real service (cdro-service-harness: cdro-hostd's service with a
recording stand-in for the engine) reads that port as its serial device.

One run of 64 simulated seconds (paced to the wall clock) is shared by the tests below; each
checks one part of what the issue asks: the handshake and the host's commands, ranges of every
pair kind against the truth, the carried node's MOTION, the counters and ERROR frames against
the faults injected, and the figures cdro-fil measured.
"""
from __future__ import annotations

import os
import pathlib

import pytest

from cdro_tools.codec import CONSTANTS as C

from fil_support import FilRun, tag_ids, truth_disagreement_m

HERE = pathlib.Path(__file__).resolve().parent
SCENARIO = HERE / "office_60s.yaml"

# Stated bounds.
RANGE_BOUND_M = 0.20        # |RANGE - true distance at its device time|: 6.7 sigma of the 30 mm noise,
                            # plus the carried node's 1 m/s over the ~10 ms between ranging and report
DEVICE_CLOCK_SLACK_S = 0.01  # millis() against simulated time (Arduino's timer0 runs ~2 ms behind at most)
STEP_S = 0.8                 # a failed attempt is counted within one step of the fault (worst step 0.73 s)
STATUS_PERIOD_S = 1.0


def seed() -> int:
    value = int(os.environ.get("CDRO_TEST_SEED", "20261122"))
    print(f"firmware in the loop: seed {value} (replay with CDRO_TEST_SEED={value})")
    return value


@pytest.fixture(scope="module")
def run(build_dir, avr_build_dir, tmp_path_factory):
    fil = FilRun(build_dir, avr_build_dir, tmp_path_factory.mktemp("fil"), SCENARIO,
                 fil_args=["--seed", str(seed())])
    try:
        fil.run()
    finally:
        fil.kill()
    s = fil.summary
    print(f"cdro-fil: {s['simulated_s']} s simulated, {s['rangings']['per_second']:.1f} ranges/s, worst loop "
          f"{s['loop']['worst_cycles']} cycles, {s['uart']['tx_bytes_per_s']:.0f} B/s to the host")
    return fil


def status_frames(run):
    return run.device("STATUS")


def last_connected_health(run):
    connected = [h for h in run.health() if h["link"] == "connected"]
    assert connected, "the link never reached connected:\n" + run.host_log()
    return connected[-1]


# ---- the handshake and the host's commands -----------------------------------------------------

def test_handshake_commands_and_keepalive(run):
    own, remotes = run.scenario.own_id, run.scenario.remote_ids
    device = run.device()
    assert run.rejected == {}, f"chunks that did not decode: {run.rejected}"

    hello = device[0]
    assert hello.type == "HELLO" and hello.frame.sequence == 0, "the host saw the boot from its first frame"
    assert hello["node_id"] == own
    assert hello["protocol_version"] == C["CDRO_PROTOCOL_VERSION"] and hello["layout_hash"] == C["CDRO_LAYOUT_HASH"]
    caps = (C["CDRO_CAP_DIRECT_RANGING"] | C["CDRO_CAP_REMOTE_RANGING"] | C["CDRO_CAP_REMOTE_ACCEL"]
            | C["CDRO_CAP_DISCOVERY"] | C["CDRO_CAP_LOCAL_ACCEL"]  # the own node is a tag
            | C["CDRO_CAP_POZYX_SETUP"])
    assert hello["pozyx_tries"] == 1, "the Pozyx answered at the first try"
    assert hello["capabilities"] == caps
    assert hello["max_nodes"] == 10 and hello["reset_cause"] == C["CDRO_RESET_POWER_ON"]
    # Every node's Pozyx firmware and UWB settings, read at start and reported on the host too.
    infos = run.device("NODE_INFO")
    assert {i["node_id"] for i in infos} == {own, *remotes}
    assert all(i["result"] == C["CDRO_NODE_INFO_READ"] and i["mismatch"] == 0 for i in infos)
    host_log = run.host_log()
    assert "Pozyx firmware 1.1" in host_log and "not our frames" not in host_log
    for node in (own, *remotes):
        assert f"serial: node 0x{node:04X}: Pozyx firmware 1.1, channel 5" in host_log

    lists = run.device("NODE_LIST")
    assert [frame["source"] for frame in lists] == [C["CDRO_NODE_SOURCE_DISCOVERY"], C["CDRO_NODE_SOURCE_HOST"]]
    assert sorted(lists[0]["node_ids"]) == sorted(remotes), "discovery found every node in range"
    assert lists[1]["node_ids"] == remotes, "SET_NODES took the host's list"

    sent = run.sent()
    kinds = [f.type for f in sent]
    assert kinds[:3] == ["SET_NODES", "SET_SCHEDULE", "START"], kinds[:6]
    assert set(kinds[3:]) == {"PING"}, "after the configuration, only keepalives: no resend, no re-handshake"
    pings = sent[3:]
    assert len(pings) >= 50, f"a PING a second over {run.scenario.duration_s} s, got {len(pings)}"

    # Every command got exactly one ACK naming it; every PING's ACK echoes its nonce; no NACK.
    acks = {(a["acked_type"], a["acked_sequence"]): a for a in run.device("ACK")}
    assert not run.device("NACK")
    for command in sent:
        ack = acks.get((command.frame.type_id, command.frame.sequence))
        if ack is None and command is sent[-1]:
            continue  # the last PING may have been in flight when the simulation ended
        assert ack is not None, f"no ACK for {command.type} seq {command.frame.sequence}"
        assert ack["value"] == (command["nonce"] if command.type == "PING" else 0)
    assert len(run.device("ACK")) >= len(sent) - 1

    statuses = status_frames(run)
    running = [s for s in statuses if s.host_time_us > run.device("ACK")[2].host_time_us]
    assert running and all(s["running"] == 1 and s["node_count"] == len(remotes) for s in running)

    health = last_connected_health(run)
    counters = health["counters"]
    assert counters["handshakes"] == 1
    for name in ("nacks", "command_timeouts", "pings_missed", "device_resets",
                 "chunks_rejected", "frames_lost", "sequence_gaps", "unknown_node_frames", "value_errors"):
        assert counters[name] == 0, f"{name} = {counters[name]}"
    # Connected from the handshake until the simulation ended (then the port went away).
    lines = run.health()
    first = next(i for i, h in enumerate(lines) if h["link"] == "connected")
    last = max(i for i, h in enumerate(lines) if h["link"] == "connected")
    assert all(h["link"] == "connected" for h in lines[first:last + 1])
    assert (lines[last]["t_s"] + run.host_t_to_sim_s()) > run.scenario.duration_s - 1.5


# ---- ranges: every pair kind, against the truth ------------------------------------------------

def test_ranges_cover_every_pair_and_agree_with_the_truth(run):
    own, remotes = run.scenario.own_id, run.scenario.remote_ids
    ranges = run.device("RANGE")
    pairs = {}
    for r in ranges:
        pairs.setdefault((r["from_id"], r["to_id"]), []).append(r)
    direct = [(own, n) for n in remotes]
    remote = [(a, b) for i, a in enumerate(remotes) for b in remotes[i + 1:]]
    assert set(pairs) == set(direct) | set(remote), "exactly the pairs of ALL_PAIRS, ranged by the first node"
    for pair in direct + remote:
        assert len(pairs[pair]) >= 20, f"pair {pair[0]:#06x}-{pair[1]:#06x}: {len(pairs[pair])} ranges"
        remote_flag = pair in remote
        assert all(bool(r["flags"] & C["CDRO_RANGE_FLAG_REMOTE"]) == remote_flag for r in pairs[pair])

    # The truth is the tools' world model of what cdro-fil read (cdro-fil --print-scenario), and
    # cdro-fil's own truth file agrees with it at every sample (0.1 mm written).
    disagreement_m, samples = truth_disagreement_m(run.world, run.truth_path)
    assert samples >= 7 * 600 and disagreement_m <= 0.001, (samples, disagreement_m)
    worst = 0.0
    for r in ranges:
        t = r["device_time_ms"] / 1000.0
        error = abs(r["distance_mm"] / 1000.0 - run.world.distance_m(r["from_id"], r["to_id"], t))
        worst = max(worst, error)
        assert error <= RANGE_BOUND_M, f"RANGE {r.frame.fields} is {error:.3f} m off the truth"
    print(f"{len(ranges)} ranges, worst {worst * 1000:.0f} mm off the truth (bound {RANGE_BOUND_M * 1000:.0f} mm)")

    # Each RANGE is a ranging the simulated network performed, reported as is (same pair and
    # millimetres, a little later on the device clock); the network's good rangings that never
    # became a RANGE are the few a fault cut off after the measurement.
    performed = {}
    for row in run.sim_ranges:
        if row["result"] == "ok":
            key = (int(row["from"]), int(row["to"]), int(row["distance_mm"]))
            performed.setdefault(key, []).append(float(row["t"]))
    for r in ranges:
        key = (r["from_id"], r["to_id"], r["distance_mm"])
        times = performed.get(key, [])
        t = r["device_time_ms"] / 1000.0
        match = [x for x in times if t - 0.8 <= x <= t + DEVICE_CLOCK_SLACK_S]
        assert match, f"RANGE {r.frame.fields} matches no ranging of the simulated network"
        times.remove(match[0])
    unreported = sum(len(v) for v in performed.values())
    faults = sum(run.summary["faults_injected"].values())
    assert unreported <= faults + 1, f"{unreported} good rangings never reported ({faults} faults injected)"
    assert run.summary["rangings"]["direct"] + run.summary["rangings"]["remote"] == len(run.sim_ranges) - \
        sum(1 for row in run.sim_ranges if row["result"] == "garbage")

    # STATUS counts exactly the RANGE frames sent before it.
    last = status_frames(run)[-1]
    before = [r for r in ranges if r.frame.sequence < last.frame.sequence]
    assert last["ranges_ok_direct"] == sum(1 for r in before if not r["flags"] & C["CDRO_RANGE_FLAG_REMOTE"])
    assert last["ranges_ok_remote"] == sum(1 for r in before if r["flags"] & C["CDRO_RANGE_FLAG_REMOTE"])
    # The consumer got every one of them.
    assert sum(1 for line in run.received if line["kind"] == "range") == len(ranges)


# ---- the carried node ----------------------------------------------------------------------------

def test_carried_node_is_reported_moving_then_still(run):
    (stretch,) = run.summary["motion"]
    mover, start_s, end_s = stretch["node"], stretch["from_s"], stretch["to_s"]
    motions = run.device("MOTION")
    changes = [m for m in motions if m["reason"] == C["CDRO_MOTION_REASON_CHANGE"]]
    assert [(m["node_id"], m["moving"]) for m in changes] == [(mover, 1), (mover, 0)], \
        "one MOVING and one STILL, for the carried node only"
    moving_s = changes[0]["device_time_ms"] / 1000.0
    still_s = changes[1]["device_time_ms"] / 1000.0
    # MOVING within the first samples of the walk (the poll runs every 200 ms); STILL once the
    # 8-sample window has cleared and 16 quiet samples followed (24 polls, 4.8 s, plus jitter).
    assert start_s - DEVICE_CLOCK_SLACK_S <= moving_s <= start_s + 1.0, (start_s, moving_s)
    assert end_s + 22 * 0.2 <= still_s <= end_s + 30 * 0.21 + 0.5, (end_s, still_s)

    # Every tag reports PERIODIC samples every 5 s; anchors are never polled after their kind.
    for node in tag_ids(run.scenario):
        periodic = [m for m in motions if m["node_id"] == node and m["reason"] == C["CDRO_MOTION_REASON_PERIODIC"]]
        assert len(periodic) >= 10, f"{node:#06x}: {len(periodic)} periodic MOTION"
        if node != mover:
            assert all(m["moving"] == 0 for m in motions if m["node_id"] == node)
    assert {m["node_id"] for m in motions} == set(tag_ids(run.scenario))

    # Between the two, the carried node's pairs carry MOVING and are ranged about boost (2)
    # times as often per pair as the others; outside, no RANGE carries MOVING.
    ranges = run.device("RANGE")
    with_mover = lambda r: mover in (r["from_id"], r["to_id"])  # noqa: E731
    inside = [r for r in ranges if moving_s + 0.1 < r["device_time_ms"] / 1000.0 < still_s - 0.1]
    assert inside
    for r in inside:
        assert bool(r["flags"] & C["CDRO_RANGE_FLAG_MOVING"]) == with_mover(r), r.frame.fields
    outside = [r for r in ranges if not moving_s - 0.1 <= r["device_time_ms"] / 1000.0 <= still_s + 0.1]
    assert not any(r["flags"] & C["CDRO_RANGE_FLAG_MOVING"] for r in outside)
    n = len(run.scenario.remote_ids)
    mover_pairs, pairs = n, n + n * (n - 1) // 2   # pairs with the mover: own-mover and mover-other
    moving_rate = sum(1 for r in inside if with_mover(r)) / mover_pairs
    still_rate = sum(1 for r in inside if not with_mover(r)) / (pairs - mover_pairs)
    ratio = moving_rate / still_rate
    print(f"pairs with the carried node ranged {ratio:.2f} times as often (boost 2)")
    assert 1.5 <= ratio <= 2.5


# ---- counters and ERROR frames against the faults ------------------------------------------------

def fault_windows(run) -> list[tuple[float, float]]:
    """Simulated-time intervals in which a fault may make an attempt fail or a counter move."""
    windows = []
    for e in run.summary["fault_events"]:
        if e["kind"] == "power_off":
            windows.append((e["at_s"], e["at_s"] + e["duration_s"] + STEP_S))
        else:
            assert e["injected"] == e["count"], f"{e['kind']} at {e['at_s']} s: {e['injected']} of {e['count']}"
            windows.append((e["first_injected_s"], e["last_injected_s"] + STEP_S))
    return windows


def test_counters_and_errors_agree_with_the_faults(run):
    s = run.summary
    assert s["faults_injected"] == s["faults_armed"], "every fault armed was injected"
    assert s["protocol_violations"] == 0
    statuses = status_frames(run)
    final = statuses[-1]

    # Bus: every NACK is one failed transaction, counted once; ERROR BUS reports them (at most
    # one per status period) and only then.
    nacks = s["faults_injected"]["nack_address"] + s["faults_injected"]["nack_write"]
    assert final["bus_errors"] == nacks
    nack_events = [e for e in s["fault_events"] if e["kind"] in ("nack_address", "nack_write")]
    errors = run.device("ERROR")
    bus = [e for e in errors if e["code"] == C["CDRO_DEVICE_ERROR_BUS"]]
    assert bus
    for e in bus:
        t = e["device_time_ms"] / 1000.0
        assert any(n["first_injected_s"] - DEVICE_CLOCK_SLACK_S <= t <= n["last_injected_s"] + 2 * STATUS_PERIOD_S
                   for n in nack_events), f"ERROR BUS at {t} s, no NACK near"

    # Garbage and stale results: the network performed them, the firmware rejected them all.
    assert s["rangings"]["garbage"] == s["faults_injected"]["garbage_range"]
    assert s["rangings"]["stale"] == s["faults_injected"]["stale_range"]
    assert all(r["distance_mm"] < 200_000 for r in run.device("RANGE"))
    assert final["timeouts"] >= s["faults_injected"]["no_completion"]
    assert final["frames_dropped"] == 0 and final["commands_rejected"] == 0

    # Outside the faults' windows no attempt failed, no retry ran, no bus error or timeout: the
    # failure counters move only where a fault was.
    windows = fault_windows(run)
    moving = ("ranges_failed_direct", "ranges_failed_remote", "retries", "bus_errors", "timeouts")
    for before, after in zip(statuses, statuses[1:]):
        t0, t1 = before["uptime_ms"] / 1000.0, after["uptime_ms"] / 1000.0
        if any(a < t1 + DEVICE_CLOCK_SLACK_S and t0 - DEVICE_CLOCK_SLACK_S < b for a, b in windows):
            continue
        for name in moving:
            assert after[name] == before[name], f"{name} moved in ({t0}, {t1}] s with no fault there"
    assert final["ranges_failed_direct"] + final["ranges_failed_remote"] > 0

    # The anchor powered off: no RANGE with it while off, its attempts fail and are counted, its
    # pairs' streaks end in ERROR RANGING (node_id = the pair's responding node), and every one
    # of its pairs ranges again within the backoff bound once it is back.
    (off,) = [e for e in s["fault_events"] if e["kind"] == "power_off"]
    node, off_s, on_s = off["node"], off["at_s"], off["at_s"] + off["duration_s"]
    remotes = run.scenario.remote_ids
    ranges = run.device("RANGE")
    with_node = [r for r in ranges if node in (r["from_id"], r["to_id"])]
    assert not [r for r in with_node if off_s + STEP_S < r["device_time_ms"] / 1000.0 < on_s]
    at = lambda t: max((x for x in statuses if x["uptime_ms"] / 1000.0 <= t), key=lambda x: x["uptime_ms"])  # noqa: E731
    first, last = at(off_s), at(on_s)
    assert last["ranges_failed_direct"] - first["ranges_failed_direct"] >= 2, "the direct pair's slots failed"
    assert last["ranges_failed_remote"] - first["ranges_failed_remote"] >= 2 * (len(remotes) - 1)
    assert last["timeouts"] > first["timeouts"]
    ranging_errors = [e for e in errors if e["code"] == C["CDRO_DEVICE_ERROR_RANGING"]]
    assert ranging_errors
    responders = {node} | {r for r in remotes[remotes.index(node) + 1:]}  # (node, later) pairs name the later one
    for e in ranging_errors:
        assert off_s <= e["device_time_ms"] / 1000.0 <= on_s + STEP_S, e.frame.fields
        assert e["node_id"] in responders, e.frame.fields
    assert node in {e["node_id"] for e in ranging_errors}
    pairs = [(run.scenario.own_id, node)] + [(a, b) for i, a in enumerate(remotes) for b in remotes[i + 1:]
                                          if node in (a, b)]
    back_bound_s = 8.0  # 4 whole rounds of backoff (under 1 s each here) and the round under way
    for a, b in pairs:
        assert any(on_s < r["device_time_ms"] / 1000.0 <= on_s + back_bound_s
                   for r in with_node if (r["from_id"], r["to_id"]) == (a, b)), f"pair {a:#06x}-{b:#06x} not back"
    # An anchor is not polled, so its silence raised no ERROR ACCEL of its own.
    assert not [e for e in errors if e["code"] == C["CDRO_DEVICE_ERROR_ACCEL"] and e["node_id"] == node]

    # The service saw it all as valid frames: nothing invalid reached the consumer.
    counters = last_connected_health(run)["counters"]
    assert counters["value_errors"] == 0 and counters["chunks_rejected"] == 0


# ---- what cdro-fil measured ------------------------------------------------------------------------

def test_measurements_are_consistent(run):
    s = run.summary
    frequency = s["frequency_hz"]
    assert s["exit_reason"] == "duration" and s["avr_resets"] == 0
    # It ends at the first frame boundary after its duration (a frame takes 6.2 ms at most).
    assert run.scenario.duration_s <= s["simulated_s"] <= run.scenario.duration_s + 0.1
    assert s["cycles"] == pytest.approx(s["simulated_s"] * frequency, abs=frequency * 0.002)

    # Paced to the wall clock, never ahead of it: device time maps onto host time with no more
    # error than the lag cdro-fil measured (plus a frame's time on the wire and the host's read).
    assert s["wall_s"] >= s["simulated_s"]
    offset_s = run.host_t_to_sim_s()
    slack_s = s["max_lag_ms"] / 1000.0 + 0.05
    for line in run.received:
        if line["kind"] == "range":
            mapped_s = (line["t_us"] - run.capture_created_us) / 1e6 + offset_s
            assert abs(mapped_s - line["device_time_ms"] / 1000.0) <= slack_s, line

    # Throughput of the schedule: ALL_PAIRS over 6 remote nodes with the real device's timings
    # (pozyx.model realistic: ~45 ms a direct range, ~65 ms a remote one, accelerometer polls of
    # 3 tags between them): a round of 21 pairs in ~1.4 s, ~14 ranges/s.
    assert s["rangings"]["per_second"] >= 12.0
    assert s["pozyx_model"]["model"] == "realistic"

    # The main loop as timed from outside (PC at loop()) against the firmware's own STATUS
    # longest_loop_us, which times the step inside it with micros() (4 us resolution).
    loop = s["loop"]
    longest_us = max(x["longest_loop_us"] for x in status_frames(run))
    assert loop["iterations"] > 1000
    assert longest_us <= loop["worst_us"] + 8
    assert longest_us >= loop["worst_us"] - 200, (longest_us, loop["worst_us"])
    assert loop["worst_us"] < 875_000 + 20_000, "within CDRO_FW_LONGEST_OPERATION_MS + 20 ms"

    # The stack's worst case over the whole scenario (every instruction's stack pointer,
    # interrupts included) leaves at least 256 B of the Uno's 2 KB untouched, and the
    # firmware's own figure (STATUS free_ram_bytes, the painted low-water mark) is never below it.
    stack = s["stack"]
    print(f"stack: deepest {stack['deepest_bytes']} B, headroom {stack['headroom_bytes']} B, painted free "
          f"{stack['painted_free_bytes']} B; STATUS free_ram_bytes {status_frames(run)[-1]['free_ram_bytes']} B")
    assert stack["headroom_bytes"] >= 256
    assert stack["painted_free_bytes"] >= stack["headroom_bytes"]
    assert status_frames(run)[-1]["free_ram_bytes"] >= stack["headroom_bytes"]

    # Serial: every byte the UART sent reached the host; every host byte reached the UART.
    uart = s["uart"]
    final = run.health()[-1]["counters"]
    assert uart["host_read_everything"] and uart["tx_dropped_bytes"] == 0
    assert final["bytes_received"] == uart["tx_bytes"]
    assert 0 <= final["bytes_sent"] - uart["rx_bytes"] <= 2 * 13, "at most the last PING still in flight"
    assert uart["baud"] == 16_000_000 // (8 * 17)  # U2X, UBRR 16: 117647 bit/s, 2.1 % fast
    assert 0.01 < uart["tx_link_share"] < 0.5
    print(f"serial: {uart['tx_bytes_per_s']:.0f} B/s to the host ({uart['tx_link_share'] * 100:.1f} % of the link), "
          f"{uart['rx_bytes_per_s']:.1f} B/s from it; worst loop {loop['worst_cycles']} cycles "
          f"({loop['worst_us'] / 1000:.1f} ms) at {loop['worst_at_s']:.2f} s")
