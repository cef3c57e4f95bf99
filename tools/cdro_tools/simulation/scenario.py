"""Scenario files: YAML, checked strictly (unknown keys, wrong types and impossible values are
errors naming the key), with every default in one place. docs/tools.md documents each key.

The format is shared with cdro-fil (sim/fil/src/scenario.cpp, which reads the same keys):
a key only cdro-fil can act on is refused with a message saying so, and a key spelled the way an
older file spelled it is refused with its current name (FIL_ONLY_KEYS, FIL_FAULT_KINDS, RENAMED_KEYS).

Built-in scenarios ship in cdro_tools/scenarios/*.yaml and are named without the extension.
"""
from __future__ import annotations

import dataclasses
import importlib.resources
import math
import pathlib
import re
from typing import Any

import yaml

from ..codec import CONSTANTS as C


class ScenarioError(ValueError):
    """A scenario that cannot be used; the message names the file and the key."""


# ---- the scenario, as dataclasses with the documented defaults -------------------------------

@dataclasses.dataclass
class Node:
    id: int
    x_m: float
    y_m: float
    z_m: float = 0.0
    accelerometer: bool = False            # tags have one, anchors do not
    moving_amplitude_mg: float | None = None  # overrides accelerometer.moving_amplitude_mg


@dataclasses.dataclass
class MotionSegment:
    node: int
    start_s: float
    waypoints: list[tuple[float, float]]   # waypoints_m: (x_m, y_m); the node starts from where it is
    speed_mps: float | None = None         # either a speed ...
    end_s: float | None = None             # ... or an end time (then the speed follows)


@dataclasses.dataclass
class Odometry:
    rate_hz: float = 10.0
    distance_noise_frac: float = 0.02      # std of the relative error of each step's distance
    heading_noise_rad: float = 0.002       # std of each moving step's heading change error (rad)
    heading_drift_rad_s: float = 0.0       # constant heading drift (rad/s), also when standing still


@dataclasses.dataclass
class Robot:
    id: int
    start_s: float = 0.0                   # drives from here on; before, it stands at its node position
    waypoints: list[tuple[float, float]] | None = None
    speed_mps: float = 0.5
    turn_rate_rad_s: float = 0.5           # turns in place at waypoints
    heading_rad: float | None = None       # initial heading; default: towards the first waypoint
    poses: list[tuple[float, float, float]] | None = None  # alternative: (t_s, x_m, y_m), linear
    odometry: Odometry = dataclasses.field(default_factory=Odometry)
    moving_amplitude_mg: float = 120.0     # vibration of a driving robot, mg


@dataclasses.dataclass
class Schedule:
    """The SET_SCHEDULE fields the simulated host sends (CSV and capture modes)."""

    mode: int = C["CDRO_SCHEDULE_ALL_PAIRS"]
    slot_period_ms: int = 0
    motion_poll_ms: int = 200
    moving_boost: int = 2
    status_period_ms: int = 1000
    max_retries: int = 1

    def fields(self) -> dict[str, int]:
        return dataclasses.asdict(self)


@dataclasses.dataclass
class NlosLink:
    a: int
    b: int
    bias_m: float


@dataclasses.dataclass
class Nlos:
    links: list[NlosLink] = dataclasses.field(default_factory=list)
    random_links: int = 0                  # this many further links get a persistent bias ...
    random_bias_m: tuple[float, float] = (0.3, 1.5)  # ... drawn uniformly from this range
    outlier_probability: float = 0.0       # per range: reads long by an exponential amount
    outlier_mean_m: float = 0.5            # mean of that exponential tail
    rss_loss_db: float = 6.0               # RSS lower on biased links


@dataclasses.dataclass
class Uwb:
    noise_std_m: float = 0.1                                # Pozyx nominal accuracy
    noise_variance_m2: tuple[float, float] | None = None    # per-link variance drawn uniformly (overrides)
    scale: float = 1.0                                      # measured = scale x true (+ errors)
    max_range_m: float = 100.0                              # beyond: the range fails (timeout)
    dropout_probability: float = 0.0                        # per attempt: fails (Pozyx 0x11)
    nlos: Nlos = dataclasses.field(default_factory=Nlos)


@dataclasses.dataclass
class Accelerometer:
    noise_std_mg: float = 8.0              # std of the norm's noise
    moving_amplitude_mg: float = 250.0     # swing of the norm while carried (walking)
    moving_frequency_hz: float = 1.8       # step frequency


@dataclasses.dataclass
class Device:
    """What the firmware cannot know about its board. Everything else (its version, how many
    nodes it takes, its timing) is the firmware's own (firmware/core, run by cdro-sim).
    pozyx_firmware and pozyx_present are read from the scenario's pozyx section."""

    pozyx_firmware: int = 0x11             # pozyx.firmware_version: FIRMWARE_VER, major << 4 | minor
    pozyx_present: bool = True            # pozyx.present; False: the shield does not answer on I2C
    free_ram_bytes: int = 612              # reported in STATUS
    tx_buffer_bytes: int = 4096            # live mode: frames that do not fit are dropped


@dataclasses.dataclass
class Fault:
    at_s: float
    kind: str
    params: dict[str, Any] = dataclasses.field(default_factory=dict)


FAULT_KINDS = {
    # kind: {parameter: default}
    "garbage": {"bytes": 16},
    "bit_flip": {"frames": 1},
    "cut_frame": {"frames": 1},
    "absurd": {"frames": 6},
    "vanish": {"duration_s": 3.0, "reboot": False},
    "reset": {"cause": "watchdog"},
}

# The faults cdro-fil injects on the I2C bus and in the simulated Pozyx; cdro-sim's device is not
# behind a simulated I2C bus, so it cannot act on them.
FIL_FAULT_KINDS = ("nack_address", "nack_write", "no_completion", "error_completion", "garbage_range",
                   "stale_range", "drop_remote_reply", "refuse_function", "late_reply", "power_off")

# Keys of the one scenario format that only cdro-fil acts on (sim/fil/src/scenario.cpp), by
# path with list indices written [].
FIL_ONLY_KEYS = {
    "uwb.bias_m": "a constant added to every range",
    "uwb.ranging_us": "the simulated Pozyx's timing",
    "uwb.message_us": "the simulated Pozyx's timing",
    "uwb.processing_us": "the simulated Pozyx's timing",
    "pozyx.who_am_i": "the simulated Pozyx's WHO_AM_I register",
    "pozyx.model": "the simulated Pozyx's behaviour, realistic or ideal",
}

# Spellings of earlier scenario files (cdro-sim's and cdro-fil's) and what they are called now.
# The keys are refused rather than read, so that a file has one spelling.
RENAMED_KEYS = {
    "own": "own_id",
    "nodes[].x": "x_m",
    "nodes[].y": "y_m",
    "nodes[].z": "z_m",
    "nodes[].tag": "accelerometer",
    "motion[].waypoints": "waypoints_m",
    "robot.waypoints": "waypoints_m",
    "uwb.noise_std_mm": "noise_std_m (in metres)",
    "uwb.bias_mm": "bias_m (in metres)",
    "accelerometer.noise_mg": "noise_std_mg",
    "device.pozyx_firmware": "pozyx.firmware_version",
    "device.pozyx_present": "pozyx.present",
}

RESET_CAUSES = {"power_on": C["CDRO_RESET_POWER_ON"], "external": C["CDRO_RESET_EXTERNAL"],
                "brown_out": C["CDRO_RESET_BROWN_OUT"], "watchdog": C["CDRO_RESET_WATCHDOG"]}


@dataclasses.dataclass
class Scenario:
    name: str
    own_id: int
    nodes: list[Node]
    duration_s: float = 60.0
    seed: int = 1
    description: str = ""
    motion: list[MotionSegment] = dataclasses.field(default_factory=list)
    robot: Robot | None = None
    schedule: Schedule = dataclasses.field(default_factory=Schedule)
    uwb: Uwb = dataclasses.field(default_factory=Uwb)
    accelerometer: Accelerometer = dataclasses.field(default_factory=Accelerometer)
    device: Device = dataclasses.field(default_factory=Device)
    faults: list[Fault] = dataclasses.field(default_factory=list)
    epoch_unix_s: float = 1_700_000_000.0  # host clock at the start, for capture files

    def node(self, node_id: int) -> Node:
        for node in self.nodes:
            if node.id == node_id:
                return node
        raise KeyError(node_id)

    @property
    def remote_ids(self) -> list[int]:
        return [n.id for n in self.nodes if n.id != self.own_id]


# ---- parsing ----------------------------------------------------------------------------------

class _Reader:
    """Walks a YAML mapping with the path of each key, for error messages."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, path: str, message: str) -> ScenarioError:
        return ScenarioError(f"{self.source}: {path}: {message}")

    def mapping(self, value: Any, path: str, allowed: set[str], required: set[str] = frozenset()) -> dict:
        if value is None:
            value = {}
        if not isinstance(value, dict):
            raise self.fail(path, f"expected a mapping, got {type(value).__name__}")
        unknown = sorted(str(k) for k in value if k not in allowed)
        prefix = "" if path == "(top)" else path + "."
        for key in unknown:
            pattern = re.sub(r"\[\d+\]", "[]", prefix + key)
            if pattern in RENAMED_KEYS:
                raise self.fail(prefix + key, f"this key is now called {RENAMED_KEYS[pattern]}")
            if pattern in FIL_ONLY_KEYS:
                raise self.fail(prefix + key, f"only cdro-fil supports this key ({FIL_ONLY_KEYS[pattern]}); "
                                              "cdro-sim cannot act on it")
        if unknown:
            raise self.fail(path, f"unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(allowed))}")
        missing = sorted(required - set(value))
        if missing:
            raise self.fail(path, f"missing key(s) {', '.join(missing)}")
        return value

    def number(self, value: Any, path: str, low: float | None = None, high: float | None = None,
               low_open: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(path, f"expected a number, got {value!r}")
        if low is not None and (value < low or (low_open and value == low)):
            raise self.fail(path, f"{value} is below {'or at ' if low_open else ''}the minimum {low}")
        if high is not None and value > high:
            raise self.fail(path, f"{value} is above the maximum {high}")
        return float(value)

    def integer(self, value: Any, path: str, low: int | None = None, high: int | None = None) -> int:
        if isinstance(value, str):
            try:
                value = int(value, 0)
            except ValueError:
                raise self.fail(path, f"expected an integer, got {value!r}") from None
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(path, f"expected an integer, got {value!r}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise self.fail(path, f"{value} is outside {low}..{high}")
        return value

    def node_id(self, value: Any, path: str) -> int:
        # 0 is not an address and 0xFFFF is the UWB broadcast (and the firmware's "no Pozyx" id).
        return self.integer(value, path, 1, 0xFFFE)

    def coordinate(self, value: Any, path: str) -> float:
        return self.number(value, path, -1000.0, 1000.0)

    def boolean(self, value: Any, path: str) -> bool:
        if not isinstance(value, bool):
            raise self.fail(path, f"expected true or false, got {value!r}")
        return value

    def pair(self, value: Any, path: str, low: float | None = None) -> tuple[float, float]:
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise self.fail(path, f"expected [low, high], got {value!r}")
        lo, hi = (self.number(v, f"{path}[{i}]", low) for i, v in enumerate(value))
        if hi < lo:
            raise self.fail(path, f"high {hi} is below low {lo}")
        return lo, hi

    def points(self, value: Any, path: str, size: int) -> list[tuple[float, ...]]:
        if not isinstance(value, list) or not value:
            raise self.fail(path, "expected a non-empty list of points")
        out = []
        for i, point in enumerate(value):
            if path.startswith("motion") and isinstance(point, (list, tuple)) and len(point) == 3:
                raise self.fail(f"{path}[{i}]", "only cdro-fil supports [x, y, z] waypoints (a node carried up or "
                                                "down); cdro-sim keeps each node at its z_m: give [x, y]")
            if not isinstance(point, (list, tuple)) or len(point) != size:
                raise self.fail(f"{path}[{i}]", f"expected {size} numbers, got {point!r}")
            out.append(tuple(self.number(v, f"{path}[{i}][{k}]") for k, v in enumerate(point)))
        return out


def _fields(cls) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


def _given(m: dict, cls, key: str, field: str | None = None) -> Any:
    """m[key] if the file gives it, else the default of the dataclass's field (`field`, or the key):
    every default is written once, in the dataclasses above."""
    return m.get(key, getattr(cls, field or key))


def parse_scenario(data: Any, source: str, default_name: str = "scenario") -> Scenario:
    r = _Reader(source)
    top = r.mapping(data, "(top)", {"name", "description", "duration_s", "seed", "own_id", "nodes", "motion",
                                    "robot", "schedule", "uwb", "accelerometer", "pozyx", "device", "faults",
                                    "epoch_unix_s"}, {"own_id", "nodes"})
    nodes: list[Node] = []
    if not isinstance(top["nodes"], list) or not top["nodes"]:
        raise r.fail("nodes", "expected a non-empty list of nodes")
    for i, raw in enumerate(top["nodes"]):
        path = f"nodes[{i}]"
        m = r.mapping(raw, path, {"id", "x_m", "y_m", "z_m", "accelerometer", "moving_amplitude_mg"},
                      {"id", "x_m", "y_m"})
        nodes.append(Node(
            id=r.node_id(m["id"], f"{path}.id"), x_m=r.coordinate(m["x_m"], f"{path}.x_m"),
            y_m=r.coordinate(m["y_m"], f"{path}.y_m"), z_m=r.coordinate(_given(m, Node, "z_m"), f"{path}.z_m"),
            accelerometer=r.boolean(_given(m, Node, "accelerometer"), f"{path}.accelerometer"),
            moving_amplitude_mg=(None if m.get("moving_amplitude_mg") is None
                                 else r.number(m["moving_amplitude_mg"], f"{path}.moving_amplitude_mg", 0))))
    ids = [n.id for n in nodes]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise r.fail("nodes", "duplicate id(s) " + ", ".join(f"0x{i:04X}" for i in duplicates))
    own_id = r.node_id(top["own_id"], "own_id")
    if own_id not in ids:
        raise r.fail("own_id", f"0x{own_id:04X} is not among the nodes")

    def known(node_id: int, path: str) -> int:
        if node_id not in ids:
            raise r.fail(path, f"0x{node_id:04X} is not among the nodes")
        return node_id

    if top.get("duration_s") == 0:
        raise r.fail("duration_s", "only cdro-fil supports 0 (run until stopped); cdro-sim needs a duration")
    scenario = Scenario(name=str(top.get("name", default_name)), own_id=own_id, nodes=nodes,
                        duration_s=r.number(_given(top, Scenario, "duration_s"), "duration_s", 0, low_open=True),
                        seed=r.integer(_given(top, Scenario, "seed"), "seed", 0, 2**63 - 1),
                        description=str(top.get("description", "")).strip(),
                        epoch_unix_s=r.number(_given(top, Scenario, "epoch_unix_s"), "epoch_unix_s", 0, 4e9))
    if len(nodes) - 1 > C["CDRO_MAX_NODES"]:
        raise r.fail("nodes", f"{len(nodes) - 1} remote nodes; a device schedules at most {C['CDRO_MAX_NODES']}")

    for i, raw in enumerate(top.get("motion") or []):
        path = f"motion[{i}]"
        m = r.mapping(raw, path, {"node", "start_s", "waypoints_m", "speed_mps", "end_s"},
                      {"node", "start_s", "waypoints_m"})
        segment = MotionSegment(node=known(r.node_id(m["node"], f"{path}.node"), f"{path}.node"),
                                start_s=r.number(m["start_s"], f"{path}.start_s", 0),
                                waypoints=r.points(m["waypoints_m"], f"{path}.waypoints_m", 2))
        if ("speed_mps" in m) == ("end_s" in m):
            raise r.fail(path, "give exactly one of speed_mps and end_s")
        if "speed_mps" in m:
            segment.speed_mps = r.number(m["speed_mps"], f"{path}.speed_mps", 0, low_open=True)
        else:
            segment.end_s = r.number(m["end_s"], f"{path}.end_s", segment.start_s, low_open=True)
        scenario.motion.append(segment)

    if top.get("robot") is not None:
        path = "robot"
        m = r.mapping(top["robot"], path, _fields(Robot) - {"waypoints"} | {"waypoints_m"}, {"id"})
        robot = Robot(id=known(r.node_id(m["id"], "robot.id"), "robot.id"),
                      start_s=r.number(_given(m, Robot, "start_s"), "robot.start_s", 0),
                      speed_mps=r.number(_given(m, Robot, "speed_mps"), "robot.speed_mps", 0, low_open=True),
                      turn_rate_rad_s=r.number(_given(m, Robot, "turn_rate_rad_s"), "robot.turn_rate_rad_s", 0,
                                               low_open=True),
                      moving_amplitude_mg=r.number(_given(m, Robot, "moving_amplitude_mg"),
                                                   "robot.moving_amplitude_mg", 0))
        if ("waypoints_m" in m) == ("poses" in m):
            raise r.fail(path, "give exactly one of waypoints_m and poses")
        if "waypoints_m" in m:
            robot.waypoints = r.points(m["waypoints_m"], "robot.waypoints_m", 2)
        else:
            robot.poses = r.points(m["poses"], "robot.poses", 3)
            times = [p[0] for p in robot.poses]
            if any(b <= a for a, b in zip(times, times[1:])):
                raise r.fail("robot.poses", "times must increase")
        if m.get("heading_rad") is not None:
            robot.heading_rad = r.number(m["heading_rad"], "robot.heading_rad")
        o = r.mapping(m.get("odometry"), "robot.odometry", _fields(Odometry))
        robot.odometry = Odometry(
            rate_hz=r.number(_given(o, Odometry, "rate_hz"), "robot.odometry.rate_hz", 0, low_open=True),
            distance_noise_frac=r.number(_given(o, Odometry, "distance_noise_frac"),
                                         "robot.odometry.distance_noise_frac", 0),
            heading_noise_rad=r.number(_given(o, Odometry, "heading_noise_rad"), "robot.odometry.heading_noise_rad", 0),
            heading_drift_rad_s=r.number(_given(o, Odometry, "heading_drift_rad_s"),
                                         "robot.odometry.heading_drift_rad_s"))
        if any(s.node == robot.id for s in scenario.motion):
            raise r.fail("motion", f"the robot 0x{robot.id:04X} moves by its path, not by motion segments")
        scenario.robot = robot

    s = r.mapping(top.get("schedule"), "schedule", _fields(Schedule))
    modes = {"direct_only": C["CDRO_SCHEDULE_DIRECT_ONLY"], "all_pairs": C["CDRO_SCHEDULE_ALL_PAIRS"]}
    mode = s.get("mode", "all_pairs")
    if mode not in modes:
        raise r.fail("schedule.mode", f"{mode!r} is not one of {', '.join(modes)}")
    scenario.schedule = Schedule(
        mode=modes[mode],
        slot_period_ms=r.integer(_given(s, Schedule, "slot_period_ms"), "schedule.slot_period_ms", 0, 60000),
        motion_poll_ms=r.integer(_given(s, Schedule, "motion_poll_ms"), "schedule.motion_poll_ms", 0, 60000),
        moving_boost=r.integer(_given(s, Schedule, "moving_boost"), "schedule.moving_boost", 1, 8),
        status_period_ms=r.integer(_given(s, Schedule, "status_period_ms"), "schedule.status_period_ms", 100, 60000),
        max_retries=r.integer(_given(s, Schedule, "max_retries"), "schedule.max_retries", 0, 10))

    u = r.mapping(top.get("uwb"), "uwb", _fields(Uwb))
    uwb = Uwb(noise_std_m=r.number(_given(u, Uwb, "noise_std_m"), "uwb.noise_std_m", 0),
              scale=r.number(_given(u, Uwb, "scale"), "uwb.scale", 0, low_open=True),
              max_range_m=r.number(_given(u, Uwb, "max_range_m"), "uwb.max_range_m", 0, low_open=True),
              dropout_probability=r.number(_given(u, Uwb, "dropout_probability"), "uwb.dropout_probability", 0, 1))
    if u.get("noise_variance_m2") is not None:
        uwb.noise_variance_m2 = r.pair(u["noise_variance_m2"], "uwb.noise_variance_m2", 0)
    n = r.mapping(u.get("nlos"), "uwb.nlos", _fields(Nlos))
    uwb.nlos = Nlos(random_links=r.integer(_given(n, Nlos, "random_links"), "uwb.nlos.random_links", 0),
                    random_bias_m=r.pair(_given(n, Nlos, "random_bias_m"), "uwb.nlos.random_bias_m", 0),
                    outlier_probability=r.number(_given(n, Nlos, "outlier_probability"), "uwb.nlos.outlier_probability",
                                                 0, 1),
                    outlier_mean_m=r.number(_given(n, Nlos, "outlier_mean_m"), "uwb.nlos.outlier_mean_m", 0,
                                            low_open=True),
                    rss_loss_db=r.number(_given(n, Nlos, "rss_loss_db"), "uwb.nlos.rss_loss_db", 0))
    for i, link in enumerate(n.get("links") or []):
        path = f"uwb.nlos.links[{i}]"
        if not isinstance(link, (list, tuple)) or len(link) != 3:
            raise r.fail(path, f"expected [id_a, id_b, bias_m], got {link!r}")
        a = known(r.node_id(link[0], f"{path}[0]"), f"{path}[0]")
        b = known(r.node_id(link[1], f"{path}[1]"), f"{path}[1]")
        if a == b:
            raise r.fail(path, "a link needs two different nodes")
        uwb.nlos.links.append(NlosLink(a, b, r.number(link[2], f"{path}[2]", 0)))
    pairs = len(nodes) * (len(nodes) - 1) // 2
    if uwb.nlos.random_links + len(uwb.nlos.links) > pairs:
        raise r.fail("uwb.nlos.random_links", f"more NLOS links than the {pairs} node pairs")
    scenario.uwb = uwb

    a = r.mapping(top.get("accelerometer"), "accelerometer", _fields(Accelerometer))
    scenario.accelerometer = Accelerometer(
        noise_std_mg=r.number(_given(a, Accelerometer, "noise_std_mg"), "accelerometer.noise_std_mg", 0),
        moving_amplitude_mg=r.number(_given(a, Accelerometer, "moving_amplitude_mg"),
                                     "accelerometer.moving_amplitude_mg", 0),
        moving_frequency_hz=r.number(_given(a, Accelerometer, "moving_frequency_hz"),
                                     "accelerometer.moving_frequency_hz", 0, low_open=True))

    pz = r.mapping(top.get("pozyx"), "pozyx", {"firmware_version", "present"})
    dv = r.mapping(top.get("device"), "device", _fields(Device) - {"pozyx_firmware", "pozyx_present"})
    scenario.device = Device(
        pozyx_firmware=r.integer(_given(pz, Device, "firmware_version", "pozyx_firmware"), "pozyx.firmware_version",
                                 0, 0xFF),
        pozyx_present=r.boolean(_given(pz, Device, "present", "pozyx_present"), "pozyx.present"),
        free_ram_bytes=r.integer(_given(dv, Device, "free_ram_bytes"), "device.free_ram_bytes", 0, 0xFFFF),
        tx_buffer_bytes=r.integer(_given(dv, Device, "tx_buffer_bytes"), "device.tx_buffer_bytes", 128, 1 << 24))

    faults = top.get("faults") or []
    if not isinstance(faults, list):
        raise r.fail("faults", "expected a list")
    for i, raw in enumerate(faults):
        scenario.faults.append(parse_fault_mapping(raw, f"faults[{i}]", r))
    scenario.faults.sort(key=lambda f: f.at_s)
    return scenario


def parse_fault_mapping(raw: Any, path: str, r: _Reader) -> Fault:
    if not isinstance(raw, dict) or "kind" not in raw:
        raise r.fail(path, "expected a mapping with kind and at_s")
    kind = raw["kind"]
    if kind in FIL_FAULT_KINDS:
        raise r.fail(f"{path}.kind", f"only cdro-fil supports the fault kind {kind!r} (I2C and Pozyx faults under "
                                     f"simavr); cdro-sim's kinds are {', '.join(FAULT_KINDS)}")
    if kind not in FAULT_KINDS:
        raise r.fail(f"{path}.kind", f"{kind!r} is not one of {', '.join(FAULT_KINDS)}")
    m = r.mapping(raw, path, {"kind", "at_s", *FAULT_KINDS[kind]}, {"at_s"})
    params = dict(FAULT_KINDS[kind])
    for key in FAULT_KINDS[kind]:
        if key not in m:
            continue
        if key in ("bytes", "frames"):
            params[key] = r.integer(m[key], f"{path}.{key}", 1, 4096)
        elif key == "duration_s":
            params[key] = r.number(m[key], f"{path}.{key}", 0, 3600, low_open=True)
        elif key == "reboot":
            params[key] = r.boolean(m[key], f"{path}.{key}")
        elif key == "cause":
            if m[key] not in RESET_CAUSES:
                raise r.fail(f"{path}.cause", f"{m[key]!r} is not one of {', '.join(RESET_CAUSES)}")
            params[key] = m[key]
    return Fault(at_s=r.number(m["at_s"], f"{path}.at_s", 0), kind=kind, params=params)


def parse_fault_option(text: str) -> Fault:
    """--fault KIND@T[,key=value...], e.g. vanish@20,duration_s=3 or garbage@5,bytes=40."""
    r = _Reader("--fault")
    head, _, rest = text.partition(",")
    kind, at, at_s = head.partition("@")
    if not at:
        raise ScenarioError(f"--fault {text!r}: expected KIND@SECONDS[,key=value...]")
    raw: dict[str, Any] = {"kind": kind.strip()}
    try:
        raw["at_s"] = float(at_s)
    except ValueError:
        raise ScenarioError(f"--fault {text!r}: {at_s!r} is not a time in seconds") from None
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        if not eq:
            raise ScenarioError(f"--fault {text!r}: {item!r} is not key=value")
        raw[key.strip()] = yaml.safe_load(value)
    return parse_fault_mapping(raw, text, r)


# ---- built-in scenarios -----------------------------------------------------------------------

def builtin_names() -> list[str]:
    folder = importlib.resources.files("cdro_tools") / "scenarios"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_scenario(name_or_path: str) -> Scenario:
    """A built-in scenario by name (paper-fig3, demo, ...) or a YAML file."""
    path = pathlib.Path(name_or_path)
    if name_or_path in builtin_names():
        text = (importlib.resources.files("cdro_tools") / "scenarios" / f"{name_or_path}.yaml").read_text()
        source = f"built-in scenario {name_or_path}"
        default_name = name_or_path
    elif path.is_file():
        text = path.read_text()
        source = str(path)
        default_name = path.stem
    else:
        raise ScenarioError(f"{name_or_path}: neither a built-in scenario ({', '.join(builtin_names())}) "
                            f"nor a file")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ScenarioError(f"{source}: not valid YAML: {error}") from None
    return parse_scenario(data, source, default_name)


def shared_view(scenario: Scenario) -> dict[str, Any]:
    """What cdro-sim and cdro-fil both read from a scenario, in the form `cdro-fil --print-scenario`
    prints it (docs/tools.md, "Scenario files"): a file both tools load must give both the same.
    Each motion stretch has both its speed and its end, whichever of the two the file gives, and
    its waypoints with the height the node keeps."""
    motion = []
    at: dict[int, tuple[float, float]] = {n.id: (n.x_m, n.y_m) for n in scenario.nodes}
    for segment in sorted(scenario.motion, key=lambda s: s.start_s):
        points = [at[segment.node], *segment.waypoints]
        length_m = sum(math.dist(a, b) for a, b in zip(points, points[1:]))
        if segment.speed_mps is not None:
            speed_mps = segment.speed_mps
            end_s = segment.start_s + length_m / speed_mps
        else:
            end_s = segment.end_s
            speed_mps = length_m / (end_s - segment.start_s)
        at[segment.node] = segment.waypoints[-1]
        z_m = scenario.node(segment.node).z_m
        motion.append((segment, {"node": segment.node, "start_s": segment.start_s, "end_s": end_s,
                                 "speed_mps": speed_mps, "waypoints_m": [[x, y, z_m] for x, y in segment.waypoints]}))
    order = {id(segment): i for i, segment in enumerate(scenario.motion)}
    motion.sort(key=lambda item: order[id(item[0])])
    return {
        "name": scenario.name,
        "seed": scenario.seed,
        "duration_s": scenario.duration_s,
        "own_id": scenario.own_id,
        "nodes": [{"id": n.id, "x_m": n.x_m, "y_m": n.y_m, "z_m": n.z_m, "accelerometer": n.accelerometer}
                  for n in scenario.nodes],
        "motion": [view for _, view in motion],
        "uwb": {"noise_std_m": scenario.uwb.noise_std_m, "max_range_m": scenario.uwb.max_range_m},
        "accelerometer": {"noise_std_mg": scenario.accelerometer.noise_std_mg,
                          "moving_amplitude_mg": scenario.accelerometer.moving_amplitude_mg,
                          "moving_frequency_hz": scenario.accelerometer.moving_frequency_hz},
        "pozyx": {"firmware_version": scenario.device.pozyx_firmware},
    }


def from_shared_view(view: dict[str, Any], source: str) -> Scenario:
    """The Scenario of a shared view (`cdro-fil --print-scenario`, shared_view's form), so that the
    world model (world.World) places the nodes of a run of cdro-fil: what cdro-fil read, without a
    second reader of the YAML. Only the shared keys come through; the rest keep their defaults. A
    stretch carried up or down (a waypoint off the node's height, which only cdro-fil supports) is
    refused: the world model keeps each node at its height."""
    try:
        nodes = [Node(id=int(n["id"]), x_m=float(n["x_m"]), y_m=float(n["y_m"]), z_m=float(n["z_m"]),
                      accelerometer=bool(n["accelerometer"])) for n in view["nodes"]]
        heights_m = {n.id: n.z_m for n in nodes}
        motion = []
        for i, m in enumerate(view["motion"]):
            for k, (_, _, z_m) in enumerate(m["waypoints_m"]):
                if not math.isclose(z_m, heights_m[m["node"]], abs_tol=1e-9):
                    raise ScenarioError(f"{source}: motion[{i}].waypoints_m[{k}]: z {z_m} m is not the height of "
                                        f"node 0x{m['node']:04X} ({heights_m[m['node']]} m); the world model "
                                        "keeps each node at its height")
            motion.append(MotionSegment(node=int(m["node"]), start_s=float(m["start_s"]),
                                        waypoints=[(float(x), float(y)) for x, y, _ in m["waypoints_m"]],
                                        speed_mps=float(m["speed_mps"]), end_s=float(m["end_s"])))
        uwb, accel = view["uwb"], view["accelerometer"]
        return Scenario(name=str(view["name"]), own_id=int(view["own_id"]), nodes=nodes,
                        duration_s=float(view["duration_s"]), seed=int(view["seed"]), motion=motion,
                        uwb=Uwb(noise_std_m=float(uwb["noise_std_m"]), max_range_m=float(uwb["max_range_m"])),
                        accelerometer=Accelerometer(noise_std_mg=float(accel["noise_std_mg"]),
                                                    moving_amplitude_mg=float(accel["moving_amplitude_mg"]),
                                                    moving_frequency_hz=float(accel["moving_frequency_hz"])),
                        device=Device(pozyx_firmware=int(view["pozyx"]["firmware_version"])))
    except ScenarioError:
        raise
    except (KeyError, TypeError, ValueError) as error:
        raise ScenarioError(f"{source}: not a shared scenario view ({type(error).__name__}: {error})") from None
