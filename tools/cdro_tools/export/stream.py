"""The service's live stream as a map state: JSON Lines objects (`node`, `robot`, `health`, from a
file, stdin or MQTT payloads) and the live map's server-sent `map` events (docs/outputs.md,
docs/service.md "Outputs").

Written against the documented schema; keys that newer services add are used when present and
never required: `t_unix_s` (s since the Unix epoch), a robot `frame` (`odometry` or `map`), the
robot's heading variance and x/y-heading covariances, `z_m`, and null positions for nodes that
are not placed. What cannot be used is dropped, counted by reason and reported (`Tally`), and
reading goes on.
"""
from __future__ import annotations

import collections
import dataclasses
import json
import math
import sys
import time
import urllib.error
import urllib.request
from typing import IO, Callable, Iterable, Iterator

KINDS = ("node", "robot", "health")


class StreamError(Exception):
    """An input that cannot be read at all (not a problem of one line)."""


@dataclasses.dataclass
class Tally:
    """What was taken and what was dropped, by reason; the first few drops are printed."""

    name: str = "input"
    print_first: int = 5                       # drops printed in full; the rest only counted
    out: IO[str] | None = None                 # where drops are reported (stderr)
    taken: int = 0
    dropped: collections.Counter = dataclasses.field(default_factory=collections.Counter)

    def drop(self, where: str, reason: str) -> None:
        self.dropped[reason] += 1
        if sum(self.dropped.values()) <= self.print_first:
            print(f"{self.name}: {where}: dropped: {reason}", file=self.out or sys.stderr)

    @property
    def dropped_total(self) -> int:
        return sum(self.dropped.values())

    def summary(self) -> str:
        if not self.dropped:
            return f"{self.name}: {self.taken} object(s) taken, none dropped"
        reasons = ", ".join(f"{count} {reason}" for reason, count in self.dropped.most_common())
        return f"{self.name}: {self.taken} object(s) taken, {self.dropped_total} dropped ({reasons})"


def unix_time_s(obj: dict | None) -> float | None:
    """The object's t_unix_s when it is a usable time, else None."""
    value = (obj or {}).get("t_unix_s")
    return float(value) if _finite(value) and 0 <= value < 2**32 else None


def seconds_to_ns(t_s: float) -> int:
    """s (float) to integer ns at the service's resolution, the microsecond (its clocks are us;
    t_unix_s is written to the us). Whole seconds and the fraction apart: an epoch time in a
    double is only good to ~0.2 us, and t x 1e9 would carry that error into the ns."""
    whole = math.floor(t_s)
    return whole * 1_000_000_000 + round((t_s - whole) * 1e6) * 1000


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_object(obj) -> str:
    """Why a JSON Lines object cannot be used ("" when it can)."""
    if not isinstance(obj, dict):
        return "not a JSON object"
    kind = obj.get("type")
    if kind not in KINDS:
        return f"unknown type {kind!r}"
    if kind == "health":
        if obj.get("t_unix_s") is not None and not (_finite(obj["t_unix_s"]) and 0 <= obj["t_unix_s"] < 2**32):
            return "health t_unix_s is not a time (a number of s, 0 .. 2^32)"
        return "" if isinstance(obj.get("counters", {}), dict) else "health counters are not an object"
    if not isinstance(obj.get("id"), int) or isinstance(obj.get("id"), bool) or not 0 < obj["id"] <= 0xFFFF:
        return f"{kind} without a node id (1..65535)"
    for key in ("t_s", "t_unix_s"):
        # Times go into unsigned 32-bit seconds (ROS and Foxglove stamps): 0 .. 2^32 s.
        if obj.get(key) is not None and not (_finite(obj[key]) and 0 <= obj[key] < 2**32):
            return f"{kind} {key} is not a time (a number of s, 0 .. 2^32)"
    if kind == "node" and not node_placed(obj):
        return ""  # an unplaced node's position is not looked at (0, 0 today, null later)
    for key in ("x_m", "y_m"):
        if not _finite(obj.get(key)):
            return f"{kind} {key} is not a number"
    if kind == "robot" and obj.get("heading_rad") is not None and not _finite(obj["heading_rad"]):
        return "robot heading_rad is not a number"
    return ""


def node_placed(node: dict) -> bool:
    """Placed and with a position: today `placed`/`status`; a null position (newer services)
    also means not placed."""
    if node.get("x_m") is None or node.get("y_m") is None:
        return False
    if "placed" in node:
        return bool(node["placed"])
    return node.get("status", "placed") != "unplaced"


def node_status(node: dict) -> str:
    """The lifecycle word of docs/outputs.md; derived from the booleans when `status` is absent."""
    status = node.get("status")
    if isinstance(status, str) and status:
        return status
    if not node_placed(node):
        return "unplaced"
    if node.get("moving"):
        return "moving"
    return "converged" if node.get("converged") else "placed"


def covariance_2x2(obj: dict) -> tuple[float, float, float]:
    """(var_x, cov_xy, var_y) in m^2; missing or non-finite terms count as 0."""
    return tuple(float(obj[k]) if _finite(obj.get(k)) else 0.0 for k in ("var_x_m2", "cov_xy_m2", "var_y_m2"))


# Names the robot's heading terms may carry (docs/outputs.md of newer services); the first one
# present is used. rad^2 and m*rad.
ROBOT_HEADING_KEYS = {
    "var_heading": ("var_heading_rad2", "var_theta_rad2"),
    "cov_x_heading": ("cov_x_heading_m_rad", "cov_x_theta_m_rad"),
    "cov_y_heading": ("cov_y_heading_m_rad", "cov_y_theta_m_rad"),
}


def robot_covariance_3x3(robot: dict) -> tuple[list[list[float]], bool]:
    """The robot's (x, y, heading) covariance (m^2, m rad, rad^2) and whether the heading terms
    were in the line. A `covariance` / `cov_3x3` key holding a 3x3 (or 9 numbers) wins; else the
    2x2 keys plus the heading keys above; else the heading row and column are 0 and the flag is
    False (docs/outputs.md today gives the 2x2 block only)."""
    for key in ("covariance", "cov_3x3", "covariance_3x3"):
        value = robot.get(key)
        flat = None
        if isinstance(value, list) and len(value) == 3 and all(isinstance(r, list) and len(r) == 3 for r in value):
            flat = [v for r in value for v in r]
        elif isinstance(value, list) and len(value) == 9:
            flat = value
        if flat is not None and all(_finite(v) for v in flat):
            return [[float(flat[3 * i + j]) for j in range(3)] for i in range(3)], True
    vx, cxy, vy = covariance_2x2(robot)
    found = {}
    for name, keys in ROBOT_HEADING_KEYS.items():
        found[name] = next((float(robot[k]) for k in keys if _finite(robot.get(k))), None)
    have = found["var_heading"] is not None
    vh = found["var_heading"] or 0.0
    cxh = found["cov_x_heading"] or 0.0
    cyh = found["cov_y_heading"] or 0.0
    return [[vx, cxy, cxh], [cxy, vy, cyh], [cxh, cyh, vh]], have


def robot_frame(robot: dict) -> str:
    """`map` or `odometry`: the robot line's `frame` when given; today's lines do not say, and the
    live robot is then taken to be in the map's frame (the map and the robot share the engine's
    output frame once a map exists, docs/engine.md "Stage 2")."""
    frame = robot.get("frame")
    return frame if frame in ("map", "odometry") else "map"


@dataclasses.dataclass
class MapState:
    """The latest of everything the stream said."""

    nodes: dict[int, dict] = dataclasses.field(default_factory=dict)
    robot: dict | None = None
    links: list[dict] | None = None            # only the live map's events carry links
    health: dict | None = None
    t_s: float | None = None                   # s since the run started (the service's t_s)
    t_unix_s: float | None = None              # s since the Unix epoch, when the stream says so

    def apply(self, obj: dict) -> str:
        """One checked JSON Lines object; returns its type."""
        kind = obj["type"]
        if kind == "node":
            self.nodes[obj["id"]] = obj
        elif kind == "robot":
            self.robot = obj
        else:
            self.health = obj
        self._clock(obj)
        return kind

    def apply_map(self, event: dict, tally: Tally, where: str) -> None:
        """A live map event (`/api/map` object): replaces the nodes, robot, links and health."""
        nodes = {}
        for node in event.get("nodes") or []:
            candidate = dict(node, type="node")
            reason = check_object(candidate)
            if reason:
                tally.drop(where, reason)
                continue
            nodes[candidate["id"]] = candidate
        self.nodes = nodes
        robot = event.get("robot")
        if robot is not None:
            candidate = dict(robot, type="robot")
            reason = check_object(candidate)
            if reason:
                tally.drop(where, reason)
                robot = None
            else:
                robot = candidate
        self.robot = robot
        links = event.get("links")
        self.links = [link for link in links if isinstance(link, dict) and isinstance(link.get("a"), int)
                      and isinstance(link.get("b"), int)] if isinstance(links, list) else None
        health = event.get("health")
        self.health = health if isinstance(health, dict) else self.health
        self._clock(event)
        tally.taken += 1

    def _clock(self, obj: dict) -> None:
        if _finite(obj.get("t_s")):
            self.t_s = float(obj["t_s"])
        if unix_time_s(obj) is not None:
            self.t_unix_s = unix_time_s(obj)


def parse_jsonl_line(text: str, where: str, tally: Tally) -> dict | None:
    """One line of JSON Lines, checked; None (dropped and counted) when it cannot be used."""
    text = text.strip()
    if not text:
        return None
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as error:
        tally.drop(where, f"not JSON ({error.msg})")
        return None
    reason = check_object(obj)
    if reason:
        tally.drop(where, reason)
        return None
    tally.taken += 1
    return obj


def read_jsonl(stream: Iterable[str], name: str, tally: Tally) -> Iterator[dict]:
    """The usable objects of a JSON Lines stream, in order."""
    for number, text in enumerate(stream, start=1):
        obj = parse_jsonl_line(text, f"{name}:{number}", tally)
        if obj is not None:
            yield obj


def parse_sse(lines: Iterable[bytes]) -> Iterator[tuple[str, str]]:
    """(event, data) of a text/event-stream (the WHATWG rules the live map's server follows:
    `event:` and `data:` fields, a blank line ends an event, `:` lines are comments)."""
    event, data = "message", []
    for raw in lines:
        line = raw.decode("utf-8", errors="replace").rstrip("\r\n")
        if not line:
            if data:
                yield event, "\n".join(data)
            event, data = "message", []
            continue
        if line.startswith(":"):
            continue
        field, _, value = line.partition(":")
        value = value[1:] if value.startswith(" ") else value
        if field == "event":
            event = value
        elif field == "data":
            data.append(value)


def follow_sse(url: str, tally: Tally, stop: Callable[[], bool], log: Callable[[str], None],
               reconnect_max_s: float = 5.0) -> Iterator[dict]:
    """The `map` events of the live map at url (`http://host:port/`, `/api/events` is appended
    unless given), as JSON objects; reconnects with backoff (0.2 s doubling to reconnect_max_s)
    as the browser does, until stop() is true."""
    if not url.rstrip("/").endswith("/api/events"):
        url = url.rstrip("/") + "/api/events"
    delay_s = 0.2
    number = 0
    while not stop():
        try:
            # The server sends a comment every 10 s: a read timeout of 30 s means it is gone.
            with urllib.request.urlopen(url, timeout=30) as response:
                log(f"following {url}")
                delay_s = 0.2
                for event, data in parse_sse(response):
                    number += 1
                    if event != "map":
                        continue
                    try:
                        obj = json.loads(data)
                    except json.JSONDecodeError as error:
                        tally.drop(f"{url} event {number}", f"not JSON ({error.msg})")
                        continue
                    if not isinstance(obj, dict):
                        tally.drop(f"{url} event {number}", "not a JSON object")
                        continue
                    yield obj
                    if stop():
                        return
        except (urllib.error.URLError, OSError, ValueError) as error:
            log(f"{url}: {error}; retrying in {delay_s:g} s")
        end = time.monotonic() + delay_s
        while time.monotonic() < end and not stop():
            time.sleep(0.05)
        delay_s = min(delay_s * 2, reconnect_max_s)
