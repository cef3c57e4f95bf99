"""Evaluation of the movement stage: the robot's causal path, the beacons, and the track of a
node that was carried (cdro-eval-motion; docs/tools.md).

- Path: the trajectory CSV `t,x,y,heading_rad,var_x,cov_xy,var_y,frame` (the online estimate
  after each odometry step) against a truth `t,x,y[,heading_rad]`, matched by time (nearest truth
  row within `max_dt_s`), rigidly fitted (reflection allowed, no scale) over the whole path. When
  the map appeared while the robot stood, its first rows are dead reckoning in the odometry's
  frame and the rest in the map's (`frame`): only the rows in the frame of the last row are
  evaluated, and the others are counted (a trajectory without the column is one frame).
- Beacons: the final node estimates against their truth, fitted on their own, and also seen
  through the path's fit (one frame for both: the stricter figure).
- Track: the engine's trace `ranges,id,x,y,...,converged,t` of a node that moved, against its
  true track `t,id,x,y` (interpolated), in the frame fitted on the static nodes' final estimates;
  errors while it moved (motion truth `t,id,moving`), and how long after each stop it converged.
"""
from __future__ import annotations

import bisect
import dataclasses
import math

import numpy as np

from .alignment import align, rigid_fit
from .inputs import BadRow, Format, Policy, Reader, Row, read_count, read_rows


FRAMES = ("odometry", "map")  # cdro-hostd's trajectory `frame` values (RobotFrame in movement.hpp)
PATH_FORMAT = Format(("t", "x", "y"), ("frame",))       # a trajectory or a truth path, with its header
TRACKS_FORMAT = Format(("t", "id", "x", "y"))           # cdro-sim's --tracks-csv
# cdro-hostd's --motion-csv (host/hostd/src/csv_input.cpp): without a header t,id,moving too.
MOTION_FORMAT = Format(("t", "id", "moving"), (), (("t", "id", "moving"),))
TRACE_ROWS_FORMAT = Format(("ranges", "id", "x", "y", "converged", "t"), ("status",))


@dataclasses.dataclass
class PathSeries:
    t_s: np.ndarray     # (n,)
    xy_m: np.ndarray    # (n, 2)
    frames: list[str] | None = None  # (n,) each row's frame, when the file has the column


def read_path(path: str, bad: list[BadRow]) -> PathSeries:
    """`t,x,y,...[,frame]` rows (a trajectory or a ground truth), in file order."""
    times, points, frames = [], [], []

    def on_row(row: Row) -> None:
        t_s, xy_m = row.number("t"), (row.number("x"), row.number("y"))
        frame = row.text("frame") if has_frame else None
        if has_frame and frame not in FRAMES:
            row.reject(f"frame {frame!r} is not one of {', '.join(FRAMES)}")
        times.append(t_s)
        points.append(xy_m)
        frames.append(frame)

    reader = Reader(path, PATH_FORMAT, Policy.LENIENT, kept_problems=None)
    has_frame = "frame" in reader.columns   # then every row must have one
    try:
        reader.for_each(on_row)
    finally:
        bad.extend(reader.summary.problems)
    return PathSeries(np.array(times), np.array(points, dtype=float).reshape(-1, 2), frames if has_frame else None)


def last_frame_rows(series: PathSeries) -> tuple[PathSeries, int]:
    """The rows in the frame of the last row, and how many rows were in another frame."""
    if not series.frames:
        return series, 0
    keep = np.array([frame == series.frames[-1] for frame in series.frames])
    kept = PathSeries(series.t_s[keep], series.xy_m[keep], [f for f, k in zip(series.frames, keep) if k])
    return kept, int(len(keep) - keep.sum())


def read_tracks(path: str, bad: list[BadRow], policy: Policy = Policy.LENIENT) -> dict[int, PathSeries]:
    """`t,id,x,y`: true tracks of the nodes that move, by id, sorted by time."""
    rows: dict[int, list[tuple[float, float, float]]] = {}

    def on_row(row: Row) -> None:
        t_s, node = row.number("t"), row.node_id("id")
        rows.setdefault(node, []).append((t_s, row.number("x"), row.number("y")))

    read_rows(path, TRACKS_FORMAT, on_row, bad, policy)
    out = {}
    for node, values in rows.items():
        values.sort()
        out[node] = PathSeries(np.array([v[0] for v in values]), np.array([v[1:] for v in values], dtype=float))
    return out


def read_motion(path: str, bad: list[BadRow]) -> dict[int, list[tuple[float, float]]]:
    """`t,id,moving`: for each node, its (start, stop) intervals of motion (s)."""
    changes: dict[int, list[tuple[float, bool]]] = {}

    def on_row(row: Row) -> None:
        t_s, node = row.number("t"), row.node_id("id")
        changes.setdefault(node, []).append((t_s, row.flag("moving")))

    read_rows(path, MOTION_FORMAT, on_row, bad)
    intervals: dict[int, list[tuple[float, float]]] = {}
    for node, events in changes.items():
        events.sort()
        start = None
        for t, moving in events:
            if moving and start is None:
                start = t
            elif not moving and start is not None:
                intervals.setdefault(node, []).append((start, t))
                start = None
        if start is not None:
            intervals.setdefault(node, []).append((start, math.inf))
    return intervals


def interpolate(series: PathSeries, t_s: float) -> np.ndarray:
    """The series' position at t_s (linear; held before the first and after the last row)."""
    if t_s <= series.t_s[0]:
        return series.xy_m[0]
    if t_s >= series.t_s[-1]:
        return series.xy_m[-1]
    i = bisect.bisect_right(series.t_s, t_s)
    f = (t_s - series.t_s[i - 1]) / (series.t_s[i] - series.t_s[i - 1])
    return series.xy_m[i - 1] + f * (series.xy_m[i] - series.xy_m[i - 1])


def _stats(errors: np.ndarray) -> dict:
    if len(errors) == 0:
        return {"points": 0, "rmse_m": None, "p95_m": None, "max_m": None}
    return {"points": int(len(errors)), "rmse_m": float(np.sqrt(np.mean(errors ** 2))),
            "p95_m": float(np.percentile(errors, 95)), "max_m": float(np.max(errors))}


def evaluate_path(estimate: PathSeries, truth: PathSeries, max_dt_s: float = 0.06) -> dict:
    """Aligned errors of a causal path: one rigid fit over the rows in its final frame."""
    estimate, other_frame_points = last_frame_rows(estimate)
    order = np.argsort(truth.t_s)
    truth_t, truth_xy = truth.t_s[order], truth.xy_m[order]
    pairs_est, pairs_true, times = [], [], []
    for t, xy in zip(estimate.t_s, estimate.xy_m):
        i = bisect.bisect_left(truth_t, t)
        best = min((j for j in (i - 1, i) if 0 <= j < len(truth_t)), key=lambda j: abs(truth_t[j] - t), default=None)
        if best is not None and abs(truth_t[best] - t) <= max_dt_s:
            pairs_est.append(xy)
            pairs_true.append(truth_xy[best])
            times.append(t)
    if len(pairs_est) < 2:
        raise ValueError("fewer than two trajectory rows match the truth in time")
    source, target = np.array(pairs_est), np.array(pairs_true)
    rotation, translation = rigid_fit(source, target)
    errors = np.linalg.norm(source @ rotation.T + translation - target, axis=1)
    tenth = max(len(errors) // 10, 1)
    report = _stats(errors)
    report["by_tenth_m"] = [float(np.sqrt(np.mean(errors[k * tenth:(k + 1) * tenth] ** 2))) for k in range(10)
                            if len(errors[k * tenth:(k + 1) * tenth])]
    report["reflected"] = bool(np.linalg.det(rotation) < 0)
    report["frame"] = estimate.frames[-1] if estimate.frames else None
    report["other_frame_points"] = other_frame_points
    report["frame_from_s"] = float(estimate.t_s[0]) if other_frame_points else None  # s, its first row
    return {"report": report, "rotation": rotation, "translation": translation, "t_s": np.array(times),
            "aligned_m": source @ rotation.T + translation, "truth_m": target}


def evaluate_beacons(estimates: dict, truth: dict, path_fit: tuple | None) -> dict:
    """Final node estimates (id -> (x, y)) against their truth: own fit, and the path's fit."""
    own = align(estimates, truth)
    report = {"nodes": own.nodes, "own_fit_rmse_m": own.rmse_m, "own_fit_errors_m": own.errors_m}
    if path_fit is not None:
        rotation, translation = path_fit
        errors = {i: float(np.linalg.norm(rotation @ np.asarray(estimates[i][:2]) + translation - truth[i][:2]))
                  for i in estimates if i in truth}
        report["path_fit_rmse_m"] = float(np.sqrt(np.mean(np.square(list(errors.values()))))) if errors else None
        report["path_fit_errors_m"] = errors
    return report


def evaluate_track(trace_rows: list[tuple[int, float, int, np.ndarray, bool, str]], node: int, truth_start: dict,
                   track: PathSeries, intervals: list[tuple[float, float]], settle_s: float = 0.5) -> dict:
    """trace_rows: (ranges, t_s, id, xy, converged, status) in file order. The frame is the rigid
    fit of the static nodes' last estimates to their truth; errors of `node` while it moved (from
    each start to settle_s after each stop), the time from each stop to its first converged row,
    and how late the engine saw each start (its first `moving` row from the start to the stop)
    and each stop (its first row after the stop that is no longer `moving`, once it was seen
    moving): None where it never did, or where the trace has no status."""
    last: dict[int, np.ndarray] = {}
    for _, _, node_id, xy, _, _ in trace_rows:
        last[node_id] = xy
    static = {i: xy for i, xy in last.items() if i != node and i in truth_start}
    fit = align(static, truth_start)
    errors, times = [], []
    reconverged, start_seen, stop_seen = [], [], []
    for start, stop in intervals:
        first_converged = first_moving = first_stopped = None
        seen_moving = False
        for _, t, node_id, xy, converged, status in trace_rows:
            if node_id != node:
                continue
            seen_moving = seen_moving or (t >= start and status == "moving")
            if start <= t <= stop + settle_s:
                errors.append(float(np.linalg.norm(fit.apply(xy) - interpolate(track, t))))
                times.append(t)
            if t >= start and t <= stop and status == "moving" and first_moving is None:
                first_moving = t - start
            if math.isfinite(stop) and t > stop:
                if converged and first_converged is None:
                    first_converged = t - stop
                if seen_moving and status != "moving" and first_stopped is None:
                    first_stopped = t - stop
        reconverged.append(first_converged)
        start_seen.append(first_moving)
        stop_seen.append(first_stopped)
    report = _stats(np.array(errors))
    report["static_rmse_m"] = fit.rmse_m
    report["reconverged_after_s"] = reconverged
    report["start_seen_after_s"] = start_seen
    report["stop_seen_after_s"] = stop_seen
    return {"report": report, "fit": fit, "t_s": np.array(times), "errors_m": np.array(errors)}


def read_trace_rows(path: str, bad: list[BadRow]) -> list[tuple[int, float, int, np.ndarray, bool, str]]:
    """The engine's trace with its t column: (ranges, t_s, id, xy, converged, status) of placed
    nodes (status '' when the trace has no status column)."""
    rows = []

    def on_row(row: Row) -> None:
        if row.text("x") == "":
            return
        count, t_s, node = read_count(row, "ranges"), row.number("t"), row.node_id("id")
        xy_m = np.array([row.number("x"), row.number("y")])
        rows.append((count, t_s, node, xy_m, row.flag("converged"), row.text("status") if row.has("status") else ""))

    read_rows(path, TRACE_ROWS_FORMAT, on_row, bad)
    return rows
