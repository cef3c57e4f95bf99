"""Scenario files: YAML, checked strictly (unknown keys, wrong types and impossible values are
errors naming the key). Every key's default and valid range are sim/scenario_keys.def's, the one
definition cdro-fil expands too (KEYS, generated from it; docs/tools.md's table is as well).

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
from .scenario_keys import KEYS, RENAMED


class ScenarioError(ValueError):
    """A scenario that cannot be used; the message names the file and the key."""


def _default(key: str) -> Any:
    """The default sim/scenario_keys.def gives the key (a pair as a tuple)."""
    value = KEYS[key]["default"]
    return tuple(value) if isinstance(value, list) else value


# ---- the scenario, as dataclasses with the documented defaults -------------------------------

@dataclasses.dataclass
class Node:
    id: int
    x_m: float
    y_m: float
    z_m: float = _default("nodes[].z_m")
    accelerometer: bool = _default("nodes[].accelerometer")  # tags have one, anchors do not
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
    rate_hz: float = _default("robot.odometry.rate_hz")
    distance_noise_frac: float = _default("robot.odometry.distance_noise_frac")  # std of each step's relative error
    heading_noise_rad: float = _default("robot.odometry.heading_noise_rad")      # std per moving step (rad)
    heading_drift_rad_s: float = _default("robot.odometry.heading_drift_rad_s")  # rad/s, also standing still


@dataclasses.dataclass
class Robot:
    id: int
    start_s: float = _default("robot.start_s")  # drives from here on; before, it stands at its node position
    waypoints: list[tuple[float, float]] | None = None
    speed_mps: float = _default("robot.speed_mps")
    turn_rate_rad_s: float = _default("robot.turn_rate_rad_s")  # turns in place at waypoints
    heading_rad: float | None = None       # initial heading; default: towards the first waypoint
    poses: list[tuple[float, float, float]] | None = None  # alternative: (t_s, x_m, y_m), linear
    odometry: Odometry = dataclasses.field(default_factory=Odometry)
    moving_amplitude_mg: float = _default("robot.moving_amplitude_mg")  # vibration of a driving robot, mg


@dataclasses.dataclass
class Schedule:
    """The SET_SCHEDULE fields the simulated host sends (CSV and capture modes)."""

    mode: int = C[f"CDRO_SCHEDULE_{_default('schedule.mode').upper()}"]
    slot_period_ms: int = _default("schedule.slot_period_ms")
    motion_poll_ms: int = _default("schedule.motion_poll_ms")
    moving_boost: int = _default("schedule.moving_boost")
    status_period_ms: int = _default("schedule.status_period_ms")
    max_retries: int = _default("schedule.max_retries")

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
    random_links: int = _default("uwb.nlos.random_links")  # this many further links get a persistent bias ...
    random_bias_m: tuple[float, float] = _default("uwb.nlos.random_bias_m")  # ... drawn uniformly from this range
    outlier_probability: float = _default("uwb.nlos.outlier_probability")  # per range: reads long by an exponential
    outlier_mean_m: float = _default("uwb.nlos.outlier_mean_m")  # mean of that exponential tail
    rss_loss_db: float = _default("uwb.nlos.rss_loss_db")  # RSS lower on biased links


@dataclasses.dataclass
class Uwb:
    noise_std_m: float = _default("uwb.noise_std_m")       # Pozyx nominal accuracy
    noise_variance_m2: tuple[float, float] | None = None    # per-link variance drawn uniformly (overrides)
    scale: float = _default("uwb.scale")                   # measured = scale x true (+ errors)
    max_range_m: float = _default("uwb.max_range_m")       # beyond: the range fails (timeout)
    dropout_probability: float = _default("uwb.dropout_probability")  # per attempt: fails (Pozyx 0x11)
    nlos: Nlos = dataclasses.field(default_factory=Nlos)


@dataclasses.dataclass
class Accelerometer:
    noise_std_mg: float = _default("accelerometer.noise_std_mg")  # std of the norm's noise
    moving_amplitude_mg: float = _default("accelerometer.moving_amplitude_mg")  # swing while carried (walking)
    moving_frequency_hz: float = _default("accelerometer.moving_frequency_hz")  # step frequency


@dataclasses.dataclass
class Device:
    """What the firmware cannot know about its board. Everything else (its version, how many
    nodes it takes, its timing) is the firmware's own (firmware/core, run by cdro-sim).
    pozyx_firmware and pozyx_present are read from the scenario's pozyx section."""

    pozyx_firmware: int = _default("pozyx.firmware_version")  # FIRMWARE_VER, major << 4 | minor
    pozyx_present: bool = _default("pozyx.present")  # False: the shield does not answer on I2C
    free_ram_bytes: int = _default("device.free_ram_bytes")  # reported in STATUS
    tx_buffer_bytes: int = _default("device.tx_buffer_bytes")  # live mode: frames that do not fit are dropped


@dataclasses.dataclass
class Fault:
    at_s: float
    kind: str
    params: dict[str, Any] = dataclasses.field(default_factory=dict)


FAULT_KINDS = {
    # kind: {parameter: default}
    "garbage": {"bytes": _default("faults[].bytes")},
    "bit_flip": {"frames": 1},
    "cut_frame": {"frames": 1},
    "absurd": {"frames": 6},
    "vanish": {"duration_s": 3.0, "reboot": _default("faults[].reboot")},
    "reset": {"cause": _default("faults[].cause")},
}

# The faults cdro-fil injects on the I2C bus and in the simulated Pozyx; cdro-sim's device is not
# behind a simulated I2C bus, so it cannot act on them.
FIL_FAULT_KINDS = ("nack_address", "nack_write", "no_completion", "error_completion", "garbage_range",
                   "stale_range", "drop_remote_reply", "refuse_function", "late_reply", "power_off")

# Keys of the one scenario format that only cdro-fil acts on, by path with list indices written [],
# and the note the refusal gives: sim/scenario_keys.def's tool and meaning.
FIL_ONLY_KEYS = {path: spec["meaning"] for path, spec in KEYS.items() if spec["tool"] == "cdro-fil"}

# Spellings of earlier scenario files (cdro-sim's and cdro-fil's) and what they are called now
# (sim/scenario_keys.def). The keys are refused rather than read, so that a file has one spelling.
RENAMED_KEYS = RENAMED

RESET_CAUSES = {"power_on": C["CDRO_RESET_POWER_ON"], "external": C["CDRO_RESET_EXTERNAL"],
                "brown_out": C["CDRO_RESET_BROWN_OUT"], "watchdog": C["CDRO_RESET_WATCHDOG"]}


@dataclasses.dataclass
class Scenario:
    name: str
    own_id: int
    nodes: list[Node]
    duration_s: float = _default("duration_s")
    seed: int = _default("seed")
    description: str = ""
    motion: list[MotionSegment] = dataclasses.field(default_factory=list)
    robot: Robot | None = None
    schedule: Schedule = dataclasses.field(default_factory=Schedule)
    uwb: Uwb = dataclasses.field(default_factory=Uwb)
    accelerometer: Accelerometer = dataclasses.field(default_factory=Accelerometer)
    device: Device = dataclasses.field(default_factory=Device)
    faults: list[Fault] = dataclasses.field(default_factory=list)
    epoch_unix_s: float = _default("epoch_unix_s")  # host clock at the start, for capture files

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

    def number(self, value: Any, path: str, low: float | None = None) -> float:
        """A finite number; `low` for a value that is not a key of sim/scenario_keys.def (a link's bias)."""
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(path, f"expected a number, got {value!r}")
        if low is not None and value < low:
            raise self.fail(path, f"must be at least {low}, got {value}")
        return float(value)

    def integer(self, value: Any, path: str) -> int:
        if isinstance(value, str):
            try:
                value = int(value, 0)
            except ValueError:
                raise self.fail(path, f"expected an integer, got {value!r}") from None
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(path, f"expected an integer, got {value!r}")
        return value

    def checked(self, value: Any, path: str, key: str | None = None) -> int | float:
        """value as the key at `path` (or `key`, its place in sim/scenario_keys.def) takes it: of
        its type and inside its range, said in the words cdro-fil uses."""
        spec = KEYS[key or _pattern(path)]
        number = self.integer(value, path) if spec["type"] == "INT" else self.number(value, path)
        if not admits(spec, number):
            raise self.fail(path, f"must be {spec['requirement']}, got {value}")
        return number

    def get(self, m: dict, key: str, path: str) -> Any:
        """m[key] checked, or the key's default in sim/scenario_keys.def if m leaves it out."""
        return self.checked(m[key], path) if key in m else _default(_pattern(path))

    def count(self, value: list, path: str) -> None:
        spec = KEYS[_pattern(path)]
        if not admits(spec, len(value)):
            raise self.fail(path, f"the number of entries must be {spec['requirement']}, got {len(value)}")

    def boolean(self, value: Any, path: str) -> bool:
        if not isinstance(value, bool):
            raise self.fail(path, f"expected true or false, got {value!r}")
        return value

    def pair(self, value: Any, path: str) -> tuple[float, float]:
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise self.fail(path, f"expected [low, high], got {value!r}")
        lo, hi = (self.checked(v, f"{path}[{i}]", _pattern(path)) for i, v in enumerate(value))
        if hi < lo:
            raise self.fail(path, f"high {hi} is below low {lo}")
        return lo, hi

    def points(self, value: Any, path: str, size: int, key: str | None = None) -> list[tuple[float, ...]]:
        """A list of points; with `key`, each coordinate checked as that key of sim/scenario_keys.def."""
        if not isinstance(value, list) or not value:
            raise self.fail(path, "expected a non-empty list of points")
        out = []
        for i, point in enumerate(value):
            if path.startswith("motion") and isinstance(point, (list, tuple)) and len(point) == 3:
                raise self.fail(f"{path}[{i}]", "only cdro-fil supports [x, y, z] waypoints (a node carried up or "
                                                "down); cdro-sim keeps each node at its z_m: give [x, y]")
            if not isinstance(point, (list, tuple)) or len(point) != size:
                raise self.fail(f"{path}[{i}]", f"expected {size} numbers, got {point!r}")
            out.append(tuple(self.checked(v, f"{path}[{i}][{k}]", key) if key else self.number(v, f"{path}[{i}][{k}]")
                             for k, v in enumerate(point)))
        return out


def _pattern(path: str) -> str:
    """A key's place with list indices written [], as sim/scenario_keys.def names it."""
    return re.sub(r"\[\d+\]", "[]", path)


def admits(spec: dict, value: float) -> bool:
    """Whether value is inside the key's range (sim/scenario_keys.def; BOUNDS says which ends are open)."""
    low_open = spec["bounds"] in ("OPEN_MIN", "OPEN")
    high_open = spec["bounds"] in ("OPEN_MAX", "OPEN")
    return ((value > spec["min"] if low_open else value >= spec["min"])
            and (value < spec["max"] if high_open else value <= spec["max"]))


def _fields(cls) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


def parse_scenario(data: Any, source: str, default_name: str = "scenario") -> Scenario:
    r = _Reader(source)
    top = r.mapping(data, "(top)", {"name", "description", "duration_s", "seed", "own_id", "nodes", "motion",
                                    "robot", "schedule", "uwb", "accelerometer", "pozyx", "device", "faults",
                                    "epoch_unix_s"}, {"own_id", "nodes"})
    nodes: list[Node] = []
    if not isinstance(top["nodes"], list):
        raise r.fail("nodes", "expected a list of nodes")
    r.count(top["nodes"], "nodes")
    for i, raw in enumerate(top["nodes"]):
        path = f"nodes[{i}]"
        m = r.mapping(raw, path, {"id", "x_m", "y_m", "z_m", "accelerometer", "moving_amplitude_mg"},
                      {"id", "x_m", "y_m"})
        nodes.append(Node(
            id=r.get(m, "id", f"{path}.id"), x_m=r.get(m, "x_m", f"{path}.x_m"), y_m=r.get(m, "y_m", f"{path}.y_m"),
            z_m=float(r.get(m, "z_m", f"{path}.z_m")),
            accelerometer=r.boolean(m.get("accelerometer", Node.accelerometer), f"{path}.accelerometer"),
            moving_amplitude_mg=(None if m.get("moving_amplitude_mg") is None
                                 else r.get(m, "moving_amplitude_mg", f"{path}.moving_amplitude_mg"))))
    ids = [n.id for n in nodes]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise r.fail("nodes", "duplicate id(s) " + ", ".join(f"0x{i:04X}" for i in duplicates))
    own_id = r.get(top, "own_id", "own_id")
    if own_id not in ids:
        raise r.fail("own_id", f"0x{own_id:04X} is not among the nodes")

    def known(node_id: int, path: str) -> int:
        if node_id not in ids:
            raise r.fail(path, f"0x{node_id:04X} is not among the nodes")
        return node_id

    if top.get("duration_s") == 0:
        raise r.fail("duration_s", "only cdro-fil supports 0 (run until stopped); cdro-sim needs a duration")
    scenario = Scenario(name=str(top.get("name", default_name)), own_id=own_id, nodes=nodes,
                        duration_s=float(r.get(top, "duration_s", "duration_s")), seed=r.get(top, "seed", "seed"),
                        description=str(top.get("description", "")).strip(),
                        epoch_unix_s=float(r.get(top, "epoch_unix_s", "epoch_unix_s")))

    for i, raw in enumerate(top.get("motion") or []):
        path = f"motion[{i}]"
        m = r.mapping(raw, path, {"node", "start_s", "waypoints_m", "speed_mps", "end_s"},
                      {"node", "start_s", "waypoints_m"})
        segment = MotionSegment(node=known(r.get(m, "node", f"{path}.node"), f"{path}.node"),
                                start_s=float(r.get(m, "start_s", f"{path}.start_s")),
                                waypoints=r.points(m["waypoints_m"], f"{path}.waypoints_m", 2, "motion[].waypoints_m"))
        if ("speed_mps" in m) == ("end_s" in m):
            raise r.fail(path, "give exactly one of speed_mps and end_s")
        if "speed_mps" in m:
            segment.speed_mps = float(r.get(m, "speed_mps", f"{path}.speed_mps"))
        else:
            segment.end_s = float(r.get(m, "end_s", f"{path}.end_s"))
            if segment.end_s <= segment.start_s:
                raise r.fail(f"{path}.end_s", "must be after start_s")
        scenario.motion.append(segment)
    _check_implied_speeds(scenario, r)

    if top.get("robot") is not None:
        path = "robot"
        m = r.mapping(top["robot"], path, _fields(Robot) - {"waypoints"} | {"waypoints_m"}, {"id"})
        robot = Robot(id=known(r.get(m, "id", "robot.id"), "robot.id"),
                      start_s=float(r.get(m, "start_s", "robot.start_s")),
                      speed_mps=float(r.get(m, "speed_mps", "robot.speed_mps")),
                      turn_rate_rad_s=float(r.get(m, "turn_rate_rad_s", "robot.turn_rate_rad_s")),
                      moving_amplitude_mg=float(r.get(m, "moving_amplitude_mg", "robot.moving_amplitude_mg")))
        if ("waypoints_m" in m) == ("poses" in m):
            raise r.fail(path, "give exactly one of waypoints_m and poses")
        if "waypoints_m" in m:
            robot.waypoints = r.points(m["waypoints_m"], "robot.waypoints_m", 2, "robot.waypoints_m")
        else:
            robot.poses = r.points(m["poses"], "robot.poses", 3)
            times = [p[0] for p in robot.poses]
            if any(b <= a for a, b in zip(times, times[1:])):
                raise r.fail("robot.poses", "times must increase")
        if m.get("heading_rad") is not None:
            robot.heading_rad = float(r.get(m, "heading_rad", "robot.heading_rad"))
        o = r.mapping(m.get("odometry"), "robot.odometry", _fields(Odometry))
        robot.odometry = Odometry(**{key: float(r.get(o, key, f"robot.odometry.{key}")) for key in _fields(Odometry)})
        if any(s.node == robot.id for s in scenario.motion):
            raise r.fail("motion", f"the robot 0x{robot.id:04X} moves by its path, not by motion segments")
        scenario.robot = robot

    s = r.mapping(top.get("schedule"), "schedule", _fields(Schedule))
    modes = {"direct_only": C["CDRO_SCHEDULE_DIRECT_ONLY"], "all_pairs": C["CDRO_SCHEDULE_ALL_PAIRS"]}
    mode = s.get("mode", _default("schedule.mode"))
    if mode not in modes:
        raise r.fail("schedule.mode", f"{mode!r} is not one of {', '.join(modes)}")
    scenario.schedule = Schedule(mode=modes[mode], **{key: r.get(s, key, f"schedule.{key}")
                                                      for key in _fields(Schedule) - {"mode"}})

    u = r.mapping(top.get("uwb"), "uwb", _fields(Uwb))
    uwb = Uwb(**{key: float(r.get(u, key, f"uwb.{key}"))
                 for key in ("noise_std_m", "scale", "max_range_m", "dropout_probability")})
    if u.get("noise_variance_m2") is not None:
        uwb.noise_variance_m2 = r.pair(u["noise_variance_m2"], "uwb.noise_variance_m2")
    n = r.mapping(u.get("nlos"), "uwb.nlos", _fields(Nlos))
    uwb.nlos = Nlos(random_links=r.get(n, "random_links", "uwb.nlos.random_links"),
                    random_bias_m=(r.pair(n["random_bias_m"], "uwb.nlos.random_bias_m") if "random_bias_m" in n
                                   else _default("uwb.nlos.random_bias_m")),
                    **{key: float(r.get(n, key, f"uwb.nlos.{key}"))
                       for key in ("outlier_probability", "outlier_mean_m", "rss_loss_db")})
    for i, link in enumerate(n.get("links") or []):
        path = f"uwb.nlos.links[{i}]"
        if not isinstance(link, (list, tuple)) or len(link) != 3:
            raise r.fail(path, f"expected [id_a, id_b, bias_m], got {link!r}")
        a = known(r.checked(link[0], f"{path}[0]", "nodes[].id"), f"{path}[0]")
        b = known(r.checked(link[1], f"{path}[1]", "nodes[].id"), f"{path}[1]")
        if a == b:
            raise r.fail(path, "a link needs two different nodes")
        uwb.nlos.links.append(NlosLink(a, b, r.number(link[2], f"{path}[2]", 0)))
    pairs = len(nodes) * (len(nodes) - 1) // 2
    if uwb.nlos.random_links + len(uwb.nlos.links) > pairs:
        raise r.fail("uwb.nlos.random_links", f"more NLOS links than the {pairs} node pairs")
    scenario.uwb = uwb

    a = r.mapping(top.get("accelerometer"), "accelerometer", _fields(Accelerometer))
    scenario.accelerometer = Accelerometer(**{key: float(r.get(a, key, f"accelerometer.{key}"))
                                              for key in _fields(Accelerometer)})

    pz = r.mapping(top.get("pozyx"), "pozyx", {"firmware_version", "present"})
    dv = r.mapping(top.get("device"), "device", _fields(Device) - {"pozyx_firmware", "pozyx_present"})
    scenario.device = Device(
        pozyx_firmware=r.get(pz, "firmware_version", "pozyx.firmware_version"),
        pozyx_present=r.boolean(pz.get("present", _default("pozyx.present")), "pozyx.present"),
        free_ram_bytes=r.get(dv, "free_ram_bytes", "device.free_ram_bytes"),
        tx_buffer_bytes=r.get(dv, "tx_buffer_bytes", "device.tx_buffer_bytes"))

    faults = top.get("faults") or []
    if not isinstance(faults, list):
        raise r.fail("faults", "expected a list")
    for i, raw in enumerate(faults):
        scenario.faults.append(parse_fault_mapping(raw, f"faults[{i}]", r))
    scenario.faults.sort(key=lambda f: f.at_s)
    return scenario


def _check_implied_speeds(scenario: Scenario, r: _Reader) -> None:
    """A stretch given by its end: the speed it implies, from where the node is at its start (the
    end of its stretch before), must be a speed motion[].speed_mps admits, as cdro-fil checks."""
    spec = KEYS["motion[].speed_mps"]
    at = {n.id: (n.x_m, n.y_m) for n in scenario.nodes}
    order = sorted(range(len(scenario.motion)), key=lambda i: scenario.motion[i].start_s)
    for i in order:
        segment = scenario.motion[i]
        points = [at[segment.node], *segment.waypoints]
        at[segment.node] = segment.waypoints[-1]
        if segment.end_s is None:
            continue
        length_m = sum(math.dist(a, b) for a, b in zip(points, points[1:]))
        took_s = segment.end_s - segment.start_s
        if not admits(spec, length_m / took_s):
            raise r.fail(f"motion[{i}].end_s", f"{length_m:g} m in {took_s:g} s is {length_m / took_s:g} m/s; "
                                               f"the speed must be {spec['requirement']}")


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
        if key == "reboot":
            params[key] = r.boolean(m[key], f"{path}.{key}")
        elif key == "cause":
            if m[key] not in RESET_CAUSES:
                raise r.fail(f"{path}.cause", f"{m[key]!r} is not one of {', '.join(RESET_CAUSES)}")
            params[key] = m[key]
        else:  # bytes, frames, duration_s: ranged in sim/scenario_keys.def
            params[key] = r.checked(m[key], f"{path}.{key}", f"faults[].{key}")
    return Fault(at_s=float(r.checked(m["at_s"], f"{path}.at_s", "faults[].at_s")), kind=kind, params=params)


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
