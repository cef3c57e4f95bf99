"""Where map states go: Foxglove channels (an MCAP file, or the live WebSocket server) or a ROS 2
MCAP file; and the loop that turns a stream of JSON Lines objects into their messages."""
from __future__ import annotations

import collections
import dataclasses
import json
import math
from typing import Iterable, Iterator

import foxglove
from foxglove import channels as fc

from . import ros2, scene
from .ranges import RangeRow
from .stream import MapState, seconds_to_ns, unix_time_s


class FoxgloveChannels:
    """The Foxglove topics of docs/outputs.md on one foxglove Context (the global one for the
    live server, a private one per MCAP file)."""

    def __init__(self, context: foxglove.Context | None = None):
        kw = {"context": context} if context is not None else {}
        self.nodes_channel = fc.SceneUpdateChannel(scene.TOPIC_NODES, **kw)
        self.links_channel = fc.SceneUpdateChannel(scene.TOPIC_LINKS, **kw)
        self.pose_channel = fc.PoseInFrameChannel(scene.TOPIC_ROBOT_POSE, **kw)
        self.path_channel = fc.PosesInFrameChannel(scene.TOPIC_ROBOT_PATH, **kw)
        self.robot_scene_channel = fc.SceneUpdateChannel(scene.TOPIC_ROBOT_SCENE, **kw)
        self.tf_channel = fc.FrameTransformsChannel(scene.TOPIC_TF, **kw)
        self.health_channel = foxglove.Channel(scene.TOPIC_HEALTH, schema=scene.HEALTH_SCHEMA, **kw)
        self._ranges_channel = None
        self._context = kw
        self.builder = scene.SceneBuilder()
        self.counts: collections.Counter = collections.Counter()

    def _log(self, channel, topic: str, message, t_ns: int | None) -> None:
        channel.log(message, log_time=t_ns)
        self.counts[topic] += 1

    def nodes(self, state: MapState, t_ns: int, only: set[int] | None = None) -> None:
        self._log(self.nodes_channel, scene.TOPIC_NODES, self.builder.nodes(state, t_ns, only), t_ns)
        links = self.builder.links(state, t_ns)
        if links is not None:
            self._log(self.links_channel, scene.TOPIC_LINKS, links, t_ns)

    def robot(self, state: MapState, t_ns: int, repeat: bool = False) -> None:
        built = self.builder.robot(state, t_ns, repeat)
        if built is None:
            return
        pose, path, robot_scene, transforms = built
        self._log(self.pose_channel, scene.TOPIC_ROBOT_POSE, pose, t_ns)
        self._log(self.path_channel, scene.TOPIC_ROBOT_PATH, path, t_ns)
        self._log(self.robot_scene_channel, scene.TOPIC_ROBOT_SCENE, robot_scene, t_ns)
        self._log(self.tf_channel, scene.TOPIC_TF, transforms, t_ns)

    def health(self, state: MapState, t_ns: int) -> None:
        if state.health is not None:
            self._log(self.health_channel, scene.TOPIC_HEALTH, state.health, t_ns)

    def range(self, row: RangeRow, t_ns: int) -> None:
        if self._ranges_channel is None:
            self._ranges_channel = foxglove.Channel(scene.TOPIC_RANGES, schema=scene.RANGE_SCHEMA, **self._context)
        self._log(self._ranges_channel, scene.TOPIC_RANGES,
                  {"t_s": row.t_s, "from": row.from_id, "to": row.to_id, "range_m": row.distance_mm / 1000,
                   "rss_dbm": row.rss_dbm, "flags": row.flags, "device_time_ms": row.device_time_ms}, t_ns)


class FoxgloveRecorder(FoxgloveChannels):
    """An MCAP file with Foxglove's schemas (protobuf; health and ranges as JSON with a JSON schema)."""

    def __init__(self, path: str):
        self._foxglove_context = foxglove.Context()
        try:
            self._writer = foxglove.open_mcap(path, allow_overwrite=True, context=self._foxglove_context)
        except OSError as error:  # the SDK's message does not name the file
            raise OSError(f"{path}: {error}") from error
        super().__init__(self._foxglove_context)

    def close(self) -> None:
        self._writer.close()


class Ros2Recorder:
    """An MCAP file with ROS 2 messages (profile ros2, ros2msg schemas, CDR)."""

    def __init__(self, path: str):
        from mcap_ros2.writer import Writer  # here: only --ros2 needs it

        self._file = open(path, "wb")
        self._writer = Writer(self._file)
        definitions = ros2.message_definitions()
        # Schema names as rosbag2 writes them (pkg/msg/Type): the player loads the type support by it.
        self._schemas = {name: self._writer.register_msgdef(name, text)
                         for name, text in definitions.items()}
        self.counts: collections.Counter = collections.Counter()
        self._last_robot_key = None

    def _write(self, topic: str, type_name: str, message: dict, t_ns: int) -> None:
        self._writer.write_message(topic, self._schemas[type_name], message, log_time=t_ns, publish_time=t_ns,
                                   sequence=self.counts[topic])
        self.counts[topic] += 1

    def nodes(self, state: MapState, t_ns: int, only: set[int] | None = None) -> None:
        self._write(ros2.TOPIC_MARKERS, ros2.MARKERS_TYPE, ros2.markers(state, t_ns, only), t_ns)

    def robot(self, state: MapState, t_ns: int) -> None:
        robot = state.robot
        if robot is None:
            return
        key = (robot.get("t_s"), robot["x_m"], robot["y_m"], robot.get("heading_rad"))
        if key == self._last_robot_key:
            return
        self._last_robot_key = key
        self._write(ros2.TOPIC_POSE, ros2.POSE_TYPE, ros2.robot_pose(robot, t_ns), t_ns)
        self._write(ros2.TOPIC_TF, ros2.TF_TYPE, ros2.transforms(robot, t_ns), t_ns)

    def health(self, state: MapState, t_ns: int) -> None:
        if state.health is not None:
            self._write(ros2.TOPIC_HEALTH, ros2.STRING_TYPE, {"data": json.dumps(state.health)}, t_ns)

    def range(self, row: RangeRow, t_ns: int) -> None:
        """Ranges are not part of the ROS 2 recording (no standard message for a UWB range)."""

    def close(self) -> None:
        self._writer.finish()
        self._file.close()


@dataclasses.dataclass
class Written:
    counts: collections.Counter
    saw_unix_time: bool


def _t_ns(obj: dict, start_ns: int | None) -> tuple[int, bool]:
    """(message time in ns since the Unix epoch, whether the line said so itself)."""
    t_unix = unix_time_s(obj)
    if t_unix is not None:
        return seconds_to_ns(t_unix), True
    return (start_ns or 0) + seconds_to_ns(float(obj.get("t_s") or 0.0)), False


def record_stream(sink, objects: Iterable[dict], ranges: Iterator[RangeRow] | None, rate_hz: float,
                  start_ns: int | None) -> Written:
    """Feeds a stream of checked JSON Lines objects (in stream order) into sink; start_ns (ns since
    the epoch at t_s = 0) stamps lines without t_unix_s.

    rate_hz 0: each node line gives an update of that node, each robot line a pose (and path and
    transforms), each health line a health message. rate_hz > 0: per period of 1/rate_hz s of
    stream time (t_s) in which something changed, the whole map once (and the robot once), at the
    time of the period's last node (robot) line; health lines always pass. Ranges (from a capture) go in at
    their own times, merged in time order, and make the links (the pairs ranged so far) that the
    nodes' messages then carry."""
    state = MapState()
    saw_unix = False
    period_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
    current_period = None
    dirty_nodes = dirty_robot = False
    nodes_t_ns = robot_t_ns = 0                # ns: the time of the last node / robot line
    pending_range = next(ranges, None) if ranges is not None else None
    links: dict[tuple[int, int], dict] = {}    # the pairs ranged so far, as the live map lists them
    if ranges is not None:
        state.links = []

    def emit_ranges_until(t_ns: int | None) -> None:
        nonlocal pending_range
        while pending_range is not None:
            row = pending_range
            range_ns = (start_ns or 0) + seconds_to_ns(row.t_s)
            if t_ns is not None and range_ns > t_ns:
                return
            sink.range(row, range_ns)
            pair = (min(row.from_id, row.to_id), max(row.from_id, row.to_id))
            count = links[pair]["range_count"] + 1 if pair in links else 1
            links[pair] = {"a": pair[0], "b": pair[1], "last_range_m": row.distance_mm / 1000, "range_count": count}
            state.links = list(links.values())
            pending_range = next(ranges, None)

    def flush() -> None:
        nonlocal dirty_nodes, dirty_robot
        if dirty_nodes:
            sink.nodes(state, nodes_t_ns)
        if dirty_robot:
            sink.robot(state, robot_t_ns)
        dirty_nodes = dirty_robot = False

    for obj in objects:
        t_ns, said = _t_ns(obj, start_ns)
        saw_unix = saw_unix or said
        if period_s:
            index = math.floor(float(obj.get("t_s") or 0.0) / period_s)
            if current_period is not None and index != current_period:
                flush()
            current_period = index
        emit_ranges_until(t_ns)
        kind = state.apply(obj)
        if kind == "health":
            sink.health(state, t_ns)
        elif not period_s:
            if kind == "node":
                sink.nodes(state, t_ns, {obj["id"]})
            else:
                sink.robot(state, t_ns)
        elif kind == "node":
            dirty_nodes, nodes_t_ns = True, t_ns
        else:
            dirty_robot, robot_t_ns = True, t_ns
    flush()
    emit_ranges_until(None)
    return Written(sink.counts, saw_unix)
