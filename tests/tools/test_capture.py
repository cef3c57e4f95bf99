"""cdro-capture on real pseudo-terminals, run as a user runs it. Timeouts are deadlock guards."""
import json
import signal
import subprocess
import sys
import time

from cdro_tools import codec
from cdro_tools.simulation.link import PtyLink

GUARD_S = 30


def range_frame(sequence):
    return codec.encode_frame(codec.Frame("RANGE", sequence, {"device_time_ms": 1000 + sequence, "from_id": 0x6001,
                                                              "to_id": 0x6002, "distance_mm": 4000 + sequence,
                                                              "rss_dbm": -80, "flags": 0}))


def start_capture(tmp_path, port, *args):
    stderr = open(tmp_path / "capture.stderr", "w")
    process = subprocess.Popen([sys.executable, "-m", "cdro_tools.capture", "--port", str(port), "--out",
                                str(tmp_path / "out.cdrocap"), *args], stdout=subprocess.PIPE, stderr=stderr, text=True)
    return process


def wait_until(condition, what):
    deadline = time.monotonic() + GUARD_S
    while not condition():
        assert time.monotonic() < deadline, f"deadlock guard: {what}"
        time.sleep(0.01)


def wait_reader(link):
    wait_until(link.reader_present, "the capture never opened the port")
    time.sleep(0.2)                          # pyserial flushes the input right after opening
    link.hold()


def records(tmp_path):
    path = tmp_path / "out.cdrocap"
    if not path.exists() or path.stat().st_size == 0:
        return []
    try:
        return codec.read_capture(path).records
    except codec.CaptureError:
        return []


def finish(process):
    process.send_signal(signal.SIGINT)
    try:
        out, _ = process.communicate(timeout=GUARD_S)
    finally:
        if process.poll() is None:
            process.kill()
    return process.returncode, json.loads(out.strip().splitlines()[-1])


def test_that_capture_survives_the_port_vanishing_and_keeps_every_chunk(tmp_path):
    # Fixture: a device on a pseudo-terminal
    link = PtyLink(tmp_path / "dev")
    link.create()
    process = start_capture(tmp_path, tmp_path / "dev", "--quiet")
    try:
        wait_reader(link)
        first = [range_frame(i) for i in range(20)]
        half = range_frame(20)[:10]                        # the device vanishes in the middle of a frame

        # Test: 20 frames, half a frame, the device vanishes, comes back, 10 more frames
        for frame in first:
            link.write(frame)
        link.write(half)
        wait_until(lambda: len(records(tmp_path)) == 20, "first frames not recorded")
        link.close()
        time.sleep(0.3)
        link.create()
        wait_reader(link)
        second = [range_frame(i) for i in range(100, 110)]
        for frame in second:
            link.write(frame)
        wait_until(lambda: len(records(tmp_path)) == 31, "frames after the return not recorded")
        code, summary = finish(process)
    finally:
        link.close()
        if process.poll() is None:
            process.kill()

    # Assert
    stderr = (tmp_path / "capture.stderr").read_text()
    assert code == 0
    assert [r.data for r in records(tmp_path)] == [f[:-1] for f in first] + [half] + [f[:-1] for f in second]
    assert summary["vanished"] == 1 and summary["partial_chunks"] == 1 and summary["frames_ok"] == 30
    assert sum(summary["rejected"].values()) == 1
    assert "vanished" in stderr and "is back after" in stderr
    header = codec.read_capture(tmp_path / "out.cdrocap").header
    assert header.source == f"serial:{tmp_path / 'dev'}@115200"


def test_that_capture_records_exactly_what_the_simulator_sent(tmp_path):
    # Fixture: the simulator as the device, keeping its own capture; 3 simulated s at 10 x real time
    sim = subprocess.Popen([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo",
                            "--pty", str(tmp_path / "dev"), "--speed", "10", "--duration", "3",
                            "--capture", str(tmp_path / "sim.cdrocap")],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_until(lambda: (tmp_path / "dev").is_symlink(), "the simulator made no link")
        process = start_capture(tmp_path, tmp_path / "dev")

        # Test: capture until the simulator has ended the scenario and gone away, and the capture
        # has seen it go (its stderr says so: a loaded machine may not have run it yet)
        assert sim.wait(GUARD_S) == 0
        wait_until(lambda: "vanished" in (tmp_path / "capture.stderr").read_text(), "the capture never saw the link go")
        code, summary = finish(process)
    finally:
        for p in (sim,):
            if p.poll() is None:
                p.kill()

    # Assert
    sent = [r.data for r in codec.read_capture(tmp_path / "sim.cdrocap").records if not r.to_device]
    assert code == 0 and [r.data for r in records(tmp_path)] == sent
    assert summary["frames_ok"] == len(sent) - 1               # the boot's lone 0x00 is an empty chunk
    assert summary["vanished"] == 1                             # the simulator removed the link at its end


def test_that_capture_waits_for_a_port_that_is_not_there_yet(tmp_path):
    process = start_capture(tmp_path, tmp_path / "dev", "--wait")
    link = PtyLink(tmp_path / "dev")
    try:
        time.sleep(0.3)
        link.create()
        wait_reader(link)
        link.write(range_frame(1))
        wait_until(lambda: len(records(tmp_path)) == 1, "frame not recorded")
        code, summary = finish(process)
    finally:
        link.close()
        if process.poll() is None:
            process.kill()
    assert code == 0 and summary["frames_ok"] == 1


def test_that_a_missing_port_is_a_clear_error(tmp_path):
    result = subprocess.run([sys.executable, "-m", "cdro_tools.capture", "--port", str(tmp_path / "none"), "--out",
                             str(tmp_path / "out.cdrocap")], capture_output=True, text=True, timeout=GUARD_S)
    assert result.returncode == 2
    assert "cannot capture" in result.stderr and "--wait" in result.stderr
    assert not (tmp_path / "out.cdrocap").exists()


def test_that_help_has_an_example_and_bad_arguments_fail():
    def run(*a):
        return subprocess.run([sys.executable, "-m", "cdro_tools.capture", *a], capture_output=True, text=True,
                              timeout=GUARD_S)

    assert "example" in run("--help").stdout
    assert run("--port", "x", "--out", "y", "--duration", "0").returncode == 2
    assert run("--out", "y").returncode == 2


def test_that_an_unwritable_output_is_a_clear_error(tmp_path):
    link = PtyLink(tmp_path / "dev")
    link.create()
    try:
        result = subprocess.run([sys.executable, "-m", "cdro_tools.capture", "--port", str(tmp_path / "dev"), "--out",
                                 str(tmp_path / "no" / "such" / "dir.cdrocap")], capture_output=True, text=True,
                                timeout=GUARD_S)
    finally:
        link.close()
    assert result.returncode == 1 and "cannot write" in result.stderr


def test_that_the_status_line_gives_rates_while_frames_arrive(capsys):
    # Fixture: a capture whose clock the test moves; 10 frames/s arrive in batches every 0.5 s,
    # and the status goes to a log (not a terminal: a line every 5 s)
    import argparse
    import types
    from cdro_tools import capture
    clock = [1000.0]
    fake_time = types.SimpleNamespace(monotonic=lambda: clock[0], time_ns=time.time_ns, sleep=time.sleep)
    original_time = capture.time
    capture.time = fake_time
    try:
        status = capture.Capture(argparse.Namespace(quiet=False, port="pty", out="out.cdrocap"), stop=lambda: False)
        status.tty = False
        status.writer = types.SimpleNamespace(records_written=0)
        sequence = 0

        # Test: 12 s of frames
        for _ in range(24):
            clock[0] += 0.5
            data = b"".join(range_frame(sequence + k) for k in range(5))
            sequence += 5
            list(status.decoder.feed(data))
            status.bytes_total += len(data)
            status._status()
    finally:
        capture.time = original_time

    # Assert: every status line has rates, and they are the rates the frames came at
    lines = [line for line in capsys.readouterr().err.splitlines() if "frames ok" in line]
    assert len(lines) >= 2
    assert all("- B/s" not in line for line in lines), lines
    assert "10.0 frames/s" in lines[-1]
