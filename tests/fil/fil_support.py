"""Firmware in the loop, the test side: runs cdro-fil (the Uno .elf in simavr against a scenario's
simulated Pozyx network, its UART on a pseudo-terminal) together with a host process on that
pseudo-terminal, and reads back what both recorded.

The host is any program that takes the service's options (docs/service.md, "Command line"):
today build/bin/cdro-service-harness (the service with a recording stand-in for the engine,
plus --received), later build/bin/cdro-hostd. `FilRun(host="cdro-hostd", ...)` runs the same
scenario against the real engine.

Everything a run writes lives in its own directory and its serial port is its own
pseudo-terminal, so runs can go on in parallel.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import pathlib
import signal
import subprocess
import time

from cdro_tools.codec import FrameError, decode_frame, read_capture, validate_frame
from cdro_tools.evaluation.tracking import read_node_tracks
from cdro_tools.simulation.scenario import Scenario, from_shared_view
from cdro_tools.simulation.world import World

DEADLOCK_GUARD_S = 60.0  # s of wall-clock time beyond the scenario; only reached when something is broken


def avr_elf(avr_build_dir: pathlib.Path, board: str = "uno") -> pathlib.Path:
    return avr_build_dir / "bin" / f"cdro-firmware-{board}.elf"


# ---- the scenario and its truth ----------------------------------------------------------------

def fil_scenario(fil_binary: pathlib.Path, path: pathlib.Path, fil_args: list[str] | None = None) -> Scenario:
    """The scenario as cdro-fil reads it for a run with `fil_args` (--seed, --duration-s ...):
    `cdro-fil --print-scenario` (docs/tools.md, "Scenario files"), as the tools' Scenario, so that
    the tools' world model (World) gives the truth of the run."""
    result = subprocess.run([str(fil_binary), "--print-scenario", "--scenario", str(path), *(fil_args or [])],
                            capture_output=True, text=True, timeout=60)
    if result.returncode != 0:
        raise AssertionError(f"cdro-fil --print-scenario {path} exited with {result.returncode}:\n{result.stderr}")
    return from_shared_view(json.loads(result.stdout), f"cdro-fil --print-scenario {path}")


def tag_ids(scenario: Scenario) -> list[int]:
    """The nodes with an accelerometer, in scenario order."""
    return [n.id for n in scenario.nodes if n.accelerometer]


def truth_disagreement_m(world: World, truth_csv: pathlib.Path) -> tuple[float, int]:
    """How far cdro-fil's --truth-csv (t,id,x,y,z) is from the world model at its samples: the
    largest distance (m) and the number of samples."""
    bad: list = []
    tracks = read_node_tracks(str(truth_csv), bad)
    if bad:
        raise AssertionError(f"{truth_csv}: rows that do not read: {bad[:3]}")
    worst_m, samples = 0.0, 0
    for node, track in tracks.items():
        for t_s, p_m in zip(track.t_s, track.p_m):
            worst_m = max(worst_m, math.dist(world.position(node, float(t_s)), p_m))
            samples += 1
    return worst_m, samples


def read_csv(path: pathlib.Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


# ---- what the host received and sent ------------------------------------------------------------

@dataclasses.dataclass
class WireFrame:
    host_time_us: int     # when the host's read() completed the chunk (capture record time)
    to_device: bool
    frame: object         # cdro_tools.codec.Frame

    @property
    def type(self) -> str:
        return self.frame.type

    def __getitem__(self, name):
        return self.frame[name]


def capture_frames(path: pathlib.Path) -> tuple[list[WireFrame], int, dict]:
    """Every frame of a capture in both directions, the capture's creation time (us since the
    epoch) and what did not decode (by result)."""
    contents = read_capture(path)
    frames, rejected = [], {}
    for record in contents.records:
        try:
            frame = decode_frame(record.data)
            validate_frame(frame)
        except FrameError as error:
            rejected[str(error.result)] = rejected.get(str(error.result), 0) + 1
            continue
        frames.append(WireFrame(record.host_time_us, record.to_device, frame))
    return frames, contents.header.created_unix_us, rejected


# ---- the run ------------------------------------------------------------------------------------

class FilRun:
    """cdro-fil on a scenario, and a host on its pseudo-terminal, in `directory`.

    host: the binary's name in build_dir/bin ("cdro-service-harness" or "cdro-hostd"); the
    harness also gets --received. The host's config is generated (service sections, see
    docs/service.md) with `extra_config` appended (e.g. an engine: section).
    """

    def __init__(self, build_dir: pathlib.Path, avr_build_dir: pathlib.Path, directory: pathlib.Path,
                 scenario: pathlib.Path, host: str = "cdro-service-harness", name: str = "fil",
                 extra_config: str = "", fil_args: list[str] | None = None, host_args: list[str] | None = None):
        self.fil_binary = build_dir / "bin" / "cdro-fil"
        self.host_binary = build_dir / "bin" / host
        self.elf = avr_elf(avr_build_dir)
        for path, how in ((self.fil_binary, "build the native tree (cmake --build build)"),
                          (self.host_binary, "build the native tree (cmake --build build)"),
                          (self.elf, "build the AVR image (cmake --build build-avr, docs/firmware.md)")):
            if not path.exists():
                raise AssertionError(f"{path} missing: {how}")
        self.dir = pathlib.Path(directory)
        self.scenario_path = pathlib.Path(scenario)
        self.fil_args = fil_args or []
        self.scenario = fil_scenario(self.fil_binary, self.scenario_path, self.fil_args)
        self.world = World(self.scenario)
        self.name = name
        self.host = host
        self.link = self.dir / f"{name}.tty"
        self.summary_path = self.dir / f"{name}.summary.json"
        self.truth_path = self.dir / f"{name}.truth.csv"
        self.ranges_path = self.dir / f"{name}.ranges.csv"
        self.capture_path = self.dir / f"{name}.cdrocap"
        self.jsonl_path = self.dir / f"{name}.jsonl"
        self.received_path = self.dir / f"{name}.received.jsonl"
        self.fil_log_path = self.dir / f"{name}.fil.log"
        self.host_log_path = self.dir / f"{name}.host.log"
        self.config_path = self.dir / f"{name}.yaml"
        remote = ", ".join(f"0x{i:04X}" for i in self.scenario.remote_ids)
        # Timeouts above the firmware's worst step (0.73 s, docs/firmware.md); a PING every
        # second so that the keepalive is exercised throughout.
        self.config_path.write_text(f"""
serial:
  device: {self.link}
  reconnect_min_s: 0.05
  reconnect_max_s: 0.2
  hello_timeout_s: 1.0
  hello_retries: 20
  command_timeout_s: 1.5
  command_retries: 3
  keepalive_period_s: 1.0
  keepalive_misses: 3
nodes:
  ids: [{remote}]
schedule:
  mode: all_pairs
  motion_poll_ms: 200
  moving_boost: 2
  status_period_ms: 1000
  max_retries: 1
capture: {{path: {self.capture_path}}}
output: {{jsonl: {self.jsonl_path}, health_period_s: 0.5}}
http: {{port: 0}}
checkpoint: {{path: ""}}
logging: {{level: info}}
{extra_config}
""")
        self.host_args = host_args or []
        self.fil = None
        self.host_process = None

    def start(self) -> None:
        # cdro-fil first, holding the AVR until the port is opened (as the Uno resets when the
        # host opens it), so the host sees the boot from its first byte; then the host.
        self._fil_log = open(self.fil_log_path, "w")
        self.fil = subprocess.Popen(
            [str(self.fil_binary), "--elf", str(self.elf), "--scenario", str(self.scenario_path),
             "--link", str(self.link), "--start-on-open", "--summary", str(self.summary_path),
             "--truth-csv", str(self.truth_path), "--ranges-csv", str(self.ranges_path), *self.fil_args],
            stdout=subprocess.DEVNULL, stderr=self._fil_log)
        deadline = time.monotonic() + 10.0
        while not self.link.is_symlink():
            if self.fil.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"cdro-fil did not create {self.link}:\n{self.fil_log()}")
            time.sleep(0.01)
        command = [str(self.host_binary), "--config", str(self.config_path), *self.host_args]
        if self.host == "cdro-service-harness":
            command += ["--received", str(self.received_path)]
        self._host_log = open(self.host_log_path, "w")
        self.host_process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=self._host_log)

    def wait(self) -> None:
        """Until cdro-fil ends its scenario, then stops the host with SIGTERM."""
        try:
            code = self.fil.wait(timeout=self.scenario.duration_s + DEADLOCK_GUARD_S)
        except subprocess.TimeoutExpired:
            self.fil.kill()
            raise AssertionError(f"cdro-fil did not end:\n{self.fil_log()}") from None
        finally:
            self._fil_log.close()
        assert code == 0, f"cdro-fil exited with {code}:\n{self.fil_log()}"
        self.host_process.send_signal(signal.SIGTERM)
        try:
            host_code = self.host_process.wait(timeout=30)
        finally:
            self._host_log.close()
        assert host_code == 0, f"{self.host} exited with {host_code}:\n{self.host_log()}"
        self._load()

    def run(self) -> "FilRun":
        self.start()
        self.wait()
        return self

    def kill(self) -> None:
        for process in (self.fil, self.host_process):
            if process is not None and process.poll() is None:
                process.kill()
                process.wait()

    def fil_log(self) -> str:
        return self.fil_log_path.read_text(errors="replace") if self.fil_log_path.exists() else ""

    def host_log(self) -> str:
        return self.host_log_path.read_text(errors="replace") if self.host_log_path.exists() else ""

    # ---- results ---------------------------------------------------------------------------

    def _load(self) -> None:
        self.summary = json.loads(self.summary_path.read_text())
        self.sim_ranges = read_csv(self.ranges_path)
        self.frames, self.capture_created_us, self.rejected = capture_frames(self.capture_path)
        self.jsonl = [json.loads(line) for line in self.jsonl_path.read_text().splitlines() if line]
        self.received = ([json.loads(line) for line in self.received_path.read_text().splitlines() if line]
                         if self.received_path.exists() else [])

    def device(self, type_name: str | None = None) -> list[WireFrame]:
        """Frames from the device, in arrival order (optionally of one type)."""
        return [f for f in self.frames if not f.to_device and (type_name is None or f.type == type_name)]

    def sent(self, type_name: str | None = None) -> list[WireFrame]:
        return [f for f in self.frames if f.to_device and (type_name is None or f.type == type_name)]

    def health(self) -> list[dict]:
        return [line for line in self.jsonl if line["type"] == "health"]

    def host_t_to_sim_s(self) -> float:
        """Offset to add to a JSON Lines t_s (host time since the capture was created) to get
        simulated time: the HELLO's device time against its arrival."""
        hello = self.device("HELLO")[0]
        return hello["device_time_ms"] / 1000.0 - (hello.host_time_us - self.capture_created_us) / 1e6


# ---- checks shared by the harness test and the cdro-hostd test -----------------------------------

def node_estimates(run: FilRun) -> dict[int, list[dict]]:
    """The JSON Lines node objects per id, in order."""
    out: dict[int, list[dict]] = {}
    for line in run.jsonl:
        if line["type"] == "node":
            out.setdefault(line["id"], []).append(line)
    return out
