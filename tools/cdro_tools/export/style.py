"""What the Foxglove and the ROS 2 outputs share, with no dependency beyond the standard library
(the ROS 2 relay, tools/ros2/, runs in a ROS Python that has neither foxglove-sdk nor numpy):
frame names (REP-105), sizes, the live map's colours, ellipses, labels."""
from __future__ import annotations

import math

from .stream import node_status

MAP_FRAME = "map"
ODOM_FRAME = "odom"
BASE_FRAME = "base_link"

SIGMAS = 2.0                           # ellipses at 2 sigma, as on the live map
ELLIPSE_POINTS = 48                    # vertices of an ellipse's line loop
NODE_DIAMETER_M = 0.25
ROBOT_DIAMETER_M = 0.35
PATH_POSES = 2000                      # poses kept in the robot's path (the oldest go first)

# RGBA 0..1, the live map's palette (host/service/web/style.css).
STATUS_COLOURS = {
    "converged": (0.18, 0.52, 0.25, 1.0),   # green
    "placed": (0.85, 0.86, 0.90, 1.0),      # white-grey: placed, not converged
    "settling": (0.79, 0.54, 0.0, 1.0),     # amber: moved, settling
    "moving": (0.85, 0.28, 0.06, 1.0),      # orange
    "unplaced": (0.5, 0.5, 0.5, 0.5),       # grey (not drawn: no position)
}
FOLDABLE_COLOUR = (0.48, 0.12, 0.64, 1.0)   # purple: its side cannot be told
ROBOT_COLOUR = (0.48, 0.12, 0.64, 1.0)
LINK_COLOUR = (0.60, 0.64, 0.71, 0.8)
TEXT_COLOUR = (1.0, 1.0, 1.0, 1.0)


def hex_id(node_id: int) -> str:
    return f"0x{node_id:04x}"


def ellipse_axes(var_x_m2: float, cov_xy_m2: float, var_y_m2: float) -> tuple[float, float, float]:
    """1-sigma semi-axes (m, major first) and the major axis' angle (rad) of a 2x2 covariance."""
    mean = (var_x_m2 + var_y_m2) / 2.0
    spread = math.hypot((var_x_m2 - var_y_m2) / 2.0, cov_xy_m2)
    major = math.sqrt(max(mean + spread, 0.0))
    minor = math.sqrt(max(mean - spread, 0.0))
    angle = 0.5 * math.atan2(2.0 * cov_xy_m2, var_x_m2 - var_y_m2)
    return major, minor, angle


def ellipse_points(x_m: float, y_m: float, z_m: float, cov, sigmas: float = SIGMAS) -> list[tuple[float, float, float]]:
    """The sigmas-sigma ellipse as a closed polygon in the map frame (m)."""
    major, minor, angle = ellipse_axes(*cov)
    c, s = math.cos(angle), math.sin(angle)
    points = []
    for k in range(ELLIPSE_POINTS):
        t = 2.0 * math.pi * k / ELLIPSE_POINTS
        u, v = sigmas * major * math.cos(t), sigmas * minor * math.sin(t)
        points.append((x_m + c * u - s * v, y_m + s * u + c * v, z_m))
    return points


def node_z_m(node: dict) -> float:
    z = node.get("z_m")
    return float(z) if isinstance(z, (int, float)) and not isinstance(z, bool) and math.isfinite(z) else 0.0


def node_colour(node: dict) -> tuple:
    status = node_status(node)
    if status == "placed" and node.get("foldable"):
        return FOLDABLE_COLOUR
    return STATUS_COLOURS.get(status, STATUS_COLOURS["placed"])


def node_label(node: dict) -> str:
    status = node_status(node)
    reason = node.get("reason") or ""
    return f"{hex_id(node['id'])} {status}" + (f" ({reason})" if reason else "")
