"""cdro-replay, run as a user runs it: the bytes a reader gets are the capture's device records,
byte for byte, into a pseudo-terminal it makes or a port it is given. Timeouts are deadlock guards."""
import json
import os
import select
import subprocess
import sys
import time
import tty

import serial

from cdro_tools import codec
from cdro_tools.simulation.host import HostLink

GUARD_S = 30


def replay(*args, **kwargs):
    return subprocess.Popen([sys.executable, "-m", "cdro_tools.replay", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kwargs)


def summary_of(process):
    out, err = process.communicate(timeout=GUARD_S)
    assert process.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1]), err


def device_bytes(path):
    return b"".join(r.data + b"\x00" for r in codec.read_capture(path).records if not r.to_device)


def read_master(master, process, expected_length):
    """Reads the other side of a port until the bytes expected are there (or the replay ended)."""
    received = bytearray()
    deadline = time.monotonic() + GUARD_S
    while len(received) < expected_length and time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.05)
        if ready:
            received += os.read(master, 65536)
        elif process.poll() is not None and len(received) < expected_length:
            ready, _, _ = select.select([master], [], [], 0.2)
            if not ready:
                break
    return bytes(received)


def test_that_a_replayed_simulator_capture_reaches_the_reader_byte_for_byte(tmp_path):
    # Fixture: a capture of a whole simulated conversation (with the host's commands in it)
    capture = tmp_path / "demo.cdrocap"
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--duration", "20", "--capture",
                    str(capture)], check=True, capture_output=True, timeout=GUARD_S)
    expected = device_bytes(capture)

    # Test: into a pseudo-terminal, as fast as the reader reads
    process = replay(capture, "--pty", tmp_path / "dev", "--speed", "max")
    with HostLink(str(tmp_path / "dev")) as host:
        try:
            deadline = time.monotonic() + GUARD_S
            while len(host.received) < len(expected) and time.monotonic() < deadline:
                host.poll()
        except serial.SerialException:
            pass
    summary, stderr = summary_of(process)

    # Assert
    assert bytes(host.received) == expected
    assert summary["records_skipped_to_device"] == 3 and summary["bytes_unread"] == 0
    assert summary["frames_ok"] == len(host.frames) and summary["rejected"] == {}
    assert summary["frames_by_type"]["RANGE"] == sum(1 for f in host.frames if f.type == "RANGE")
    assert not (tmp_path / "dev").exists() and "played" in stderr


def test_that_replay_into_a_port_keeps_the_recorded_order_at_a_speed_factor(tmp_path):
    # Fixture: a port (a pseudo-terminal pair made here) and a simulator capture of 5 s
    capture = tmp_path / "demo.cdrocap"
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--duration", "5", "--capture",
                    str(capture)], check=True, capture_output=True, timeout=GUARD_S)
    expected = device_bytes(capture)
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        # Test: 5 recorded seconds at 25 x
        process = replay(capture, "--port", os.ttyname(slave), "--speed", "25")
        received = read_master(master, process, len(expected))
        summary, _ = summary_of(process)
    finally:
        os.close(master)
        os.close(slave)

    # Assert
    assert received == expected
    assert summary["records_played"] == sum(1 for r in codec.read_capture(capture).records if not r.to_device)


def test_that_the_golden_capture_plays_its_device_records_and_skips_the_host_and_odometry_ones(tmp_path, golden_dir):
    vectors = json.loads((golden_dir / "vectors.json").read_text())
    vector = vectors["capture"]
    not_device = (codec.capture_file.FLAG_TO_DEVICE | codec.capture_file.FLAG_ODOMETRY |
                  codec.capture_file.FLAG_HOST_EVENT)
    expected = b"".join(bytes.fromhex(r["data"]) + b"\x00" for r in vector["records"] if not r["flags"] & not_device)
    cases = (("whole", vector["bytes"], 3, 1, 1), ("cut", vector["cut_short"]["bytes"], 2, 1, 1),
             ("version 1", vectors["capture_v1"]["bytes"], 3, 0, 0))
    for name, blob, played, odometry, host_events in cases:
        path = tmp_path / f"{name.replace(' ', '-')}.cdrocap"
        path.write_bytes(bytes.fromhex(blob))
        master, slave = os.openpty()
        tty.setraw(slave)
        try:
            process = replay(path, "--port", os.ttyname(slave), "--speed", "max")
            want = expected if played == 3 else expected[:len(bytes.fromhex(vector["records"][0]["data"])) + 1 + 3]
            received = read_master(master, process, len(want))
            summary, stderr = summary_of(process)
        finally:
            os.close(master)
            os.close(slave)
        assert received == want, name   # (the odometry JSON and the host event never reach the port)
        assert summary["records_played"] == played and summary["records_skipped_to_device"] == 1, name
        assert summary["records_skipped_odometry"] == odometry, name
        assert summary["records_skipped_host_events"] == host_events, name
        assert f"skipped 1 host-to-device, {odometry} odometry and {host_events} host event records" in stderr, name
        if name == "cut":
            assert summary["capture_truncated_tail_bytes"] == vector["cut_short"]["truncated_tail_bytes"]
            assert "truncated tail" in stderr


def test_that_bad_input_exits_non_zero_with_a_clear_message(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    for args, message in (([tmp_path / "missing.cdrocap", "--pty", tmp_path / "dev"], "No such file"),
                          ([tmp_path / "notes.txt", "--pty", tmp_path / "dev"], "not a CDRO capture file"),
                          ([tmp_path / "notes.txt"], "required")):
        process = replay(*args)
        _, err = process.communicate(timeout=GUARD_S)
        assert process.returncode == 2 and message in err, err
    process = replay("--help")
    out, _ = process.communicate(timeout=GUARD_S)
    assert "example" in out
