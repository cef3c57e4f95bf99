"""cdro-plot: a map and an RMSE-over-time plot (PNG) from the service's estimates.

Estimates: the JSON Lines of cdro-hostd (docs/outputs.md: `node` and `robot` lines over time),
or the offline nodes CSV (id,x,y,var_x,cov_xy,var_y,converged), optionally with a robot
trajectory CSV (t,x,y,heading_rad,var_x,cov_xy,var_y[,frame]; only the rows in the last row's
frame are drawn). Truth from cdro-sim (or a dataset): nodes id,x,y,z (start positions), tracks
t,id,x,y of everything that moves, ranges t,from,to,range_m (to draw links).

Estimates live in the engine's own frame. They are aligned to the truth with a rigid fit
(rotation and translation, reflection allowed, no scale) over the nodes that stand still (the
nodes without a truth track; all nodes when fewer than three stand still), at the end for the
map and at every time step for the RMSE curve; every node's error is then measured in that fit.
The truth of a moving node is its track at the estimate's time; a nodes CSV is the map at the
end of the run, so it is compared with the end of each track. The map shows the truth (hollow circles),
the aligned estimates with their 2-sigma ellipses, the links that were ranged, the tracks of
moving nodes (truth dashed, estimates solid), and the robot's path. The numbers (aligned
RMSE, per-node errors) are printed as one JSON object on stdout.

Two views need no truth: --residuals (with --ranges, and --heights where heights are known)
draws every link's residual, the median of its ranges minus the distance between its nodes'
final estimates, on the map and as bars (a link without line of sight reads long; a misplaced
node has residuals of one sign on all its links); --convergence draws every node's 2-sigma
radius over time and the number of converged nodes over time, from JSON Lines or from the
engine's trace (cdro-hostd --trace-csv, given as ESTIMATES; over its t column when every row
has one, else over the ranges processed).

examples:
  cdro-plot estimates.jsonl --truth truth.csv --tracks tracks.csv --ranges ranges.csv --map map.png --rmse rmse.png
  cdro-plot nodes.csv --trajectory trajectory.csv --truth truth.csv --tracks tracks.csv --map map.png
  cdro-plot nodes.csv --ranges ranges.csv --heights heights.csv --residuals residuals.png
  cdro-plot trace.csv --convergence convergence.png
"""
from __future__ import annotations

import argparse
import bisect
import collections
import dataclasses
import json
import math
import sys

import numpy as np

from .evaluation import diagnostics, drawing
from .evaluation import inputs as csv_inputs
from .evaluation import movement
from .evaluation.alignment import align, rigid_fit, rmse  # noqa: F401  (rigid_fit: part of this module's API)
from .cli import entry_point


InputError = csv_inputs.InputError     # an input file that cannot be used at all
TRAJECTORY_FORMAT = csv_inputs.Format(("t", "x", "y", "heading_rad", "var_x", "cov_xy", "var_y"), ("frame",))
TRACE_FORMAT = csv_inputs.Format(("ranges", "id", "x", "y", "var_x", "cov_xy", "var_y", "converged"), ("t",))


@dataclasses.dataclass
class Estimate:
    t_s: float
    x_m: float
    y_m: float
    cov_m2: np.ndarray              # 2x2
    converged: bool = False
    moving: bool = False
    frame: str | None = None        # robot: "odometry" or "map" (None: not said)


@dataclasses.dataclass
class Estimates:
    nodes: dict[int, list[Estimate]] = dataclasses.field(default_factory=lambda: collections.defaultdict(list))
    robot: dict[int, list[Estimate]] = dataclasses.field(default_factory=lambda: collections.defaultdict(list))
    dropped: collections.Counter = dataclasses.field(default_factory=collections.Counter)  # unusable lines
    skipped: collections.Counter = dataclasses.field(default_factory=collections.Counter)  # fine, nothing to draw
    timed: bool = False             # JSON Lines or a trace: estimates over time
    axis: str = "t_s"               # what t_s counts: "t_s" (seconds) or "ranges" (a trace without times)


def _cov(var_x, cov_xy, var_y) -> np.ndarray:
    return np.array([[float(var_x), float(cov_xy)], [float(cov_xy), float(var_y)]])


def _finite(*values) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)


def read_json_lines(path: str) -> Estimates:
    out = Estimates(timed=True)
    with open(path) as f:
        for line in f:
            if not line.strip():
                continue
            try:
                obj = json.loads(line)
            except json.JSONDecodeError:
                out.dropped["not JSON"] += 1
                continue
            if not isinstance(obj, dict):
                out.dropped["not an object"] += 1
                continue
            kind = obj.get("type")
            if kind not in ("node", "robot"):
                if kind != "health":
                    out.dropped[f"type {kind!r}"] += 1
                continue
            # (before the numbers: an unplaced node's position is null, schema 2)
            if kind == "node" and obj.get("placed") is False:
                out.skipped["node not placed yet"] += 1
                continue
            keys = ["t_s", "id", "x_m", "y_m", "var_x_m2", "cov_xy_m2", "var_y_m2"]
            if any(k not in obj for k in keys):
                out.dropped[f"{kind} line without {', '.join(k for k in keys if k not in obj)}"] += 1
                continue
            values = [obj[k] for k in keys]
            if not _finite(*values) or obj["id"] != int(obj["id"]):
                out.dropped[f"{kind} line with a non-numeric value"] += 1
                continue
            estimate = Estimate(float(obj["t_s"]), float(obj["x_m"]), float(obj["y_m"]),
                                _cov(obj["var_x_m2"], obj["cov_xy_m2"], obj["var_y_m2"]),
                                bool(obj.get("converged", False)), bool(obj.get("moving", False)))
            estimate.frame = obj.get("frame")
            (out.nodes if kind == "node" else out.robot)[int(obj["id"])].append(estimate)
    for series in (*out.nodes.values(), *out.robot.values()):
        series.sort(key=lambda e: e.t_s)
    # Robot lines of schema 2 name their frame: as with a trajectory CSV, only the lines in the
    # frame of the last one share the nodes' frame.
    for robot_id, series in out.robot.items():
        final_frame = series[-1].frame if series else None
        kept = [e for e in series if e.frame == final_frame]
        if len(kept) < len(series):
            out.skipped[f"robot line in the {series[0].frame} frame (before the map)"] += len(series) - len(kept)
        out.robot[robot_id] = kept
    return out


def _drop(out: Estimates, bad: list[csv_inputs.BadRow]) -> None:
    """A CSV's bad rows (skipped), by file: how many, and the first one's line and reason."""
    for path in dict.fromkeys(b.path for b in bad):
        rows = [b for b in bad if b.path == path]
        out.dropped[f"{path}: bad rows (the first: line {rows[0].line}, {rows[0].reason})"] += len(rows)


def read_nodes_csv(path: str, trajectory: str | None, robot_id: int | None) -> Estimates:
    out = Estimates(timed=False)
    bad: list[csv_inputs.BadRow] = []
    unplaced: list[int] = []
    for node_id, e in csv_inputs.read_estimates(path, bad, unplaced).items():
        out.nodes[node_id].append(Estimate(0.0, float(e.xy_m[0]), float(e.xy_m[1]), e.cov_m2, e.converged))
    if unplaced:
        out.skipped[f"{path}: node not placed yet"] += len(unplaced)
    if trajectory:
        rows: list[tuple[Estimate, str | None]] = []

        def on_row(row: csv_inputs.Row) -> None:
            t_s, x_m, y_m = row.number("t"), row.number("x"), row.number("y")
            row.number("heading_rad")   # not drawn, but a row without a heading is damaged
            cov = _cov(row.number("var_x"), row.number("cov_xy"), row.number("var_y"))
            rows.append((Estimate(t_s, x_m, y_m, cov), row.text("frame") if row.has("frame") else None))

        csv_inputs.read_rows(trajectory, TRAJECTORY_FORMAT, on_row, bad)
        # A robot that stood while the map formed starts in the odometry's frame: only the rows in
        # the frame of the last row share the nodes' frame.
        final_frame = rows[-1][1] if rows else None
        for estimate, frame in rows:
            if frame != final_frame:
                out.skipped[f"{trajectory}: trajectory row in the {frame} frame (before the map)"] += 1
                continue
            out.robot[robot_id if robot_id is not None else 0].append(estimate)
    _drop(out, bad)
    return out


def read_trace_csv(path: str) -> Estimates:
    """The engine's trace (cdro-hostd --trace-csv): a snapshot of every placed node after every
    K-th range. Over its `t` column (s) when every row has one, else over the ranges processed."""
    out = Estimates(timed=True)
    rows: list[tuple[float, float | None, int, Estimate]] = []

    def on_row(row: csv_inputs.Row) -> None:
        count = csv_inputs.read_count(row, "ranges")
        t_s = row.number("t") if row.has("t") and row.text("t") != "" else None
        node_id, x_m, y_m = row.node_id("id"), row.number("x"), row.number("y")
        cov = _cov(row.number("var_x"), row.number("cov_xy"), row.number("var_y"))
        rows.append((float(count), t_s, node_id, Estimate(0.0, x_m, y_m, cov, row.flag("converged"))))

    bad: list[csv_inputs.BadRow] = []
    csv_inputs.read_rows(path, TRACE_FORMAT, on_row, bad)
    _drop(out, bad)
    timed = bool(rows) and all(t_s is not None for _, t_s, _, _ in rows)
    out.axis = "t_s" if timed else "ranges"
    for count, t_s, node_id, estimate in rows:
        estimate.t_s = t_s if timed else count
        out.nodes[node_id].append(estimate)
    for series in out.nodes.values():
        series.sort(key=lambda e: e.t_s)
    return out


def _is_trace(path: str) -> bool:
    """Whether a CSV's header names a `ranges` column (a trace, not a nodes CSV)."""
    try:
        with csv_inputs.Reader(path, csv_inputs.Format((), ("ranges",)), csv_inputs.Policy.STRICT) as reader:
            return "ranges" in reader.columns
    except InputError:
        return False            # read as a nodes CSV, which says what is wrong with it


def read_estimates(path: str, trajectory: str | None, robot_id: int | None) -> Estimates:
    with open(path) as f:
        head = f.read(4096).lstrip()
    if head.startswith("{"):
        if trajectory:
            raise InputError("--trajectory goes with a nodes CSV; JSON Lines carry the robot's own lines")
        return read_json_lines(path)
    if _is_trace(path):
        if trajectory:
            raise InputError("--trajectory goes with a nodes CSV, not with a trace")
        return read_trace_csv(path)
    return read_nodes_csv(path, trajectory, robot_id)


class Truth:
    def __init__(self, truth_csv: str | None, tracks_csv: str | None):
        self.start: dict[int, tuple[float, float]] = {}
        self.tracks: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        strict = csv_inputs.Policy.STRICT
        if truth_csv:
            xy, _ = csv_inputs.read_truth(truth_csv, [], strict)
            self.start = {node_id: (float(p[0]), float(p[1])) for node_id, p in xy.items()}
        if tracks_csv:
            for node_id, track in movement.read_tracks(tracks_csv, [], strict).items():
                self.tracks[node_id] = (track.t_s, track.xy_m)

    def has(self, node_id: int) -> bool:
        return node_id in self.start or node_id in self.tracks

    def at(self, node_id: int, t_s: float) -> np.ndarray:
        if node_id in self.tracks:
            times, xy = self.tracks[node_id]
            return np.array([np.interp(t_s, times, xy[:, 0]), np.interp(t_s, times, xy[:, 1])])
        return np.array(self.start[node_id])


def latest(series: list[Estimate], times: list[float], t_s: float) -> Estimate | None:
    """The last estimate at or before t_s (times: the series' t_s, sorted)."""
    index = bisect.bisect_right(times, t_s)
    return series[index - 1] if index else None


def aligned_errors(estimates: dict[int, Estimate], truth: Truth, t_s: float, offset_s: float):
    """(R, t, {id: error_m}) for the nodes with both an estimate and a truth, at t_s (math.inf:
    the end of every track). The fit is over the nodes that stand still where there are three:
    a moving node's estimate lags its truth, and fitting on it would spread its error over the
    whole map."""
    truth_now = {i: truth.at(i, t_s + offset_s) for i in estimates if truth.has(i)}
    still = {i: xy for i, xy in truth_now.items() if i not in truth.tracks}
    fit_on = still if len(still) >= 3 else truth_now
    alignment = align({i: (estimates[i].x_m, estimates[i].y_m) for i in fit_on}, fit_on)
    errors = {i: float(np.linalg.norm(alignment.apply([estimates[i].x_m, estimates[i].y_m]) - np.asarray(xy)[:2]))
              for i, xy in sorted(truth_now.items())}
    return alignment.rotation, alignment.translation_m, errors


def rmse_series(est: Estimates, truth: Truth, step_s: float, offset_s: float, min_nodes: int = 3):
    """[(t_s, node rmse_m, robot error_m or nan)] at every step_s of the estimates' time span."""
    times = sorted({e.t_s for series in est.nodes.values() for e in series})
    if not times:
        return []
    out = []
    end = times[-1]
    steps = int(math.floor((end - times[0]) / step_s + 1e-9))
    robot_series = next(iter(est.robot.values()), None)
    robot_times = [e.t_s for e in robot_series] if robot_series else []
    robot_id = next(iter(est.robot), None)
    node_times = {i: [e.t_s for e in series] for i, series in est.nodes.items()}
    for k in range(steps + 1):
        t = times[0] + k * step_s
        current = {i: e for i, series in est.nodes.items() if (e := latest(series, node_times[i], t)) is not None}
        if sum(1 for i in current if truth.has(i)) >= min_nodes:
            rotation, translation, errors = aligned_errors(current, truth, t, offset_s)
            robot_error = float("nan")
            if robot_series and truth.has(robot_id):
                r = latest(robot_series, robot_times, t)
                if r is not None:
                    robot_error = float(np.linalg.norm(rotation @ [r.x_m, r.y_m] + translation
                                                       - truth.at(robot_id, t + offset_s)))
            out.append((round(t, 6), rmse(errors), robot_error))
    return out


def plot_map(path: str, est: Estimates, truth: Truth, links: set[tuple[int, int]], rotation, translation,
             offset_s: float, title: str, final_t: float) -> None:
    def aligned(e: Estimate) -> np.ndarray:
        return rotation @ [e.x_m, e.y_m] + translation

    fig, ax = drawing.new_figure(drawing.MAP_SIZE_IN)
    final = {i: series[-1] for i, series in est.nodes.items() if series}
    positions = {i: aligned(e) for i, e in final.items()}
    drawing.draw_links(ax, links, positions)
    for node_id, (_, xy) in truth.tracks.items():
        ax.plot(xy[:, 0], xy[:, 1], "--", color="tab:green", linewidth=1.2, zorder=2,
                label="true track" if node_id == next(iter(truth.tracks)) else None)
    # estimated tracks of moving nodes, from converged or moving estimates (not the start-up)
    # (a track needs two estimates: a final map has one per node, and no track to draw or name)
    tracks = {i: np.array([aligned(e) for e in s if e.converged or e.moving]) for i, s in est.nodes.items()
              if i in truth.tracks or any(e.moving for e in s)}
    tracks = {i: xy for i, xy in tracks.items() if len(xy) >= 2}
    for k, xy in enumerate(tracks.values()):
        ax.plot(xy[:, 0], xy[:, 1], "-", color="tab:orange", linewidth=1.0, zorder=3,
                label="estimated track" if k == 0 else None)
    for series in est.robot.values():
        xy = np.array([aligned(e) for e in series])
        ax.plot(xy[:, 0], xy[:, 1], "-", color="tab:purple", linewidth=1.2, zorder=3, label="robot estimate")
    ids_truth = sorted(truth.start)
    if ids_truth:
        txy = np.array([truth.at(i, final_t + offset_s) for i in ids_truth])
        drawing.draw_truth(ax, txy)
    drawing.draw_estimates(ax, positions, {i: rotation @ e.cov_m2 @ rotation.T for i, e in final.items()},
                           "estimate (2-sigma)")
    drawing.finish(fig, ax, path, title)


def plot_rmse(path: str, series, title: str) -> None:
    fig, ax = drawing.new_figure(drawing.CURVE_SIZE_IN)
    t = [s[0] for s in series]
    ax.plot(t, [s[1] for s in series], label="nodes, aligned RMSE")
    if any(not math.isnan(s[2]) for s in series):
        ax.plot(t, [s[2] for s in series], label="robot position error")
    drawing.finish(fig, ax, path, title, xlabel="t (s)", ylabel="error (m)", equal=False)


def ranges_notes(bad: list[csv_inputs.BadRow]) -> list[str]:
    """The first bad rows of --ranges or --heights (skipped), and how many more."""
    notes = [f"{row.path}:{row.line}: {row.reason} (row skipped)" for row in bad[:10]]
    if len(bad) > 10:
        notes.append(f"{len(bad) - 10} more bad row(s) skipped")
    return notes


def residuals_of(est: Estimates, ranges: csv_inputs.Ranges, heights_csv: str | None):
    """Every link's residual against the final estimates, and the notes to print."""
    bad: list[csv_inputs.BadRow] = []
    heights = csv_inputs.read_heights(heights_csv, bad) if heights_csv else {}
    notes = ranges_notes(bad)
    if heights:
        projection = csv_inputs.project_ranges(ranges, heights)
        ranges = projection.ranges
        if projection.without_height:
            notes.append(f"{projection.without_height} range(s) left as measured: no height for "
                         + ", ".join(drawing.node_label(i) for i in projection.nodes_without_height[:10]))
    positions = {i: (series[-1].x_m, series[-1].y_m) for i, series in est.nodes.items() if series}
    residuals, left_out = diagnostics.link_residuals(ranges.links(), positions)
    if left_out:
        notes.append(f"{left_out} link(s) without an estimate at one end: no residual")
    return residuals, positions, notes


def convergence_of(est: Estimates):
    series = {i: [diagnostics.Sample(e.t_s, e.cov_m2, e.converged) for e in s] for i, s in est.nodes.items() if s}
    return series, diagnostics.converged_counts(series)


@entry_point
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cdro-plot", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("estimates", help="cdro-hostd JSON Lines, or a nodes CSV")
    parser.add_argument("--trajectory", help="robot trajectory CSV (with a nodes CSV)")
    parser.add_argument("--robot-id", type=lambda s: int(s, 0), help="the robot's node id (for a trajectory CSV)")
    parser.add_argument("--truth", help="truth nodes CSV id,x,y,z")
    parser.add_argument("--tracks", help="truth tracks CSV t,id,x,y")
    parser.add_argument("--ranges", help="ranges CSV t,from,to,range_m (draws the links)")
    parser.add_argument("--map", metavar="PNG", help="map output")
    parser.add_argument("--rmse", metavar="PNG", help="RMSE-over-time output (needs timed estimates and truth)")
    parser.add_argument("--residuals", metavar="PNG",
                        help="per-link residual output: median range - distance on the map (needs --ranges)")
    parser.add_argument("--heights", metavar="CSV", help="known heights id,z (m): ranges projected for --residuals")
    parser.add_argument("--convergence", metavar="PNG",
                        help="2-sigma radius per node and converged nodes over time (JSON Lines or a trace)")
    parser.add_argument("--step-s", type=float, default=0.5, help="RMSE curve step, s (default 0.5)")
    parser.add_argument("--time-offset-s", type=float, default=0.0,
                        help="truth time = estimate time + this (the service's t_s starts when it started)")
    parser.add_argument("--title", default="", help="plot title")
    args = parser.parse_args(argv)
    if not args.step_s > 0:
        parser.error("--step-s must be above 0")
    if not (args.map or args.rmse or args.residuals or args.convergence):
        parser.error("nothing to draw: give --map, --rmse, --residuals or --convergence")
    if args.residuals and not args.ranges:
        parser.error("--residuals needs --ranges (t,from,to,range_m)")
    if args.heights and not args.residuals:
        parser.error("--heights goes with --residuals")

    def fail(message: str) -> int:
        print(f"cdro-plot: {message}", file=sys.stderr)
        return 2

    try:
        est = read_estimates(args.estimates, args.trajectory, args.robot_id)
        truth = Truth(args.truth, args.tracks)
        ranges_bad: list[csv_inputs.BadRow] = []
        ranges = csv_inputs.read_ranges(args.ranges, ranges_bad) if args.ranges else None
    except (OSError, InputError, UnicodeDecodeError) as error:
        return fail(str(error))
    links = set(ranges.links()) if ranges is not None else set()
    for note in ranges_notes(ranges_bad):
        print(f"cdro-plot: note: {note}", file=sys.stderr)
    for reason, count in sorted(est.skipped.items()):
        print(f"cdro-plot: note: {count} line(s) not drawn: {reason} (as expected)", file=sys.stderr)
    for reason, count in sorted(est.dropped.items()):
        print(f"cdro-plot: dropped {count} line(s) that cannot be used: {reason}", file=sys.stderr)
    if not est.nodes:
        return fail(f"{args.estimates}: no node estimates")
    if args.convergence and not est.timed:
        return fail("--convergence needs estimates over time: JSON Lines or a trace (cdro-hostd --trace-csv)")
    if args.rmse and est.axis != "t_s":
        return fail("--rmse needs times: a trace without a t column counts ranges, not seconds")
    if args.rmse and not (est.timed or est.robot):
        return fail("--rmse needs estimates over time: JSON Lines, or a trajectory CSV")
    if args.rmse and not (truth.start or truth.tracks):
        return fail("--rmse needs --truth (and --tracks for moving nodes)")

    final = {i: s[-1] for i, s in est.nodes.items() if s}
    # A nodes CSV has no time: it is the map at the end of the run.
    final_t = max(e.t_s for e in final.values()) if est.timed else math.inf
    matched = sum(1 for i in final if truth.has(i))
    result: dict = {"nodes": len(final), "nodes_with_truth": matched}
    if matched:
        rotation, translation, errors = aligned_errors(final, truth, final_t, args.time_offset_s)
        result.update(rmse_m=round(rmse(errors), 6),
                      per_node_error_m={f"0x{i:04X}": round(e, 6) for i, e in sorted(errors.items())},
                      reflected=bool(np.linalg.det(rotation) < 0))
        for robot_id, series in est.robot.items():
            if truth.has(robot_id):
                robot_errors = [float(np.linalg.norm(rotation @ [e.x_m, e.y_m] + translation
                                                     - truth.at(robot_id, e.t_s + args.time_offset_s))) for e in series]
                result["robot_rmse_m"] = round(math.sqrt(sum(e * e for e in robot_errors) / len(robot_errors)), 6)
    else:
        rotation, translation = np.eye(2), np.zeros(2)
        if args.map:
            print("cdro-plot: no truth for these nodes: the map shows the estimates in the engine's frame",
                  file=sys.stderr)
    title = args.title or args.estimates
    try:
        if args.map:
            plot_map(args.map, est, truth, links, rotation, translation, args.time_offset_s, title, final_t)
        if args.residuals:
            residuals, positions, notes = residuals_of(est, ranges, args.heights)
            for note in notes:
                print(f"cdro-plot: note: {note}", file=sys.stderr)
            if not residuals:
                return fail("--residuals: no link has estimates at both ends")
            diagnostics.plot_residuals(args.residuals, residuals, positions, title, drawing.node_label)
            result["link_residuals"] = [
                {"a": r.a, "b": r.b, "a_hex": f"0x{r.a:04X}", "b_hex": f"0x{r.b:04X}", "ranges": r.ranges,
                 "range_median_m": round(r.range_median_m, 6), "fitted_distance_m": round(r.fitted_distance_m, 6),
                 "residual_m": round(r.residual_m, 6), "band": r.band} for r in residuals]
        if args.convergence:
            samples, counts = convergence_of(est)
            xlabel = "t (s)" if est.axis == "t_s" else "ranges processed"
            diagnostics.plot_convergence(args.convergence, samples, counts, xlabel, title, drawing.node_label)
            result["convergence"] = {
                "axis": est.axis, "points": len(counts), "final_converged": counts[-1][1] if counts else 0,
                "converged_over_time": [[round(t, 6), c] for t, c in counts],
                "final_two_sigma_m": {f"0x{i:04X}": round(diagnostics.two_sigma_radius_m(s[-1].cov_m2), 6)
                                      for i, s in sorted(samples.items())}}
        if args.rmse:
            if est.timed:
                series = rmse_series(est, truth, args.step_s, args.time_offset_s)
            else:   # a nodes CSV: the final alignment, the robot's error over its trajectory
                robot_id, robot = next(iter(est.robot.items()))
                series = [(e.t_s, result.get("rmse_m", float("nan")),
                           float(np.linalg.norm(rotation @ [e.x_m, e.y_m] + translation
                                                - truth.at(robot_id, e.t_s + args.time_offset_s)))
                           if truth.has(robot_id) else float("nan")) for e in robot]
            if not series:
                return fail("--rmse: no time with at least 3 nodes that have both an estimate and a truth")
            plot_rmse(args.rmse, series, title)
            result["rmse_over_time"] = {"points": len(series), "first_m": round(series[0][1], 6),
                                        "last_m": round(series[-1][1], 6)}
    except (OSError, InputError) as error:
        return fail(str(error))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
