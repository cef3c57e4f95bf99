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

import bisect
import csv
import dataclasses
import json
import math
import pathlib
import signal
import subprocess
import time

import yaml

from cdro_tools.codec import FrameError, decode_frame, read_capture, validate_frame

DEADLOCK_GUARD_S = 60.0  # s of wall-clock time beyond the scenario; only reached when something is broken


def avr_elf(avr_build_dir: pathlib.Path, board: str = "uno") -> pathlib.Path:
    return avr_build_dir / "bin" / f"cdro-firmware-{board}.elf"


# ---- the scenario, as the test needs it -------------------------------------------------------

@dataclasses.dataclass
class Scenario:
    path: pathlib.Path
    raw: dict
    own: int
    nodes: dict[int, dict]          # id -> node entry (x_m, y_m, z_m, accelerometer)
    duration_s: float

    @classmethod
    def load(cls, path: pathlib.Path) -> "Scenario":
        raw = yaml.safe_load(path.read_text())
        nodes = {n["id"]: n for n in raw["nodes"]}
        return cls(path, raw, raw["own_id"], nodes, float(raw.get("duration_s", 0)))

    @property
    def remote_ids(self) -> list[int]:
        return [i for i in self.nodes if i != self.own]

    @property
    def tags(self) -> list[int]:
        return [i for i, n in self.nodes.items() if n.get("accelerometer")]

    def faults(self, kind: str) -> list[dict]:
        return [f for f in self.raw.get("faults", []) if f["kind"] == kind]


# ---- truth --------------------------------------------------------------------------------------

class Truth:
    """cdro-fil --truth-csv: t,id,x,y,z (s, m), sampled every --truth-period-ms."""

    def __init__(self, path: pathlib.Path):
        self.tracks: dict[int, tuple[list[float], list[tuple[float, float, float]]]] = {}
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                times, points = self.tracks.setdefault(int(row["id"]), ([], []))
                times.append(float(row["t"]))
                points.append((float(row["x"]), float(row["y"]), float(row["z"])))

    def position(self, node: int, t_s: float) -> tuple[float, float, float]:
        """Linear between samples (the tracks are piecewise linear, so exact up to a corner)."""
        times, points = self.tracks[node]
        i = bisect.bisect_right(times, t_s)
        if i == 0:
            return points[0]
        if i == len(times):
            return points[-1]
        t0, t1 = times[i - 1], times[i]
        f = (t_s - t0) / (t1 - t0)
        a, b = points[i - 1], points[i]
        return tuple(a[k] + f * (b[k] - a[k]) for k in range(3))

    def distance(self, a: int, b: int, t_s: float) -> float:
        return math.dist(self.position(a, t_s), self.position(b, t_s))


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
        self.scenario = Scenario.load(pathlib.Path(scenario))
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
        self.fil_args = fil_args or []
        self.host_args = host_args or []
        self.fil = None
        self.host_process = None

    def start(self) -> None:
        # cdro-fil first, holding the AVR until the port is opened (as the Uno resets when the
        # host opens it), so the host sees the boot from its first byte; then the host.
        self._fil_log = open(self.fil_log_path, "w")
        self.fil = subprocess.Popen(
            [str(self.fil_binary), "--elf", str(self.elf), "--scenario", str(self.scenario.path),
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
        self.truth = Truth(self.truth_path)
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


def align_2d(estimated: dict[int, tuple[float, float]], truth: dict[int, tuple[float, float]]):
    """The rigid transform (rotation, translation, and a reflection if that fits better: a
    range-only map is known up to all three) taking estimated positions onto the truth, by least
    squares (the tools' one fit, cdro_tools.evaluation.alignment). Returns (transform function,
    RMS residual in m)."""
    from cdro_tools.evaluation.alignment import align

    ids = sorted(set(estimated) & set(truth))
    if len(ids) < 3:
        raise AssertionError(f"only {len(ids)} nodes to align")
    fit = align(estimated, truth)

    def transform(xy):
        return tuple(fit.apply(xy).tolist())

    return transform, fit.rmse_m
