"""The map state as ROS 2 messages (plain dicts shaped like the message types; standard library
only, so that tools/ros2/cdro_ros2_relay.py can fill rclpy messages from them), written CDR-encoded
into MCAP by mcap-ros2-support with the message definitions of ROS 2 Humble (which Iron and Jazzy
share for these types) taken from rosbags' type store. `ros2 bag play -s mcap FILE.mcap` plays it;
Foxglove opens it too.

Topics and frames as the Foxglove side (scene.py): REP-105 `map -> odom -> base_link`, with
`map -> odom` the identity (the stream has no separate odometry).
"""
from __future__ import annotations

import math

from .style import (BASE_FRAME, LINK_COLOUR, MAP_FRAME, NODE_DIAMETER_M, ODOM_FRAME, SIGMAS, TEXT_COLOUR,
                    ellipse_points, hex_id, node_colour, node_label, node_z_m)
from .stream import MapState, covariance_2x2, node_placed, robot_covariance_3x3, robot_frame

POSE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
MARKERS_TYPE = "visualization_msgs/msg/MarkerArray"
TF_TYPE = "tf2_msgs/msg/TFMessage"
STRING_TYPE = "std_msgs/msg/String"

TOPIC_POSE = "/cdro/robot/pose"        # PoseWithCovarianceStamped
TOPIC_MARKERS = "/cdro/markers"        # MarkerArray: nodes (spheres, ellipses, labels), links, robot
TOPIC_TF = "/tf"                       # TFMessage
TOPIC_HEALTH = "/cdro/health"          # std_msgs/String, the health line's JSON

# visualization_msgs/Marker constants
SPHERE, LINE_STRIP, LINE_LIST, TEXT_VIEW_FACING = 2, 4, 5, 9
ADD, DELETE = 0, 2
# namespaces of the markers: one marker id per node id in each
NS_NODE, NS_ELLIPSE, NS_LABEL, NS_LINKS = "cdro/nodes", "cdro/ellipses", "cdro/labels", "cdro/links"
UNKNOWN_VARIANCE = 1e6                 # rad^2: a heading variance the stream does not give (ROS: large
                                       # means unknown; -1 in the first element would void the whole pose)


def message_definitions() -> dict[str, str]:
    """The ros2msg text (with its dependencies) of each type written."""
    from rosbags.typesys import Stores, get_typestore  # here: the ROS 2 relay does not need it

    store = get_typestore(Stores.ROS2_HUMBLE)
    return {name: store.generate_msgdef(name, ros_version=2)[0] for name in (POSE_TYPE, MARKERS_TYPE, TF_TYPE,
                                                                             STRING_TYPE)}


def stamp(t_ns: int) -> dict:
    return {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}


def header(t_ns: int, frame: str) -> dict:
    return {"stamp": stamp(t_ns), "frame_id": frame}


def quaternion_z(yaw_rad: float) -> dict:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw_rad / 2.0), "w": math.cos(yaw_rad / 2.0)}


def pose(x: float, y: float, z: float, yaw_rad: float = 0.0) -> dict:
    return {"position": {"x": x, "y": y, "z": z}, "orientation": quaternion_z(yaw_rad)}


def rgba(values) -> dict:
    return {"r": values[0], "g": values[1], "b": values[2], "a": values[3]}


def marker(t_ns: int, ns: str, marker_id: int, kind: int, action: int = ADD, **fields) -> dict:
    """A Marker with every field set (the CDR writer needs them all)."""
    base = {"header": header(t_ns, MAP_FRAME), "ns": ns, "id": marker_id, "type": kind, "action": action,
            "pose": pose(0.0, 0.0, 0.0), "scale": {"x": 1.0, "y": 1.0, "z": 1.0},
            "color": rgba((1.0, 1.0, 1.0, 1.0)), "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": False,
            "points": [], "colors": [], "texture_resource": "",
            "texture": {"header": header(0, ""), "format": "", "data": b""}, "uv_coordinates": [], "text": "",
            "mesh_resource": "", "mesh_file": {"filename": "", "data": b""}, "mesh_use_embedded_materials": False}
    base.update(fields)
    return base


def node_markers(node: dict, t_ns: int) -> list[dict]:
    node_id = node["id"]
    if not node_placed(node):
        return [marker(t_ns, ns, node_id, kind, DELETE) for ns, kind in
                ((NS_NODE, SPHERE), (NS_ELLIPSE, LINE_STRIP), (NS_LABEL, TEXT_VIEW_FACING))]
    x, y, z = float(node["x_m"]), float(node["y_m"]), node_z_m(node)
    colour = node_colour(node)
    loop = ellipse_points(x, y, z, covariance_2x2(node), SIGMAS)
    loop.append(loop[0])  # LINE_STRIP: closed by repeating the first point
    return [
        marker(t_ns, NS_NODE, node_id, SPHERE, pose=pose(x, y, z),
               scale={"x": NODE_DIAMETER_M, "y": NODE_DIAMETER_M, "z": NODE_DIAMETER_M}, color=rgba(colour)),
        marker(t_ns, NS_ELLIPSE, node_id, LINE_STRIP, scale={"x": 0.02, "y": 0.0, "z": 0.0}, color=rgba(colour),
               points=[{"x": px, "y": py, "z": pz} for px, py, pz in loop]),
        marker(t_ns, NS_LABEL, node_id, TEXT_VIEW_FACING, pose=pose(x, y, z + 0.3),
               scale={"x": 0.0, "y": 0.0, "z": 0.25}, color=rgba(TEXT_COLOUR), text=node_label(node)),
    ]


def markers(state: MapState, t_ns: int, only: set[int] | None = None) -> dict:
    """MarkerArray of the nodes (all, or those in `only`) and the links (live map events; a
    capture's ranged pairs)."""
    result = []
    for node_id in sorted(state.nodes if only is None else only):
        if node_id in state.nodes:
            result.extend(node_markers(state.nodes[node_id], t_ns))
    if state.links is not None:
        points = []
        for link in state.links:
            a, b = state.nodes.get(link["a"]), state.nodes.get(link["b"])
            if a is not None and b is not None and node_placed(a) and node_placed(b):
                points += [{"x": float(n["x_m"]), "y": float(n["y_m"]), "z": node_z_m(n)} for n in (a, b)]
        result.append(marker(t_ns, NS_LINKS, 0, LINE_LIST, scale={"x": 0.01, "y": 0.0, "z": 0.0},
                             color=rgba(LINK_COLOUR), points=points))
    return {"markers": result}


def positive_semidefinite(m: list[list[float]], tolerance: float = 1e-12) -> bool:
    """A symmetric 3x3 is positive semi-definite when every principal minor is >= 0."""
    minors = [m[0][0], m[1][1], m[2][2],
              m[0][0] * m[1][1] - m[0][1] * m[1][0], m[0][0] * m[2][2] - m[0][2] * m[2][0],
              m[1][1] * m[2][2] - m[1][2] * m[2][1],
              m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
              + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])]
    return all(minor >= -tolerance for minor in minors)


def robot_pose(robot: dict, t_ns: int) -> dict:
    """PoseWithCovarianceStamped: 6x6 row-major over (x, y, z, roll, pitch, yaw); z, roll and pitch
    are not estimated (0, and variance 0: the robot is on the floor plane), yaw's terms come from
    the stream when it has them (without the x/y-yaw terms when those make it no covariance),
    else its variance is UNKNOWN_VARIANCE."""
    cov3, have_heading = robot_covariance_3x3(robot)
    if not have_heading:
        cov3[2][2] = UNKNOWN_VARIANCE
    elif not positive_semidefinite(cov3):
        # A consumer (robot_localization, Nav2) must not get a matrix that is no covariance,
        # whoever wrote the stream: keep the blocks, drop the cross terms.
        cov3[0][2] = cov3[2][0] = cov3[1][2] = cov3[2][1] = 0.0
    index = (0, 1, 5)  # x, y, yaw in the 6x6
    covariance = [0.0] * 36
    for i in range(3):
        for j in range(3):
            covariance[6 * index[i] + index[j]] = cov3[i][j]
    frame = ODOM_FRAME if robot_frame(robot) == "odometry" else MAP_FRAME
    return {"header": header(t_ns, frame),
            "pose": {"pose": pose(float(robot["x_m"]), float(robot["y_m"]), 0.0,
                                  float(robot.get("heading_rad") or 0.0)),
                     "covariance": covariance}}


def transforms(robot: dict, t_ns: int) -> dict:
    """TFMessage: map -> odom (identity) and odom -> base_link (the estimate)."""
    heading = float(robot.get("heading_rad") or 0.0)
    return {"transforms": [
        {"header": header(t_ns, MAP_FRAME), "child_frame_id": ODOM_FRAME,
         "transform": {"translation": {"x": 0.0, "y": 0.0, "z": 0.0}, "rotation": quaternion_z(0.0)}},
        {"header": header(t_ns, ODOM_FRAME), "child_frame_id": BASE_FRAME,
         "transform": {"translation": {"x": float(robot["x_m"]), "y": float(robot["y_m"]), "z": 0.0},
                       "rotation": quaternion_z(heading)}}]}


__all__ = ["message_definitions", "markers", "robot_pose", "transforms", "hex_id"]
