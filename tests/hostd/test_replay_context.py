"""A capture replays to the live run's map on its own: cdro-hostd records in the
capture's header what the map depends on (the known heights, the fixed nodes, the engine and
movement settings), and a replay takes from there whatever its own command line does not give.
A capture without that record (written before, or by cdro-sim) is replayed with a warning.

cdro-sim acts as the device on a pseudo-terminal at full speed; every timeout is a deadlock
guard."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

from cdro_tools.codec import read_capture

GUARD_S = 120.0
SCENARIO_S = 15            # simulated seconds of the demo scenario


def node_lines(path):
    return [line for line in (json.loads(t) for t in path.read_text().splitlines() if t) if line["type"] == "node"]


def wait_until(predicate, what, timeout_s=GUARD_S):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def hostd(build_dir, *args, **kwargs):
    return subprocess.run([str(build_dir / "bin" / "cdro-hostd"), *map(str, args)], capture_output=True, text=True,
                          timeout=GUARD_S, **kwargs)


def live_run(build_dir, tmp_path):
    """A live run with known heights and a non-default setting; its capture and JSON Lines."""
    seed = int(os.environ.get("CDRO_TEST_SEED", "1"))
    print(f"cdro-sim demo, seed {seed} (set CDRO_TEST_SEED to change it)")
    link, heights = tmp_path / "tty", tmp_path / "heights.csv"
    sim_log = open(tmp_path / "sim.log", "w")
    sim = subprocess.Popen([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--seed", str(seed),
                            "--duration", str(SCENARIO_S), "--pty", str(link), "--speed", "max", "--heights-csv",
                            str(heights)], stdout=subprocess.DEVNULL, stderr=sim_log)
    wait_until(link.is_symlink, "the simulator's pseudo-terminal")
    capture, jsonl = tmp_path / "live.cdrocap", tmp_path / "live.jsonl"
    live_log = open(tmp_path / "live.log", "w")
    live = subprocess.Popen([str(build_dir / "bin" / "cdro-hostd"), "--device", str(link), "--heights-csv",
                             str(heights), "--set", "engine.range.sigma_m=0.12", "--capture", str(capture),
                             "--jsonl", str(jsonl), "--http-port", "0", "--checkpoint", ""],
                            stdout=subprocess.DEVNULL, stderr=live_log, cwd=tmp_path)
    try:
        assert sim.wait(timeout=GUARD_S) == 0, (tmp_path / "sim.log").read_text()
        time.sleep(0.5)  # the last bytes read (the link is gone; the capture has them)
        live.send_signal(signal.SIGTERM)
        assert live.wait(timeout=GUARD_S) == 0, (tmp_path / "live.log").read_text()
    finally:
        for process in (sim, live):
            if process.poll() is None:
                process.kill()
        sim_log.close()
        live_log.close()
    return capture, jsonl, heights


def test_a_capture_replays_to_the_live_map_without_being_told_the_heights(build_dir, tmp_path):
    capture, live_jsonl, heights = live_run(build_dir, tmp_path)
    assert read_capture(capture).header.context, "the live run recorded no context"
    live = node_lines(live_jsonl)
    # The simulator runs at full speed: under a second of event time, in which the JSON Lines'
    # per-node limit (jsonl.max_node_rate_hz, 2 Hz) leaves each node's first and last lines.
    assert len(live) >= 2 * 7

    alone = hostd(build_dir, "--replay", capture, "--jsonl", tmp_path / "alone.jsonl", cwd=tmp_path)
    assert alone.returncode == 0, alone.stderr
    assert "the live run's 7 known heights and 0 fixed nodes, from the capture" in alone.stderr, alone.stderr
    assert "the live run's engine settings, from the capture" in alone.stderr
    assert node_lines(tmp_path / "alone.jsonl") == live

    # Told other heights: used, with a warning, and the map is another.
    other = tmp_path / "other-heights.csv"
    other.write_text("id,z\n" + "".join(f"{0x6001 + i},0\n" for i in range(7)))
    told = hostd(build_dir, "--replay", capture, "--heights-csv", other, "--jsonl", tmp_path / "told.jsonl",
                 cwd=tmp_path)
    assert told.returncode == 0, told.stderr
    assert "differ from the live run's" in told.stderr, told.stderr
    assert node_lines(tmp_path / "told.jsonl") != live
    assert not (tmp_path / "checkpoint.cdrosog").exists()  # and a replay writes no checkpoint by itself


def test_a_capture_without_its_context_replays_with_a_warning(build_dir, tmp_path):
    capture = tmp_path / "sim.cdrocap"
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--duration", "10", "--capture",
                    str(capture)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=GUARD_S)
    result = hostd(build_dir, "--replay", capture, "--jsonl", tmp_path / "out.jsonl", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "does not record what the map depends on" in result.stderr, result.stderr
