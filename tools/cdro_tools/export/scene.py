"""The map state as Foxglove messages (foxglove-sdk, protobuf-encoded schemas that Foxglove opens
natively): shared by the live bridge (cdro-foxglove) and the MCAP export (cdro-export).

Frames follow REP-105: `map` is the service's output frame; `odom` is where the robot's dead
reckoning lives; `base_link` is the robot. The stream carries one robot estimate and no separate
odometry, so `map -> odom` is published as the identity and `odom -> base_link` as the estimate
(their product is the estimate either way); a robot line in the `odometry` frame (no map yet) is
drawn in `odom`.
"""
from __future__ import annotations

import dataclasses
import math

from foxglove import messages as fm

from .stream import MapState, covariance_2x2, node_placed, robot_frame
from .style import (BASE_FRAME, LINK_COLOUR, MAP_FRAME, NODE_DIAMETER_M, ODOM_FRAME, PATH_POSES, ROBOT_COLOUR,
                    ROBOT_DIAMETER_M, TEXT_COLOUR, ellipse_points, hex_id, node_colour, node_label, node_z_m)

TOPIC_NODES = "/cdro/nodes"            # foxglove.SceneUpdate
TOPIC_LINKS = "/cdro/links"            # foxglove.SceneUpdate (live map events only)
TOPIC_ROBOT_POSE = "/cdro/robot/pose"  # foxglove.PoseInFrame
TOPIC_ROBOT_PATH = "/cdro/robot/path"  # foxglove.PosesInFrame
TOPIC_ROBOT_SCENE = "/cdro/robot/scene"  # foxglove.SceneUpdate: the robot's 2-sigma ellipse
TOPIC_TF = "/tf"                       # foxglove.FrameTransforms
TOPIC_HEALTH = "/cdro/health"          # JSON: the health object as the service wrote it
TOPIC_RANGES = "/cdro/ranges"          # JSON: one RANGE frame of a capture

def timestamp(t_ns: int) -> fm.Timestamp:
    return fm.Timestamp(t_ns // 1_000_000_000, t_ns % 1_000_000_000)


def colour(rgba) -> fm.Color:
    return fm.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def quaternion_z(yaw_rad: float) -> fm.Quaternion:
    return fm.Quaternion(x=0.0, y=0.0, z=math.sin(yaw_rad / 2.0), w=math.cos(yaw_rad / 2.0))


IDENTITY = fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def node_entity(node: dict, t_ns: int) -> fm.SceneEntity:
    """A placed node: sphere, 2-sigma ellipse, label; metadata carries what the line said."""
    x, y, z = float(node["x_m"]), float(node["y_m"]), node_z_m(node)
    rgba = node_colour(node)
    ellipse = [fm.Point3(x=px, y=py, z=pz) for px, py, pz in ellipse_points(x, y, z, covariance_2x2(node))]
    metadata = [fm.KeyValuePair(key=k, value=str(node.get(k, ""))) for k in ("status", "reason", "converged",
                                                                             "moving", "foldable")]
    metadata.append(fm.KeyValuePair(key="id", value=str(node["id"])))
    return fm.SceneEntity(
        timestamp=timestamp(t_ns), frame_id=MAP_FRAME, id=f"node-{hex_id(node['id'])}", frame_locked=True,
        metadata=metadata,
        spheres=[fm.SpherePrimitive(pose=fm.Pose(position=fm.Vector3(x=x, y=y, z=z), orientation=IDENTITY),
                                    size=fm.Vector3(x=NODE_DIAMETER_M, y=NODE_DIAMETER_M, z=NODE_DIAMETER_M),
                                    color=colour(rgba))],
        lines=[fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineLoop, thickness=2.0, scale_invariant=True,
                                points=ellipse, color=colour(rgba[:3] + (0.9,)))],
        texts=[fm.TextPrimitive(pose=fm.Pose(position=fm.Vector3(x=x, y=y, z=z + 0.3), orientation=IDENTITY),
                                billboard=True, font_size=14.0, scale_invariant=True, color=colour(TEXT_COLOUR),
                                text=node_label(node))])


@dataclasses.dataclass
class SceneBuilder:
    """Turns map states into messages; remembers what it drew so that a node that leaves the map
    (unplaced again, or gone from a live map event) is deleted, not left standing."""

    drawn_nodes: set[int] = dataclasses.field(default_factory=set)
    path: list[fm.Pose] = dataclasses.field(default_factory=list)
    last_robot_key: tuple | None = None

    def nodes(self, state: MapState, t_ns: int, only: set[int] | None = None) -> fm.SceneUpdate:
        """Entities of the placed nodes (all, or those in `only`), deletions of those that left."""
        entities, deletions = [], []
        wanted = state.nodes if only is None else {i: state.nodes[i] for i in only if i in state.nodes}
        placed = set()
        for node_id, node in sorted(wanted.items()):
            if node_placed(node):
                entities.append(node_entity(node, t_ns))
                placed.add(node_id)
        candidates = self.drawn_nodes if only is None else (self.drawn_nodes & set(only))
        for node_id in sorted(candidates - placed):
            deletions.append(fm.SceneEntityDeletion(timestamp=timestamp(t_ns),
                                                    type=fm.SceneEntityDeletionType.MatchingId,
                                                    id=f"node-{hex_id(node_id)}"))
        self.drawn_nodes = (self.drawn_nodes - candidates) | placed
        return fm.SceneUpdate(entities=entities, deletions=deletions)

    @staticmethod
    def links(state: MapState, t_ns: int) -> fm.SceneUpdate | None:
        """The live map's links between placed nodes as one line list; None without links."""
        if state.links is None:
            return None
        points = []
        for link in state.links:
            a, b = state.nodes.get(link["a"]), state.nodes.get(link["b"])
            if a is None or b is None or not node_placed(a) or not node_placed(b):
                continue
            for node in (a, b):
                points.append(fm.Point3(x=float(node["x_m"]), y=float(node["y_m"]), z=node_z_m(node)))
        entity = fm.SceneEntity(timestamp=timestamp(t_ns), frame_id=MAP_FRAME, id="links", frame_locked=True,
                                lines=[fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineList, thickness=1.0,
                                                        scale_invariant=True, points=points,
                                                        color=colour(LINK_COLOUR))])
        return fm.SceneUpdate(entities=[entity])

    def robot(self, state: MapState, t_ns: int, repeat: bool = False):
        """(PoseInFrame, PosesInFrame, SceneUpdate, FrameTransforms) of the robot, or None when
        there is no robot or it did not change (repeat: the same again, for late viewers; the
        path does not grow)."""
        robot = state.robot
        if robot is None:
            return None
        key = (robot.get("t_s"), robot["x_m"], robot["y_m"], robot.get("heading_rad"))
        changed = key != self.last_robot_key
        if not changed and not repeat:
            return None
        self.last_robot_key = key
        heading = float(robot.get("heading_rad") or 0.0)
        frame = ODOM_FRAME if robot_frame(robot) == "odometry" else MAP_FRAME
        x, y = float(robot["x_m"]), float(robot["y_m"])
        pose = fm.Pose(position=fm.Vector3(x=x, y=y, z=0.0), orientation=quaternion_z(heading))
        if changed:
            self.path.append(pose)
            del self.path[:-PATH_POSES]
        stamp = timestamp(t_ns)
        ellipse = [fm.Point3(x=px, y=py, z=pz) for px, py, pz in ellipse_points(x, y, 0.0, covariance_2x2(robot))]
        scene = fm.SceneUpdate(entities=[fm.SceneEntity(
            timestamp=stamp, frame_id=frame, id="robot", frame_locked=True,
            spheres=[fm.SpherePrimitive(pose=pose, size=fm.Vector3(x=ROBOT_DIAMETER_M, y=ROBOT_DIAMETER_M,
                                                                    z=ROBOT_DIAMETER_M / 2),
                                        color=colour(ROBOT_COLOUR))],
            lines=[fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineLoop, thickness=2.0, scale_invariant=True,
                                    points=ellipse, color=colour(ROBOT_COLOUR))])])
        transforms = fm.FrameTransforms(transforms=[
            fm.FrameTransform(timestamp=stamp, parent_frame_id=MAP_FRAME, child_frame_id=ODOM_FRAME,
                              translation=fm.Vector3(x=0.0, y=0.0, z=0.0), rotation=IDENTITY),
            fm.FrameTransform(timestamp=stamp, parent_frame_id=ODOM_FRAME, child_frame_id=BASE_FRAME,
                              translation=fm.Vector3(x=x, y=y, z=0.0), rotation=quaternion_z(heading))])
        return (fm.PoseInFrame(timestamp=stamp, frame_id=frame, pose=pose),
                fm.PosesInFrame(timestamp=stamp, frame_id=frame, poses=list(self.path)), scene, transforms)


HEALTH_SCHEMA = {
    "title": "cdro.Health",
    "description": "cdro-hostd's health line (docs/outputs.md): link state and counters",
    "type": "object",
    "properties": {
        "type": {"type": "string"},
        "t_s": {"type": "number", "description": "s since the run started"},
        "link": {"type": "string"},
        "counters": {"type": "object", "additionalProperties": {"type": "number"}},
    },
}

RANGE_SCHEMA = {
    "title": "cdro.Range",
    "description": "one RANGE frame of a capture (docs/protocol.md)",
    "type": "object",
    "properties": {
        "t_s": {"type": "number", "description": "s since the capture was created (host time)"},
        "from": {"type": "integer"}, "to": {"type": "integer"},
        "range_m": {"type": "number", "description": "m, 3D two-way range"},
        "rss_dbm": {"type": "integer", "description": "dBm"},
        "flags": {"type": "integer", "description": "CDRO_RANGE_FLAG_* bits"},
        "device_time_ms": {"type": "integer", "description": "ms since device boot"},
    },
}
