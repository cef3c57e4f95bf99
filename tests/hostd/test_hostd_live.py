"""cdro-hostd with the real engine, end to end, as a user runs it: cdro-sim acts as the Pozyx tag
on a pseudo-terminal (the README demo's scenario: 7 nodes at known heights, one carried 5.2 m at
28-32 s, NLOS links), cdro-hostd reads it as its serial port.

- A live run with faults injected into the stream (garbage, a bit flip, a frame cut in half,
  absurd values, the device vanishing and returning) is killed with kill -9 halfway; its
  capture stays readable, its periodic checkpoint decodes, its counters say exactly what the
  simulator injected, and replaying its capture gives a converged map, the same bit for bit
  every time. A second cdro-hostd resumes from the checkpoint on the same device, tracks the
  carried node and ends on a converged map.
- The documented resume tolerance (docs/service.md, "Checkpoints": 1 cm): a capture replayed
  whole, against its first part replayed, checkpointed, and its second part replayed on top of
  the resumed state.

Timeouts are deadlock guards only; nothing here depends on how fast the machine is.
"""
from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request

from cdro_tools.codec import decode_sog, read_capture
from cdro_tools.codec import capture_file
from cdro_tools.codec.capture_file import RECORD_OVERHEAD, CaptureWriter
from cdro_tools.evaluation.alignment import align

GUARD_S = 120.0                    # s of wall clock: reached only when something is broken
OWN = 0x6001
CARRIED = 0x6006
NODES = [0x6001, 0x6002, 0x6003, 0x6004, 0x6005, 0x6006, 0x6007]
SPEED = 4                          # the simulator at 4 x real time: the 60 s scenario in 15 s
# Faults, all before the kill (simulated s); the kill comes after KILL_AFTER_FRAMES frames
# (~22 s of the scenario at the firmware's ~16 frames/s; seen on a health line and killed at
# ~25 s, before the carry at 28 s. With 430, the Python device's ~24 s, the firmware's frames
# came at ~27 s and the kill at ~29.5 s, during the carry).
FAULTS = ["garbage@5,bytes=200", "bit_flip@8", "cut_frame@11", "absurd@14", "vanish@17,duration_s=1"]
KILL_AFTER_FRAMES = 360

# Stated bounds (measured: 0.02-0.05 m at the end of the scenario; the resumed run 0.4 mm off).
MAP_RMSE_M = 0.15                  # aligned RMSE of the final map against the truth
NODE_ERROR_M = 0.30                # any node, after the alignment
# Before the carry the data cannot place 0x6005 (docs/results.md, "Moving nodes"): it is nearly
# in line between 0x6001 and 0x6003, and 0x6003-0x6005 reads 0.5 m long; 0.45 m towards 0x6001
# the long link is 0x6001-0x6005 instead, at the same cost. The carried node's new links break
# the tie. Until then 0x6005 is held to this bound, and the map's RMSE to the next.
TIE_NODE = 0x6005
TIE_NODE_ERROR_M = 0.60
TIE_MAP_RMSE_M = 0.25
RESUME_TOLERANCE_M = 0.01          # docs/service.md, "Checkpoints"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(predicate, what: str, timeout_s: float = GUARD_S):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def node_lines(path) -> list[dict]:
    """The node lines of a JSON Lines file (a last line cut by kill -9 is skipped)."""
    lines = []
    for text in path.read_text().splitlines():
        try:
            line = json.loads(text)
        except json.JSONDecodeError:
            continue
        if line.get("type") == "node":
            lines.append(line)
    return lines


def last_health(path) -> dict:
    healths = []
    for text in path.read_text().splitlines():
        try:
            line = json.loads(text)
        except json.JSONDecodeError:
            continue
        if line.get("type") == "health":
            healths.append(line)
    assert healths, f"no health line in {path}"
    return healths[-1]


def final_map(path) -> dict[int, dict]:
    final = {}
    for line in node_lines(path):
        final[line["id"]] = line
    return final


def read_csv(path) -> list[list[str]]:
    rows = [line.split(",") for line in path.read_text().splitlines() if line and not line.startswith("#")]
    return rows[1:]


def truth_at_end(truth_csv, tracks_csv) -> dict[int, tuple[float, float]]:
    truth = {int(r[0]): (float(r[1]), float(r[2])) for r in read_csv(truth_csv)}
    for r in read_csv(tracks_csv):  # t,id,x,y in time order: the last row of a node is where it ends
        truth[int(r[1])] = (float(r[2]), float(r[3]))
    return truth


def check_map(final: dict[int, dict], truth: dict[int, tuple[float, float]], what: str, tie: bool = False) -> float:
    missing = [hex(n) for n in NODES if n not in final or not final[n]["placed"]]
    assert not missing, f"{what}: nodes not on the map: {missing}"
    # The tie node may say that its ranges cannot tell (with the reason); every other node converges.
    not_converged = [hex(n) for n in NODES if not final[n]["converged"] and not (tie and n == TIE_NODE)]
    assert not not_converged, f"{what}: nodes not converged: {not_converged}"
    if not final[TIE_NODE]["converged"]:
        assert final[TIE_NODE]["reason"] in ("flexible", "ambiguous", "unsettled"), final[TIE_NODE]
    fit = align({n: (final[n]["x_m"], final[n]["y_m"]) for n in NODES}, truth)
    print(f"{what}: aligned RMSE {fit.rmse_m:.3f} m; per node " +
          ", ".join(f"{n:#06x} {e:.3f}" for n, e in sorted(fit.errors_m.items())) +
          f"; {TIE_NODE:#06x} {final[TIE_NODE]['status']} {final[TIE_NODE]['reason']}")
    assert fit.rmse_m <= (TIE_MAP_RMSE_M if tie else MAP_RMSE_M), what
    for node, error_m in fit.errors_m.items():
        # Converged or not, the tie node is held to its own bound (within what converged promises, 1 m).
        bound_m = TIE_NODE_ERROR_M if tie and node == TIE_NODE else NODE_ERROR_M
        assert error_m <= bound_m, f"{what}: node {node:#06x} is {error_m:.2f} m off"
    return fit.rmse_m


class Hostd:
    """build/bin/cdro-hostd with a generated configuration, its outputs in tmp_path."""

    def __init__(self, build_dir, tmp_path, name: str, args: list[str], device=None, heights_csv=None):
        self.binary = build_dir / "bin" / "cdro-hostd"
        assert self.binary.exists(), f"{self.binary} missing: build the native tree first"
        self.name = name
        self.port = free_port()
        self.capture = tmp_path / f"{name}.cdrocap"
        self.jsonl = tmp_path / f"{name}.jsonl"
        self.checkpoint = tmp_path / f"{name}.cdrosog"
        self.stderr_path = tmp_path / f"{name}.stderr.log"
        config = tmp_path / f"{name}.yaml"
        config.write_text(f"""
serial:
  device: {device or tmp_path / 'no-device'}
  reconnect_min_s: 0.05
  reconnect_max_s: 0.4
  hello_timeout_s: 0.3
  hello_retries: 20
nodes: {{ids: [], unknown: reject}}
schedule: {{mode: all_pairs, motion_poll_ms: 200, moving_boost: 2}}
capture: {{path: {self.capture}}}
output: {{jsonl: {self.jsonl}, health_period_s: 0.5}}
http: {{port: {self.port}, update_period_s: 0.1}}
checkpoint: {{path: {self.checkpoint}, period_s: 0.5}}
logging: {{level: info}}
map: {{heights_csv: {heights_csv or "''"}}}
""")
        self._stderr = open(self.stderr_path, "w")
        self.process = subprocess.Popen([str(self.binary), "--config", str(config), *args],
                                        stdout=subprocess.DEVNULL, stderr=self._stderr)

    def health(self):
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/api/health", timeout=5) as response:
                return json.loads(response.read())
        except (urllib.error.URLError, ConnectionError, json.JSONDecodeError):
            return None

    def wait_frames(self, frames: int):
        def enough():
            if self.process.poll() is not None:
                raise AssertionError(f"{self.name} exited ({self.process.returncode}):\n{self.log()}")
            h = self.health()
            return h and h["counters"]["frames_delivered"] >= frames
        wait_until(enough, f"{self.name}: {frames} frames delivered")

    def stop(self, sig=signal.SIGTERM) -> int:
        self.process.send_signal(sig)
        return self.wait()

    def wait(self) -> int:
        try:
            return self.process.wait(timeout=GUARD_S)
        finally:
            self._stderr.close()

    def log(self) -> str:
        return self.stderr_path.read_text(errors="replace") if self.stderr_path.exists() else ""

    def close(self):
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


def sim_command(*args) -> list[str]:
    return [sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", *map(str, args)]


def replay(build_dir, tmp_path, name, capture, heights_csv, *extra) -> Hostd:
    # A replay writes only what its command line names (docs/service.md, "Capture and replay").
    run = Hostd(build_dir, tmp_path, name, ["--replay", str(capture), "--speed", "max", "--jsonl",
                                            str(tmp_path / f"{name}.jsonl"), "--checkpoint",
                                            str(tmp_path / f"{name}.cdrosog"), *extra],
                heights_csv=heights_csv)
    code = run.wait()
    assert code == 0, f"{name} exited {code}:\n{run.log()}"
    return run


def test_faults_kill_9_replay_and_resume_on_the_live_device(build_dir, tmp_path):
    seed = int(os.environ.get("CDRO_TEST_SEED", "1"))
    print(f"cdro-sim demo, seed {seed} (set CDRO_TEST_SEED to change it)")
    heights, truth_csv, tracks = tmp_path / "heights.csv", tmp_path / "truth.csv", tmp_path / "tracks.csv"
    report_path, link = tmp_path / "faults.json", tmp_path / "tty"
    faults = [arg for fault in FAULTS for arg in ("--fault", fault)]
    sim_log = open(tmp_path / "sim.stderr.log", "w")
    sim = subprocess.Popen(sim_command("--seed", seed, "--pty", link, "--speed", SPEED, "--heights-csv", heights,
                                       "--truth-csv", truth_csv, "--tracks-csv", tracks, "--fault-report",
                                       report_path, *faults),
                           stdout=subprocess.DEVNULL, stderr=sim_log)
    first = second = None
    try:
        wait_until(link.is_symlink, "the simulator's pseudo-terminal")
        first = Hostd(build_dir, tmp_path, "first", [], device=link, heights_csv=heights)
        first.wait_frames(KILL_AFTER_FRAMES)
        wait_until(lambda: first.checkpoint.exists(), "a periodic checkpoint")
        assert first.stop(signal.SIGKILL) == -signal.SIGKILL
        # Another cdro-hostd takes over the same device, from the killed one's last checkpoint.
        checkpoint = tmp_path / "killed.cdrosog"
        checkpoint.write_bytes(first.checkpoint.read_bytes())
        second = Hostd(build_dir, tmp_path, "second", ["--resume", str(checkpoint)], device=link,
                       heights_csv=heights)
        assert sim.wait(timeout=GUARD_S) == 0, (tmp_path / "sim.stderr.log").read_text()
        second.wait_frames(1)
        time.sleep(1.0)  # a health line and a checkpoint after the last frame (the map is the same either way)
        assert second.stop() == 0, second.log()
    finally:
        for run in (first, second):
            if run is not None:
                run.close()
        if sim.poll() is None:
            sim.kill()
        sim_log.close()
    report = json.loads(report_path.read_text())
    truth = truth_at_end(truth_csv, tracks)

    # The killed run: its capture is readable to the last record or all but it, its checkpoint
    # is whole, and its counters say exactly what the simulator did to the stream.
    capture = read_capture(first.capture)
    assert capture.corrupt_bytes == 0
    assert capture.truncated_tail_bytes < RECORD_OVERHEAD + 512
    assert decode_sog(checkpoint.read_bytes()).header["ranges_processed"] > 0
    counters = last_health(first.jsonl)["counters"]
    # The simulator decodes what it delivered with the host's rules (report "link.host_decoder").
    decoded = report["link"]["host_decoder"]
    for name in ("cobs_errors", "crc_errors", "value_errors", "too_long_errors", "length_errors", "short_errors",
                 "type_errors", "version_errors", "bytes_discarded"):
        assert counters[name] == decoded[name], f"{name}: {counters[name]} counted, {decoded[name]} delivered"
    assert counters["crc_errors"] >= 1 and counters["value_errors"] >= 1 and counters["bytes_discarded"] >= 200
    assert counters["frames_lost"] >= report["link"]["frames_lost_while_gone"] > 0
    assert counters["frames_rejected_unknown_node"] == report["counts"]["absurd"]["unknown_node"]
    assert report["counts"]["vanish"]["injected"] == 1
    assert counters["link_disconnects"] >= 1 and counters["handshakes"] >= 2, counters
    assert "resume:" in second.log()

    # Replaying the killed run's capture: the map it had built, and bit for bit the same twice.
    replays = [replay(build_dir, tmp_path, f"replay{i}", first.capture, heights) for i in range(2)]
    assert node_lines(replays[0].jsonl) == node_lines(replays[1].jsonl)
    assert not replays[0].capture.exists()  # a replay does not capture itself
    before_carry = {int(r[0]): (float(r[1]), float(r[2])) for r in read_csv(truth_csv)}  # t = 0
    check_map(final_map(replays[0].jsonl), before_carry, "replay of the killed run", tie=True)

    # The resumed run saw the carry and the rest of the scenario: the carried node was reported
    # moving and ends, like the others, where it is.
    assert any(line["moving"] for line in node_lines(second.jsonl) if line["id"] == CARRIED)
    final = final_map(second.jsonl)
    assert not final[CARRIED]["moving"]
    check_map(final, truth, "resumed run")
    assert read_capture(second.capture).corrupt_bytes == 0


def test_a_resumed_run_ends_within_the_documented_tolerance(build_dir, tmp_path):
    seed = int(os.environ.get("CDRO_TEST_SEED", "1"))
    print(f"cdro-sim demo, seed {seed} (set CDRO_TEST_SEED to change it)")
    heights, whole = tmp_path / "heights.csv", tmp_path / "whole.cdrocap"
    subprocess.run(sim_command("--seed", seed, "--capture", whole, "--heights-csv", heights), check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=GUARD_S)
    capture = read_capture(whole)
    start_us = capture.records[0].host_time_us
    for split_s in (20.0, 30.0, 45.0):  # before, during and after the carry (28-32 s)
        split = next(i for i, r in enumerate(capture.records) if r.host_time_us - start_us > split_s * 1e6)
        parts = []
        for part, records in (("head", capture.records[:split]), ("tail", capture.records[split:])):
            path = tmp_path / f"{part}-{split_s:g}.cdrocap"
            with CaptureWriter(path, capture.header.source, capture.header.created_unix_us) as writer:
                for record in records:
                    writer.write(record)
            parts.append(path)
        head = replay(build_dir, tmp_path, f"head-{split_s:g}", parts[0], heights)
        resumed = replay(build_dir, tmp_path, f"resumed-{split_s:g}", parts[1], heights, "--resume",
                         str(head.checkpoint))
        assert "resume:" in resumed.log()
        if split_s == 20.0:
            uninterrupted = final_map(replay(build_dir, tmp_path, "whole", whole, heights).jsonl)
        final = final_map(resumed.jsonl)
        assert sorted(final) == sorted(uninterrupted)
        worst_m = max(math.dist((final[n]["x_m"], final[n]["y_m"]),
                                (uninterrupted[n]["x_m"], uninterrupted[n]["y_m"])) for n in final)
        print(f"split at {split_s:g} s: the resumed run ends {worst_m * 1000:.2f} mm from the uninterrupted one")
        assert worst_m <= RESUME_TOLERANCE_M
        assert all(final[n]["converged"] == uninterrupted[n]["converged"] for n in final), [
            (n, final[n]["reason"], uninterrupted[n]["reason"]) for n in final
            if final[n]["converged"] != uninterrupted[n]["converged"]]


def test_a_live_runs_solves_are_adopted_when_done_and_replayed_in_place(build_dir, tmp_path):
    # Live, no frame waits for the global solve: its map is taken between frames once the worker
    # thread is done, and the capture records where (host events, format 3); the replay takes each
    # one after the same frame and so writes the live run's node lines, bit for bit.
    seed = int(os.environ.get("CDRO_TEST_SEED", "1"))
    print(f"cdro-sim demo, seed {seed} (set CDRO_TEST_SEED to change it)")
    heights, link = tmp_path / "heights.csv", tmp_path / "tty"
    sim_log = open(tmp_path / "sim.stderr.log", "w")
    sim = subprocess.Popen(sim_command("--seed", seed, "--pty", link, "--speed", SPEED, "--heights-csv", heights),
                           stdout=subprocess.DEVNULL, stderr=sim_log)
    live = None
    try:
        wait_until(link.is_symlink, "the simulator's pseudo-terminal")
        live = Hostd(build_dir, tmp_path, "live", [], device=link, heights_csv=heights)
        assert sim.wait(timeout=GUARD_S) == 0, (tmp_path / "sim.stderr.log").read_text()
        assert live.stop() == 0, live.log()
    finally:
        if live is not None:
            live.close()
        if sim.poll() is None:
            sim.kill()
        sim_log.close()
    capture = read_capture(live.capture)
    assert capture.header.format_version == 3
    events = [record for record in capture.records if record.host_event]
    assert events, "no global solve was adopted between frames"
    assert all(record.data[:1] == b"S" and len(record.data) == 9 for record in events)
    assert last_health(live.jsonl)["counters"]["host_events"] == len(events)
    replayed = replay(build_dir, tmp_path, "replayed", live.capture, heights)
    assert "the map will differ" not in replayed.log() and "did not fit" not in replayed.log()
    assert f"{len(events)} host events fed" in replayed.log()
    assert node_lines(replayed.jsonl) == node_lines(live.jsonl)

    # A capture that lost its first host event (a damaged record is skipped): the replay goes on,
    # adopts that solve at the next event, says where it parts from the live run, and ends on a map.
    damaged = tmp_path / "damaged.cdrocap"
    first = capture.records.index(events[0])
    damaged.write_bytes(capture_file.encode_header(capture.header) + b"".join(
        capture_file.encode_record(record) for i, record in enumerate(capture.records) if i != first))
    diverged = replay(build_dir, tmp_path, "damaged", damaged, heights)
    assert "the map will differ from the live one" in diverged.log()
    assert "of the capture's host events did not fit this replay" in diverged.log()
    assert f"{len(events) - 1} host events fed" in diverged.log()
    assert all(line["placed"] for line in final_map(diverged.jsonl).values())
