"""cdro-sim as the device on a real pseudo-terminal, end to end: the process is started as a
user starts it and a host talks to it through pyserial. Timeouts are deadlock guards only."""
import collections
import json
import os
import signal
import subprocess
import sys
import time

import pytest
import serial

from cdro_tools import codec
from cdro_tools.codec import CONSTANTS as C
from cdro_tools.simulation.host import HostLink

OWN, A, B, D = 0x6001, 0x6002, 0x6003, 0x6004
SCENARIO = """
own_id: 0x6001
duration_s: 20
nodes:
  - {id: 0x6001, x_m: 0, y_m: 0, z_m: 1.0, accelerometer: true}
  - {id: 0x6002, x_m: 6, y_m: 0, z_m: 2.0}
  - {id: 0x6003, x_m: 6, y_m: 5, z_m: 1.5}
  - {id: 0x6004, x_m: 0, y_m: 5, z_m: 0.5, accelerometer: true}
motion:
  - {node: 0x6004, start_s: 4, end_s: 12, waypoints_m: [[3, 5], [3, 8]]}
"""
GUARD_S = 30


class Sim:
    def __init__(self, tmp_path, *args, scenario=SCENARIO):
        path = tmp_path / "scenario.yaml"
        path.write_text(scenario)
        self.link = tmp_path / "dev"
        self.report = tmp_path / "report.json"
        self.stderr_path = tmp_path / "sim.stderr"
        with open(self.stderr_path, "w") as stderr:
            self.process = subprocess.Popen([sys.executable, "-m", "cdro_tools.sim", "--scenario", str(path), "--pty",
                                             str(self.link), "--fault-report", str(self.report), *map(str, args)],
                                            stdout=subprocess.DEVNULL, stderr=stderr)

    @property
    def stderr(self):
        return self.stderr_path.read_text()

    def wait(self):
        try:
            return self.process.wait(GUARD_S)
        finally:
            if self.process.poll() is None:
                self.process.kill()

    def stop(self):
        self.process.send_signal(signal.SIGTERM)
        return self.wait()

    def close(self):
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


@pytest.fixture
def run(tmp_path):
    sims = []

    def start(*args, **kwargs):
        sims.append(Sim(tmp_path, *args, **kwargs))
        return sims[-1]
    yield start
    for s in sims:
        s.close()


def schedule(**changes):
    fields = {"slot_period_ms": 0, "mode": C["CDRO_SCHEDULE_ALL_PAIRS"], "motion_poll_ms": 200, "moving_boost": 2,
              "status_period_ms": 1000, "max_retries": 1}
    fields.update(changes)
    return fields


def test_that_the_device_answers_the_handshake_and_commands(run, tmp_path, golden_dir):
    # Fixture
    sim_capture = tmp_path / "live.cdrocap"
    sim = run("--speed", "max", "--hold", "--capture", sim_capture)
    vectors = {v["name"]: v for v in json.loads((golden_dir / "vectors.json").read_text())["decode_errors"]}
    with HostLink(str(sim.link)) as host:
        # Test + Assert: HELLO at boot, then the discovered nodes
        hello = host.wait_for(lambda f: True, GUARD_S)
        assert hello.type == "HELLO" and hello.sequence == 0 and hello["node_id"] == OWN
        assert hello["reset_cause"] == C["CDRO_RESET_POWER_ON"] and hello["capabilities"] == 0x3F   # the firmware's
        discovered = host.wait_for(lambda f: f.type == "NODE_LIST", GUARD_S)
        assert discovered["source"] == C["CDRO_NODE_SOURCE_DISCOVERY"] and discovered["node_ids"] == [A, B, D]

        nonce_seq = host.send("PING", {"nonce": 0x12345678})
        ack = host.wait_for(lambda f: f.type in ("ACK", "NACK"), GUARD_S)
        assert (ack.type, ack["acked_sequence"], ack["value"]) == ("ACK", nonce_seq, 0x12345678)

        bad_seq = host.send("SET_SCHEDULE", schedule(moving_boost=0))
        nack = host.wait_for(lambda f: f.type in ("ACK", "NACK"), GUARD_S)
        assert (nack.type, nack["nacked_sequence"], nack["reason"]) == ("NACK", bad_seq, C["CDRO_NACK_BAD_VALUE"])
        host.send_raw(bytes.fromhex(vectors["unknown type 0x7E"]["chunk"]) + b"\x00")
        nack = host.wait_for(lambda f: f.type in ("ACK", "NACK"), GUARD_S)
        assert (nack.type, nack["reason"], nack["nacked_type"]) == ("NACK", C["CDRO_NACK_UNKNOWN_TYPE"], 0x7E)
        host.send_raw(bytes.fromhex(vectors["wrong CRC"]["chunk"]) + b"\x00")     # not answered, counted

        seq = host.send("SET_NODES", {"node_ids": [A, B, D]})
        ack = host.wait_for(lambda f: f.type in ("ACK", "NACK"), GUARD_S)
        echoed = host.wait_for(lambda f: f.type == "NODE_LIST", GUARD_S)
        assert (ack.type, ack["acked_type"], ack["acked_sequence"]) == ("ACK", 0x41, seq)
        assert echoed["source"] == C["CDRO_NODE_SOURCE_HOST"]
        host.send("SET_SCHEDULE", schedule())
        assert host.wait_for(lambda f: f.type in ("ACK", "NACK"), GUARD_S).type == "ACK"
        host.send("START")
        assert host.wait_for(lambda f: f.type in ("ACK", "NACK"), GUARD_S).type == "ACK"

        # ranging: every pair, until the device is 18 s old (D stops at 12 s, is still again ~4.6 s later)
        host.wait_for(lambda f: f.type == "RANGE" and f["device_time_ms"] > 18000, GUARD_S)
        status = host.wait_for(lambda f: f.type == "STATUS", GUARD_S)
        host.send("STOP")
        host.wait_for(lambda f: f.type == "ACK" and f["acked_type"] == 0x44, GUARD_S)
        host.read_for(0.3)
        received = bytes(host.received)

    assert status["commands_rejected"] == 3 and status["running"] == 1
    ranges = [f for f in host.frames if f.type == "RANGE"]
    pairs = collections.Counter((f["from_id"], f["to_id"]) for f in ranges)
    assert set(pairs) == {(OWN, A), (OWN, B), (OWN, D), (A, B), (A, D), (B, D)}
    # D is carried from 4 s to 12 s: MOTION on change, and its pairs ranged twice as often meanwhile
    motion = [(f["device_time_ms"], f["moving"]) for f in host.frames
              if f.type == "MOTION" and f["node_id"] == D and f["reason"] == C["CDRO_MOTION_REASON_CHANGE"]]
    assert [m for _, m in motion] == [1, 0]
    moving_from_ms, still_from_ms = motion[0][0], motion[1][0]
    during = collections.Counter((f["from_id"], f["to_id"]) for f in ranges
                                 if moving_from_ms + 2000 < f["device_time_ms"] < still_from_ms)
    with_d = [c for p, c in during.items() if D in p]
    without_d = [c for p, c in during.items() if D not in p]
    assert min(with_d) > 1.6 * max(without_d), during
    assert all(f["flags"] & C["CDRO_RANGE_FLAG_MOVING"] for f in ranges
               if D in (f["from_id"], f["to_id"]) and moving_from_ms < f["device_time_ms"] < still_from_ms)

    assert sim.stop() == 0
    assert not sim.link.exists()
    # the simulator's capture holds what the host read, and the host's commands
    contents = codec.read_capture(sim_capture)
    device_bytes = b"".join(r.data + b"\x00" for r in contents.records if not r.to_device)
    assert device_bytes.startswith(received) and len(received) > 1000
    assert sum(1 for r in contents.records if r.to_device) == 8        # every chunk the host sent


def test_that_real_time_mode_streams_status_and_ends_at_the_scenario_end(run):
    # Fixture: 4 simulated seconds at 20 x real time
    sim = run("--speed", 20, "--duration", 4)
    statuses = []
    with HostLink(str(sim.link)) as host:
        # Test: read until the simulator hangs up at the end of the scenario
        with pytest.raises(serial.SerialException):
            deadline = time.monotonic() + GUARD_S
            while time.monotonic() < deadline:
                host.poll()
        statuses = [f for f in host.frames if f.type == "STATUS"]

    # Assert
    assert sim.wait() == 0
    assert host.frames[0].type == "HELLO"
    # the firmware's first STATUS one period after HELLO (at POZYX_BOOT_MS), then every period
    assert [s["uptime_ms"] for s in statuses] == [1250, 2250, 3250]
    assert all(s["running"] == 0 for s in statuses)
    assert "end of scenario" in sim.stderr and not sim.link.exists()


FAULTY = SCENARIO.replace("duration_s: 20", "duration_s: 14") + """
faults:
  - {at_s: 2, kind: garbage, bytes: 30}
  - {at_s: 3, kind: bit_flip, frames: 2}
  - {at_s: 4, kind: cut_frame, frames: 1}
  - {at_s: 5, kind: absurd, frames: 3}
  - {at_s: 6, kind: reset}
  - {at_s: 9, kind: vanish, duration_s: 1.0}
"""


def test_that_faults_reach_the_host_and_the_report_counts_what_it_decoded(run):
    # Fixture
    sim = run("--speed", "max", "--seed", 9, scenario=FAULTY)
    totals = collections.Counter()
    connections = 0
    hellos = []
    deadline = time.monotonic() + GUARD_S

    # Test: a host that configures the device at every HELLO and reconnects when the link vanishes
    while time.monotonic() < deadline and sim.process.poll() is None:
        try:
            host = HostLink(str(sim.link), appear_timeout_s=GUARD_S, give_up=lambda: sim.process.poll() is not None)
        except (TimeoutError, serial.SerialException, OSError):
            continue
        connections += 1
        try:
            seen = 0
            while time.monotonic() < deadline:
                host.poll()
                for frame in host.frames[seen:]:
                    if frame.type == "HELLO":
                        hellos.append(frame["reset_cause"])
                        host.send("SET_NODES", {"node_ids": [A, B, D]})
                        host.send("START")
                seen = len(host.frames)
        except serial.SerialException:
            pass
        finally:
            totals.update(host.decoder.counters)
            host.close()

    # Assert
    assert sim.wait() == 0, sim.stderr
    report = json.loads(sim.report.read_text())
    counts = report["counts"]
    assert [counts[k]["injected"] for k in ("garbage", "bit_flip", "cut_frame", "absurd", "reset", "vanish")] == \
        [1, 2, 1, 3, 1, 1]
    assert counts["absurd"]["distance"] == 1 and counts["absurd"]["unknown_node"] == 1
    assert connections == 2 and hellos == [C["CDRO_RESET_POWER_ON"], C["CDRO_RESET_WATCHDOG"]]
    decoder = report["link"]["host_decoder"]
    assert {k: totals[k] for k in codec.frames.COUNTER_NAMES} == {k: decoder[k] for k in codec.frames.COUNTER_NAMES}
    assert decoder["connections"] == 2 and decoder["value_errors"] == 2
    assert report["link"]["bytes_unread_at_vanish"] == 0 and report["link"]["frames_lost_while_gone"] > 0
    assert "faults injected: garbage 1" in sim.stderr


def test_that_sigterm_stops_a_device_nobody_opened(run):
    sim = run()
    deadline = time.monotonic() + GUARD_S
    while not sim.link.is_symlink() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert sim.stop() == 0
    assert not sim.link.exists() and "stopped (signal)" in sim.stderr


def test_that_a_path_that_is_not_a_symlink_is_refused(tmp_path):
    (tmp_path / "dev").write_text("precious")
    result = subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo",
                             "--pty", str(tmp_path / "dev")], capture_output=True, text=True, timeout=GUARD_S)
    assert result.returncode == 2 and "not a symlink" in result.stderr
    assert (tmp_path / "dev").read_text() == "precious"


def test_that_the_live_transmit_buffer_refuses_a_frame_that_does_not_fit():
    # Fixture: a terminal that takes nothing (nobody reads), a 100-byte buffer
    from cdro_tools.simulation.runner import LiveTransport

    class FullLink:
        def write(self, data):
            return 0

    transport = LiveTransport(FullLink(), 100, None, lambda message: None)
    transport.state = "up"
    frame = codec.encode_frame(codec.Frame("PING", 0, {"nonce": 1}))       # 14 bytes on the wire

    # Test
    accepted = [transport.offer(i, frame, None) for i in range(10)]
    transport.pump(None)

    # Assert: 7 frames fit in 100 bytes, whole; the rest is refused, nothing is written
    assert accepted == [True] * 7 + [False] * 3
    assert transport.queued_bytes == 7 * len(frame) and transport.stats.bytes_delivered == 0


def test_that_a_device_that_goes_away_is_one_serial_error_for_the_host():
    # Fixture: a pseudo-terminal whose device side (the master) closes under an open host. Seen in
    # CI: pyserial's in_waiting let the ioctl's EIO through as a bare OSError, which the faults
    # test's reconnecting host did not take for a vanished link.
    master, slave = os.openpty()
    host = HostLink(os.ttyname(slave))
    os.close(slave)
    os.write(master, b"\x00")
    host.poll()
    os.close(master)

    # Test and assert: every poll after that is a SerialException, never a bare OSError.
    with pytest.raises(serial.SerialException):
        for _ in range(20):
            host.poll()
    host.close()
