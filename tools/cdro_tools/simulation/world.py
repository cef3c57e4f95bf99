"""The simulated world's truth: where every node is at any time, whether it moves, what its
accelerometer reads, and what the robot's wheel odometry says.

Positions are piecewise linear in time. A node carried by a motion segment goes from where it
is through its waypoints at a constant speed. The robot either follows waypoints (turning in
place towards each next waypoint at turn_rate_rad_s, then driving straight at speed_mps) or
interpolates timed poses. Heights stay constant.
"""
from __future__ import annotations

import dataclasses
import math
import random

from .scenario import Scenario, ScenarioError

ONE_G_MG = 1000.0           # norm of the acceleration at rest, mg
SENSOR_MAX_NORM_MG = 27713  # 16 g on each of three axes (MOTION frames cap the norm at 16 g)
TRACK_STEP_S = 0.1          # sampling of the tracks CSV, s


def wrap_angle(angle_rad: float) -> float:
    """To (-pi, pi]."""
    wrapped = math.fmod(angle_rad + math.pi, 2.0 * math.pi)
    if wrapped <= 0.0:
        wrapped += 2.0 * math.pi
    return wrapped - math.pi


@dataclasses.dataclass
class Piece:
    """One piece of a path: from (x0, y0, heading0) at t0 to (x1, y1, heading1) at t1, linearly."""

    t0_s: float
    t1_s: float
    x0_m: float
    y0_m: float
    x1_m: float
    y1_m: float
    heading0_rad: float = 0.0
    heading1_rad: float = 0.0

    @property
    def moves(self) -> bool:
        return (self.x0_m, self.y0_m, self.heading0_rad) != (self.x1_m, self.y1_m, self.heading1_rad)

    def at(self, t_s: float) -> tuple[float, float, float]:
        span = self.t1_s - self.t0_s
        f = 0.0 if span <= 0.0 else min(1.0, max(0.0, (t_s - self.t0_s) / span))
        return (self.x0_m + f * (self.x1_m - self.x0_m), self.y0_m + f * (self.y1_m - self.y0_m),
                self.heading0_rad + f * (self.heading1_rad - self.heading0_rad))


class Path:
    """A start pose and moving pieces in time order; the node rests between and after them."""

    def __init__(self, x_m: float, y_m: float, heading_rad: float = 0.0):
        self.start = (x_m, y_m, heading_rad)
        self.pieces: list[Piece] = []

    def end(self) -> tuple[float, float, float, float]:
        """(t_s, x_m, y_m, heading_rad) where the last piece ends."""
        if not self.pieces:
            return (0.0, *self.start)
        p = self.pieces[-1]
        return p.t1_s, p.x1_m, p.y1_m, p.heading1_rad

    def add(self, piece: Piece) -> None:
        self.pieces.append(piece)

    def pose(self, t_s: float) -> tuple[float, float, float]:
        pose = self.start
        for piece in self.pieces:
            if t_s < piece.t0_s:
                break
            pose = piece.at(t_s)
        return pose

    def moving(self, t_s: float) -> bool:
        return any(p.t0_s <= t_s < p.t1_s and p.moves for p in self.pieces)

    def change_times(self) -> list[tuple[float, bool]]:
        """(t_s, moving) at every start and stop of motion."""
        out: list[tuple[float, bool]] = []
        for piece in self.pieces:
            if not piece.moves or piece.t1_s <= piece.t0_s:
                continue
            if out and not out[-1][1] and math.isclose(out[-1][0], piece.t0_s, abs_tol=1e-9):
                out.pop()       # stops and starts again at once: still moving
            else:
                out.append((piece.t0_s, True))
            out.append((piece.t1_s, False))
        return out


def _segment_paths(scenario: Scenario) -> dict[int, Path]:
    paths: dict[int, Path] = {}
    for segment in sorted(scenario.motion, key=lambda s: (s.node, s.start_s)):
        node = scenario.node(segment.node)
        path = paths.setdefault(node.id, Path(node.x_m, node.y_m))
        t_end, x, y, _ = path.end()
        if segment.start_s < t_end - 1e-9:
            raise ScenarioError(f"motion: segments of node 0x{node.id:04X} overlap: one starts at "
                                f"{segment.start_s} s, the previous ends at {t_end:.3f} s")
        points = [(x, y), *segment.waypoints]
        length_m = sum(math.dist(a, b) for a, b in zip(points, points[1:]))
        if length_m <= 0.0:
            raise ScenarioError(f"motion: node 0x{node.id:04X} at {segment.start_s} s does not move")
        speed_mps = segment.speed_mps if segment.speed_mps else length_m / (segment.end_s - segment.start_s)
        t = segment.start_s
        for a, b in zip(points, points[1:]):
            leg_s = math.dist(a, b) / speed_mps
            if leg_s > 0.0:
                path.add(Piece(t, t + leg_s, a[0], a[1], b[0], b[1]))
            t += leg_s
    return paths


def _robot_path(scenario: Scenario) -> Path:
    robot = scenario.robot
    node = scenario.node(robot.id)
    if robot.poses:
        poses = robot.poses
        heading = robot.heading_rad
        if heading is None:
            heading = 0.0
            for a, b in zip(poses, poses[1:]):
                if (a[1], a[2]) != (b[1], b[2]):
                    heading = math.atan2(b[2] - a[2], b[1] - a[1])
                    break
        path = Path(poses[0][1], poses[0][2], heading)
        for a, b in zip(poses, poses[1:]):
            if (a[1], a[2]) != (b[1], b[2]):
                new_heading = heading + wrap_angle(math.atan2(b[2] - a[2], b[1] - a[1]) - heading)
            else:
                new_heading = heading
            path.add(Piece(a[0], b[0], a[1], a[2], b[1], b[2], heading, new_heading))
            heading = new_heading
        return path
    points = [(node.x_m, node.y_m), *robot.waypoints]
    heading = robot.heading_rad
    if heading is None:
        heading = 0.0
        for a, b in zip(points, points[1:]):
            if a != b:
                heading = math.atan2(b[1] - a[1], b[0] - a[0])
                break
    path = Path(node.x_m, node.y_m, heading)
    t = robot.start_s
    for a, b in zip(points, points[1:]):
        if a == b:
            continue
        turn = wrap_angle(math.atan2(b[1] - a[1], b[0] - a[0]) - heading)
        if abs(turn) > 1e-12:
            turn_s = abs(turn) / robot.turn_rate_rad_s
            path.add(Piece(t, t + turn_s, a[0], a[1], a[0], a[1], heading, heading + turn))
            t += turn_s
            heading += turn
        drive_s = math.dist(a, b) / robot.speed_mps
        path.add(Piece(t, t + drive_s, a[0], a[1], b[0], b[1], heading, heading))
        t += drive_s
    return path


class World:
    """Truth of one scenario. Randomness (accelerometer noise, odometry noise) comes from the
    generators passed in, so that a seed fixes everything."""

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        self.nodes = {n.id: n for n in scenario.nodes}
        self.paths = _segment_paths(scenario)
        self.robot_path = _robot_path(scenario) if scenario.robot else None
        if self.robot_path:
            self.paths[scenario.robot.id] = self.robot_path
        self._phase = {n.id: (n.id * 0.61803398875 % 1.0) * 2.0 * math.pi for n in scenario.nodes}

    # -- positions --

    def has(self, node_id: int) -> bool:
        return node_id in self.nodes

    def position(self, node_id: int, t_s: float) -> tuple[float, float, float]:
        """(x_m, y_m, z_m) at t_s."""
        node = self.nodes[node_id]
        path = self.paths.get(node_id)
        if path is None:
            return node.x_m, node.y_m, node.z_m
        x, y, _ = path.pose(t_s)
        return x, y, node.z_m

    def distance_m(self, a: int, b: int, t_s: float) -> float:
        return math.dist(self.position(a, t_s), self.position(b, t_s))

    def moving(self, node_id: int, t_s: float) -> bool:
        path = self.paths.get(node_id)
        return bool(path and path.moving(t_s))

    def moving_ids(self) -> list[int]:
        """Nodes that move at some time, in scenario order."""
        return [n.id for n in self.scenario.nodes if n.id in self.paths and self.paths[n.id].pieces]

    # -- accelerometer --

    def accel_norm_mg(self, node_id: int, t_s: float, rng: random.Random) -> int:
        """Norm of the acceleration a tag reads: 1 g plus noise, plus a periodic swing while moving."""
        model = self.scenario.accelerometer
        norm = ONE_G_MG + rng.gauss(0.0, model.noise_std_mg)
        if self.moving(node_id, t_s):
            node = self.nodes[node_id]
            if node.moving_amplitude_mg is not None:
                amplitude = node.moving_amplitude_mg
            elif self.scenario.robot and node_id == self.scenario.robot.id:
                amplitude = self.scenario.robot.moving_amplitude_mg
            else:
                amplitude = model.moving_amplitude_mg
            norm += amplitude * math.sin(2.0 * math.pi * model.moving_frequency_hz * t_s + self._phase[node_id])
        return int(min(SENSOR_MAX_NORM_MG, max(0, round(norm))))

    # -- truth files --

    def track_rows(self) -> list[tuple[float, int, float, float]]:
        """(t_s, id, x_m, y_m) every TRACK_STEP_S for everything that moves."""
        ids = self.moving_ids()
        steps = int(math.floor(self.scenario.duration_s / TRACK_STEP_S + 1e-9))
        rows = []
        for k in range(steps + 1):
            t = k * TRACK_STEP_S
            for node_id in ids:
                x, y, _ = self.position(node_id, t)
                rows.append((t, node_id, x, y))
        return rows

    def motion_rows(self) -> list[tuple[float, int, int]]:
        """(t_s, id, moving): every node at 0, then every change, in time order."""
        rows = [(0.0, n.id, 0) for n in self.scenario.nodes]
        changes = []
        for node_id, path in self.paths.items():
            for t, moving in path.change_times():
                if t <= self.scenario.duration_s:
                    changes.append((t, node_id, int(moving)))
        changes.sort()
        for t, node_id, moving in changes:
            if t == 0.0:
                rows = [(0.0, i, moving if i == node_id else m) for (_, i, m) in rows]
            else:
                rows.append((t, node_id, moving))
        return rows

    def odometry(self, rng: random.Random) -> tuple[list[tuple[float, float, float]],
                                                    list[tuple[float, float, float, float]]]:
        """Wheel odometry and the robot's true poses.

        Returns (odometry rows (t_s, distance_m, dheading_rad), truth rows (t_s, x_m, y_m,
        heading_rad)). Odometry row k, at t_k, moves pose k to pose k+1 (the Plaza convention:
        advance along the mid-point heading). Noise applies to steps that move; the heading
        drift applies to every step.
        """
        robot = self.scenario.robot
        if robot is None:
            return [], []
        odo = robot.odometry
        dt_s = 1.0 / odo.rate_hz
        steps = int(math.floor(self.scenario.duration_s * odo.rate_hz + 1e-9))
        poses = [self.robot_path.pose(k * dt_s) for k in range(steps + 1)]
        rows = []
        for k in range(steps):
            (x0, y0, h0), (x1, y1, h1) = poses[k], poses[k + 1]
            distance_m = math.hypot(x1 - x0, y1 - y0)
            dheading_rad = h1 - h0
            noise_d = rng.gauss(0.0, odo.distance_noise_frac)
            noise_h = rng.gauss(0.0, odo.heading_noise_rad)
            if distance_m > 0.0 or dheading_rad != 0.0:
                distance_m *= 1.0 + noise_d
                dheading_rad += noise_h
            dheading_rad += odo.heading_drift_rad_s * dt_s
            rows.append((k * dt_s, distance_m, dheading_rad))
        truth = [(k * dt_s, x, y, wrap_angle(h)) for k, (x, y, h) in enumerate(poses)]
        return rows, truth
