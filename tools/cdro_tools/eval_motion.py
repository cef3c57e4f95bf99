"""cdro-eval-motion: how well the movement stage did, against ground truth.

Path and beacons (a robot with odometry):
  cdro-eval-motion --trajectory traj.csv --robot-truth groundtruth.csv \\
                   --nodes nodes.csv --beacon-truth beacons.csv [--path-png path.png]
A carried node (the initialization stage's Fig. 4 tracking):
  cdro-eval-motion --trace trace.csv --tracks tracks.csv --truth truth.csv \\
                   --motion motion.csv --node 0x6006 [--track-png track.png]
Moving nodes in 3D (tags among anchors; any number of nodes):
  cdro-eval-motion --tag-trajectory tags.csv --tag-truth tag_truth.csv [--align] [--max-gap-s 0.2]

The trajectory is cdro-hostd's --out-trajectory (t,x,y,heading_rad,var_x,cov_xy,var_y,frame: the
causal estimate after each odometry step; only the rows in the last row's frame are evaluated);
the robot truth t,x,y[,heading_rad]; nodes the --out-csv; beacon truth id,x,y. The trace is
cdro-hostd's --trace-csv (with --trace-every 1 for tracking), tracks the simulator's t,id,x,y,
truth its id,x,y,z start positions, motion its t,id,moving. The tag trajectory is
t,id,x,y,z[,var_x,cov_xy,var_y,var_z,cov_xz,cov_yz] (one row per estimate of any node), the tag
truth t,id,x,y,z; each estimate is scored against its node's truth interpolated at its time
(evaluation.tracking): 3D and horizontal RMSE, p95, max, per node and overall, in the anchors'
frame (no fit) unless --align. All fits are rigid (rotation, translation, reflection allowed, no
scale). The figures go to stdout as a table and to --json; exit 2 on unusable input.
"""
from __future__ import annotations

import argparse
import json
import math
import sys

from .evaluation.drawing import node_label
from .evaluation.inputs import BadRow, InputError, read_estimates, read_truth
from .evaluation.movement import (evaluate_beacons, evaluate_path, evaluate_track, read_motion, read_path,
                                  read_trace_rows, read_tracks)
from .evaluation.tracking import MAX_TRUTH_GAP_S, evaluate_tracking, format_table, read_node_tracks
from .cli import entry_point


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cdro-eval-motion", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trajectory", metavar="CSV", help="the robot's causal trajectory (cdro-hostd --out-trajectory)")
    p.add_argument("--robot-truth", metavar="CSV", help="the robot's true path t,x,y[,heading_rad]")
    p.add_argument("--max-dt-s", type=float, default=0.06, help="time match tolerance, s (default 0.06)")
    p.add_argument("--nodes", metavar="CSV", help="final node estimates id,x,y,... (cdro-hostd --out-csv)")
    p.add_argument("--beacon-truth", metavar="CSV", help="true node positions id,x,y[,z]")
    p.add_argument("--exclude", action="append", default=[], metavar="ID",
                   help="node ids left out of the beacon figures (e.g. the robot's own tag)")
    p.add_argument("--trace", metavar="CSV", help="cdro-hostd --trace-csv (with a t column)")
    p.add_argument("--tracks", metavar="CSV", help="true tracks t,id,x,y of the nodes that move")
    p.add_argument("--truth", metavar="CSV", help="true start positions id,x,y[,z]")
    p.add_argument("--motion", metavar="CSV", help="motion truth t,id,moving")
    p.add_argument("--node", metavar="ID", help="the carried node to evaluate (decimal or 0x hex)")
    p.add_argument("--settle-s", type=float, default=0.5,
                   help="tracking errors count until this long after a stop, s (default 0.5)")
    p.add_argument("--tag-trajectory", metavar="CSV",
                   help="3D estimates of moving nodes t,id,x,y,z[,var_x,cov_xy,var_y,var_z,cov_xz,cov_yz]")
    p.add_argument("--tag-truth", metavar="CSV", help="their true tracks t,id,x,y,z")
    p.add_argument("--align", action="store_true",
                   help="fit the tag trajectory rigidly to the truth first (self-calibrated runs; default: no fit, "
                        "the anchors fix the frame)")
    p.add_argument("--max-gap-s", type=float, default=MAX_TRUTH_GAP_S,
                   help=f"estimates between truth rows further apart are skipped, s (default {MAX_TRUTH_GAP_S})")
    p.add_argument("--json", metavar="PATH", help="every figure as JSON ('-' = stdout, the table then goes to stderr)")
    p.add_argument("--path-png", metavar="PATH", help="robot path (aligned) against the truth, with the beacons")
    p.add_argument("--track-png", metavar="PATH", help="the carried node's track and its error over time")
    p.add_argument("--title", default="", help="plot title")
    return p


def _id(text: str) -> int:
    return int(text, 0)


def _fmt(value) -> str:
    return "-" if value is None or (isinstance(value, float) and not math.isfinite(value)) else f"{value:.3f}"


@entry_point
def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    out = sys.stderr if args.json == "-" else sys.stdout
    bad: list[BadRow] = []
    report: dict = {}
    try:
        path_fit = None
        if args.trajectory or args.robot_truth:
            if not (args.trajectory and args.robot_truth):
                raise InputError("--trajectory and --robot-truth go together")
            path = evaluate_path(read_path(args.trajectory, bad), read_path(args.robot_truth, bad), args.max_dt_s)
            report["path"] = path["report"]
            path_fit = (path["rotation"], path["translation"])
        if args.nodes or args.beacon_truth:
            if not (args.nodes and args.beacon_truth):
                raise InputError("--nodes and --beacon-truth go together")
            excluded = {_id(x) for x in args.exclude}
            unplaced: list[int] = []
            estimates = {i: e.xy_m for i, e in read_estimates(args.nodes, bad, unplaced).items() if i not in excluded}
            truth, _ = read_truth(args.beacon_truth, bad)
            report["beacons"] = evaluate_beacons(estimates, truth, path_fit)
            report["beacons"]["not_placed"] = sorted(i for i in unplaced if i not in excluded)
        if args.trace or args.tracks or args.node:
            if not (args.trace and args.tracks and args.truth and args.motion and args.node):
                raise InputError("tracking needs --trace, --tracks, --truth, --motion and --node")
            node = _id(args.node)
            tracks = read_tracks(args.tracks, bad)
            if node not in tracks:
                raise InputError(f"{args.tracks}: no track for node {args.node}")
            intervals = read_motion(args.motion, bad).get(node, [])
            if not intervals:
                raise InputError(f"{args.motion}: node {args.node} never moves")
            truth, _ = read_truth(args.truth, bad)
            track = evaluate_track(read_trace_rows(args.trace, bad), node, truth, tracks[node], intervals,
                                   args.settle_s)
            report["track"] = track["report"]
        if args.tag_trajectory or args.tag_truth:
            if not (args.tag_trajectory and args.tag_truth):
                raise InputError("--tag-trajectory and --tag-truth go together")
            estimates = read_node_tracks(args.tag_trajectory, bad)
            if not estimates:
                raise InputError(f"{args.tag_trajectory}: no estimates")
            report["tags"] = evaluate_tracking(estimates, read_node_tracks(args.tag_truth, bad), args.align,
                                               args.max_gap_s)
        elif args.align:
            raise InputError("--align goes with --tag-trajectory")
    except (InputError, ValueError) as error:
        print(f"cdro-eval-motion: {error}", file=sys.stderr)
        return 2
    for row in bad[:20]:
        print(f"cdro-eval-motion: skipped {row}", file=sys.stderr)
    report["bad_rows"] = len(bad)
    if "path" in report:
        p = report["path"]
        print(f"robot path: aligned RMSE {_fmt(p['rmse_m'])} m, p95 {_fmt(p['p95_m'])} m, max {_fmt(p['max_m'])} m "
              f"({p['points']} poses)", file=out)
        if p["other_frame_points"]:
            print(f"robot path: {p['other_frame_points']} earlier poses are in another frame (dead reckoning before "
                  f"the map appeared) and not evaluated; the {p['frame']} frame starts at t = "
                  f"{p['frame_from_s']:.3f} s", file=out)
    if "beacons" in report:
        b = report["beacons"]
        print(f"beacons: aligned RMSE {_fmt(b['own_fit_rmse_m'])} m (own fit, {b['nodes']} nodes)"
              + (f", {_fmt(b['path_fit_rmse_m'])} m through the path's fit" if "path_fit_rmse_m" in b else ""),
              file=out)
    if "track" in report:
        t = report["track"]
        def times(key: str) -> str:
            return ", ".join(_fmt(x) + " s" if x is not None else "never" for x in t[key])
        print(f"track of {args.node}: RMSE {_fmt(t['rmse_m'])} m, p95 {_fmt(t['p95_m'])} m, max {_fmt(t['max_m'])} m "
              f"while moving ({t['points']} estimates); seen moving {times('start_seen_after_s')} after it started, "
              f"stopped {times('stop_seen_after_s')} after it stopped; converged again "
              f"{times('reconverged_after_s')} after stopping; static nodes {_fmt(t['static_rmse_m'])} m", file=out)
    if "tags" in report:
        t = report["tags"]
        frame = "rigidly fitted to the truth" if t["aligned"] else "anchors' frame, no fit"
        print(f"moving nodes ({frame}):", file=out)
        print(format_table(t, node_label), file=out)
        o = t["overall"]
        if o["outside_truth"] or o["across_gap"] or o["no_truth"]:
            print(f"skipped: {o['outside_truth']} estimates outside the truth's time span, {o['across_gap']} across a "
                  f"truth gap > {t['max_gap_s']:g} s, {o['no_truth']} of nodes without truth"
                  + (f" ({', '.join(node_label(i) for i in t['nodes_without_truth'])})"
                     if t["nodes_without_truth"] else ""), file=out)
        if o["inside_95_h"] is not None:
            print(f"inside their 95 % region: {o['inside_95_h']:.0%} horizontally"
                  + (f", {o['inside_95_3d']:.0%} in 3D" if o["inside_95_3d"] is not None else ""), file=out)
    if args.json:
        text = json.dumps(report, indent=2, sort_keys=True, default=float)
        if args.json == "-":
            print(text)
        else:
            with open(args.json, "w") as f:
                f.write(text + "\n")
    if args.path_png and "path" in report:
        _plot_path(args.path_png, path, report.get("beacons"), args, path_fit)
    if args.track_png and "track" in report:
        _plot_track(args.track_png, track, args)
    return 0


def _plot_path(png: str, path: dict, beacons: dict | None, args, fit) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from .evaluation.inputs import read_estimates, read_truth
    fig, ax = plt.subplots(figsize=(8, 7), dpi=100)
    ax.plot(path["truth_m"][:, 0], path["truth_m"][:, 1], color="tab:green", lw=1.0, label="true path")
    ax.plot(path["aligned_m"][:, 0], path["aligned_m"][:, 1], color="tab:orange", lw=1.0,
            label=f"causal estimate ({path['report']['rmse_m']:.2f} m)")
    if beacons is not None:
        bad: list = []
        truth, _ = read_truth(args.beacon_truth, bad)
        estimates = read_estimates(args.nodes, bad)
        excluded = {_id(x) for x in args.exclude}
        for node, xy in truth.items():
            ax.scatter(*xy[:2], s=90, facecolors="none", edgecolors="black")
            if node in estimates and node not in excluded:
                moved = fit[0] @ estimates[node].xy_m + fit[1]
                ax.scatter(*moved, color="tab:blue", s=25)
                ax.annotate(str(node), xy[:2], xytext=(5, 5), textcoords="offset points", fontsize=8)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(args.title or "robot path and beacons (hollow: truth, dots: estimates)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


def _plot_track(png: str, track: dict, args) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 4), dpi=100)
    ax.plot(track["t_s"], track["errors_m"], color="tab:red", lw=1.0)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("error (m)")
    ax.grid(alpha=0.3)
    r = track["report"]
    ax.set_title(args.title or f"node {args.node} while carried: RMSE {r['rmse_m']:.2f} m, p95 {r['p95_m']:.2f} m")
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
