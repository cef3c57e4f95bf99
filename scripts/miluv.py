#!/usr/bin/env python3
"""What a plain RTLS reaches on MiLUV's real flights (docs/results.md, "Moving nodes on real data:
MiLUV"): the tracking baselines of cdro_tools.evaluation.tracking_baselines, with their defaults,
and (c) the engine's 3D tracker of moving nodes (cdro-hostd --moving, its defaults; the binary of
$CDRO_BUILD_DIR, default ./build), on both experiments of ../shared/data/miluv (its README),
scored against tag_truth.csv in the anchors' frame (no fit: the anchors are surveyed) by
cdro_tools.evaluation.tracking.

    .venv/bin/python scripts/miluv.py [--data ../shared/data/miluv] [--out DIR] [--trace]
        [--speed-sigma 0.7] [--tau 2] [--sigma 0.1] [--gate]

Per experiment it prints a markdown table, per tag and overall, of each baseline's 3D RMSE /
horizontal RMSE / 3D p95 (m) and its number of estimates:
- (a) trilateration, (b) the EKF per tag, (c-ref) the EKF over all tags with the tag-to-tag ranges;
- (c) cdro-hostd --ranges-csv R --fixed-csv (the anchors' x, y) --heights-csv (their z) --moving
  (every tag) --out-trajectory T: the engine's joint 3D track of the tags, with the tag-to-tag
  ranges (docs/engine.md, "Nodes that never stop"); anchor 0 is given as 100 (below); and the same
  with --moving-body A:B:SEPARATION_M for each robot's two tags (the distance between their lever
  arms in tags.csv: the robot's calibration);
- (d) the same without the anchors' x, y (--heights-csv only): cdro-hostd calibrates the anchors
  from the tags' ranges first (moving_calibration.hpp), then tracks; scored after one rigid fit of
  the trajectory to the truth (rotation, translation, reflection: cdro-eval-motion --align), and
  the calibrated anchors after one rigid fit of their own to the surveyed ones;
- "room centre": a constant at the anchors' centroid 1 m below them, at every tag-anchor range,
  i.e. what an estimate that learns nothing scores;
- "replica": the same baselines on the same schedule with every range recomputed from the truth
  plus N(0, 0.1 m) (numpy seed 1): what the schedule and the geometry allow when the ranges are
  what the filters assume, apart from what the real ranges' errors cost.
Then the share of the EKFs' and the engine's errors inside their 95 % regions (3D), (c-ref) and
(c) scored at (b)'s rows only (after each tag-anchor range: the same times), and per anchor the residuals of its ranges
against the truth-derived range (ranges_detail's gt_range_m): mean, median, IQR, next to its
anchor_obstructed label, how many of its ranges the gates of (b) and (c-ref) down-weighted
(of those they tested), and how many the engine's NLOS model down-weighted or refused in (c)
(cdro-hostd's "NLOS ranges" log lines); a row for the tag-to-tag ranges.

--out DIR writes every trajectory (<experiment>-<baseline>.csv, the format cdro-eval-motion
--tag-trajectory reads) and miluv.json (every figure); with --trace also, per EKF,
<experiment>-<baseline>-trace.csv: each row's error against the truth next to the sigma the filter
claimed (how the figures of the EKF's diagnosis in docs/results.md were made). --speed-sigma, --tau, --sigma and
--gate change the EKFs' motion model (m/s, s), range sigma (m) and outlier handling (a hard gate
instead of Huber weights), to see how sensitive the figures are. The EKFs' defaults were decided
on simulated flights (tracking_baselines' docstring, tests/tools/test_tracking.py), not on these
scores. Deterministic.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import pathlib
import re
import shutil
import statistics
import subprocess
import sys
import tempfile

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))     # this checkout's cdro_tools, not an installed one

from cdro_tools.evaluation import tracking  # noqa: E402 (after the path)
from cdro_tools.evaluation.alignment import rigid_fit  # noqa: E402 (after the path)
from cdro_tools.evaluation import tracking_baselines as tb  # noqa: E402 (after the path)
from cdro_tools.evaluation.inputs import Format, Policy, Row, read_rows  # noqa: E402 (after the path)
from cdro_tools.simulation.uwb import measured_range_m  # noqa: E402 (after the path)

DATA = pathlib.Path(os.environ.get("CDRO_DATA_DIR", ROOT.parent / "shared" / "data")) / "miluv"
EXPERIMENTS = ("3robots_cirObstacles_random_0", "1robot_cirObstacles_random3_0")
REPLICA_SEED, REPLICA_NOISE_M = 1, 0.1
# MiLUV numbers an anchor 0, which is not a node id (as on the live link; the readers refuse it, as
# cdro-hostd does): it is read as this id and reported under its own, as Plaza's beacon 0 is
# (docs/results.md).
ZERO_ID_AS = 100
RENUMBERED_FILES = ("ranges.csv", "ranges_detail.csv", "nodes.csv", "tag_truth.csv")
# The data set's per-range labels (its README), written by its converter: a bad row there is a broken
# conversion, not a measurement to skip.
DETAIL_FORMAT = Format(("from", "to", "range_m", "gt_range_m", "anchor_obstructed"))
TITLES = {"trilateration": "(a) trilateration", "ekf": "(b) EKF per tag", "coop-ekf": "(c-ref) cooperative EKF",
          "engine": "(c) the engine's 3D tracker", "engine-body": "(c) + two tags a body (--moving-body)",
          "room-centre": "room centre (learns nothing)",
          "self-calibrated": "(d) anchors not given, aligned"}


def centre_rows(ranges: tb.TimedRanges, anchors: dict[int, np.ndarray]) -> list:
    centre = np.mean(list(anchors.values()), axis=0) - [0.0, 0.0, tb.START_BELOW_ANCHORS_M]
    return [(t, b if a in anchors else a, centre, None) for t, a, b in
            zip(ranges.t_s.tolist(), ranges.from_ids.tolist(), ranges.to_ids.tolist())
            if (a in anchors) != (b in anchors)]


def replica(ranges: tb.TimedRanges, anchors: dict[int, np.ndarray], truth: dict[int, tracking.NodeTrack],
            seed: int) -> tb.TimedRanges:
    """The same schedule, each range the true distance (tags' truth interpolated, held at the
    ends) plus Gaussian noise."""
    rng = np.random.default_rng(seed)

    def position(node: int, t_s: float) -> np.ndarray:
        if node in anchors:
            return anchors[node]
        track = truth[node]
        return np.array([np.interp(t_s, track.t_s, track.p_m[:, k]) for k in range(3)])

    values = [measured_range_m(float(np.linalg.norm(position(a, t) - position(b, t))), rng.standard_normal(),
                               REPLICA_NOISE_M)
              for t, a, b in zip(ranges.t_s.tolist(), ranges.from_ids.tolist(), ranges.to_ids.tolist())]
    return tb.TimedRanges(ranges.t_s, ranges.from_ids, ranges.to_ids, np.array(values), ranges.lines)


def score(rows: list, truth: dict[int, tracking.NodeTrack], align: bool = False) -> dict:
    estimates: dict[int, list] = {}
    for t, node, p, cov in rows:
        estimates.setdefault(node, []).append((t, p, cov))
    tracks = {}
    for node, values in estimates.items():
        values.sort(key=lambda v: v[0])
        covs = [np.full((3, 3), np.nan) if v[2] is None else v[2] for v in values]
        tracks[node] = tracking.NodeTrack(np.array([v[0] for v in values]), np.array([v[1] for v in values]),
                                          np.array(covs))
    return tracking.evaluate_tracking(tracks, truth, align=align)


def run_baselines(ranges, anchors, args) -> dict[str, tb.TrackingResult]:
    ekf = {"speed_sigma_m_s": args.speed_sigma, "tau_s": args.tau, "sigma_m": args.sigma, "huber": not args.gate}
    return {"trilateration": tb.trilaterate(ranges, anchors), "ekf": tb.track_ekf(ranges, anchors, **ekf),
            "coop-ekf": tb.track_ekf(ranges, anchors, cooperative=True, **ekf)}


def hostd_binary() -> pathlib.Path:
    """The cdro-hostd of the native build (CDRO_BUILD_DIR, default ./build)."""
    return pathlib.Path(os.environ.get("CDRO_BUILD_DIR", ROOT / "build")) / "bin" / "cdro-hostd"


def run_engine(hostd: pathlib.Path, ranges_csv: pathlib.Path, anchors: dict[int, np.ndarray], tags: list[int],
               scratch: pathlib.Path, name: str, extra: list[str] | None = None, calibrate: bool = False,
               log: list[str] | None = None) -> tuple[list, str]:
    """(c): cdro-hostd --moving, the tags tracked in 3D by the engine (motion_track_3d.hpp) against
    the anchors given as fixed (x, y) with their heights (z), with the tag-to-tag ranges; its
    defaults. calibrate: (d), only the heights given (no --fixed-csv): the engine calibrates the
    anchors from the tags' ranges first (moving_calibration.hpp). Returns the trajectory's rows
    (t_s, id, p_m, cov_m2) and cdro-hostd's summary line; `log` gets every line it wrote."""
    scratch.mkdir(parents=True, exist_ok=True)
    fixed, heights = scratch / f"{name}-anchors.csv", scratch / f"{name}-heights.csv"
    fixed.write_text("id,x,y\n" + "".join(f"{i},{float(p[0])!r},{float(p[1])!r}\n" for i, p in sorted(anchors.items())))
    heights.write_text("id,z\n" + "".join(f"{i},{float(p[2])!r}\n" for i, p in sorted(anchors.items())))
    trajectory = scratch / f"{name}-engine.csv"
    given = [] if calibrate else ["--fixed-csv", str(fixed)]
    result = subprocess.run([str(hostd), "--ranges-csv", str(ranges_csv), *given,
                             "--heights-csv", str(heights), "--moving", ",".join(map(str, tags)),
                             "--out-csv", str(scratch / f"{name}-engine-nodes.csv"),
                             "--out-trajectory", str(trajectory), *(extra or [])],
                            capture_output=True, text=True, timeout=600)
    if result.returncode != 0:
        raise RuntimeError(f"cdro-hostd failed ({result.returncode}): {result.stderr}")
    bad: list = []
    tracks = tracking.read_node_tracks(str(trajectory), bad)
    if bad:
        raise RuntimeError(f"{trajectory}: {len(bad)} bad rows, the first: {bad[0]}")
    rows = [(float(t), node, track.p_m[k].copy(), track.cov_m2[k].copy())
            for node, track in tracks.items() for k, t in enumerate(track.t_s)]
    rows.sort(key=lambda row: row[0])   # stable: the file's order at equal times
    summary = next((line for line in result.stderr.splitlines() if "moving nodes tracked in 3D" in line), "")
    if log is not None:
        log.extend(result.stderr.splitlines())
    return rows, summary


NLOS_LINE = re.compile(r"NLOS ranges (to anchor (\d+)|between moving nodes): (\d+) taken, (\d+) of them "
                       r"down-weighted, (\d+) refused")
ANCHOR_LINE = re.compile(r"anchor (\d+) self-calibrated at (\S+), (\S+), (\S+) m")


def nlos_counts(log: list[str]) -> dict:
    """cdro-hostd's per-anchor NLOS lines (docs/engine.md): key anchor id (as the data set numbers
    it) or "tag-tag" -> taken, down_weighted, refused."""
    out: dict = {}
    for line in log:
        m = NLOS_LINE.search(line)
        if m:
            key = dataset_id(int(m.group(2))) if m.group(2) else "tag-tag"
            out[key] = {"taken": int(m.group(3)), "down_weighted": int(m.group(4)), "refused": int(m.group(5))}
    return out


def calibrated_anchors(log: list[str]) -> dict[int, np.ndarray]:
    """The anchors cdro-hostd calibrated (its "self-calibrated at" lines), by node id."""
    return {int(m.group(1)): np.array([float(m.group(k)) for k in (2, 3, 4)])
            for m in map(ANCHOR_LINE.search, log) if m}


def anchors_aligned(estimate: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> dict:
    """The calibrated anchors against the surveyed ones after one rigid fit of their own (3D,
    reflection allowed): RMSE 3D and horizontal, and each anchor's 3D error (m)."""
    ids = sorted(estimate)
    e, g = np.array([estimate[i] for i in ids]), np.array([truth[i] for i in ids])
    rotation, translation = rigid_fit(e, g, dim=3)
    d = e @ rotation.T + translation - g
    return {"rmse_3d_m": float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))),
            "rmse_h_m": float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))),
            "errors_m": {str(dataset_id(i)): float(np.linalg.norm(x)) for i, x in zip(ids, d)}}


def body_arguments(tags_csv: pathlib.Path) -> list[str]:
    """--moving-body A:B:SEPARATION_M for each robot's two tags, the separation the distance
    between their lever arms (tags.csv: id,robot,arm_x,arm_y,arm_z; the robot's calibration, what
    an installer knows)."""
    by_robot: dict[str, list[tuple[int, np.ndarray]]] = {}
    with open(tags_csv, newline="") as f:
        for row in csv.DictReader(f):
            arm = np.array([float(row["arm_x"]), float(row["arm_y"]), float(row["arm_z"])])
            by_robot.setdefault(row["robot"], []).append((int(row["id"]), arm))
    out = []
    for _robot, tags in sorted(by_robot.items()):
        if len(tags) == 2:
            (a, arm_a), (b, arm_b) = tags
            out += ["--moving-body", f"{a}:{b}:{float(np.linalg.norm(arm_a - arm_b)):.4f}"]
    return out


def write_ranges(path: pathlib.Path, ranges: tb.TimedRanges) -> None:
    with open(path, "w") as f:
        f.write("t,from,to,range_m\n")
        for t, a, b, r in zip(ranges.t_s.tolist(), ranges.from_ids.tolist(), ranges.to_ids.tolist(),
                              ranges.range_m.tolist()):
            f.write(f"{t!r},{a},{b},{r!r}\n")


def renumbered(folder: pathlib.Path, into: pathlib.Path) -> pathlib.Path:
    """A copy of an experiment's files with node id 0 as ZERO_ID_AS (a copy of the converter's
    text, field for field: only ids change)."""
    copy = into / folder.name
    copy.mkdir(parents=True, exist_ok=True)
    for file in RENUMBERED_FILES:
        with open(folder / file, newline="") as f:
            rows = list(csv.reader(f))
        ids = [i for i, column in enumerate(rows[0]) if column in ("from", "to", "id")]
        for row in rows[1:]:
            for i in ids:
                row[i] = str(ZERO_ID_AS) if row[i] == "0" else row[i]
        with open(copy / file, "w", newline="") as f:
            csv.writer(f, lineterminator="\n").writerows(rows)
    return copy


def dataset_id(node: int) -> int:
    """A node's id as the data set numbers it."""
    return 0 if node == ZERO_ID_AS else node


def anchor_report(detail_path: pathlib.Path, ranges: tb.TimedRanges, anchors: dict[int, np.ndarray],
                  results: dict[str, tb.TrackingResult]) -> list[dict]:
    residuals: dict[object, list[float]] = {}
    obstructed: dict[object, bool] = {}

    def on_row(row: Row) -> None:
        a, b = row.node_id("from"), row.node_id("to")
        key = a if a in anchors else b if b in anchors else "tag-tag"
        residuals.setdefault(key, []).append(row.number("range_m") - row.number("gt_range_m"))
        obstructed[key] = obstructed.get(key, False) or row.text("anchor_obstructed") == "1"

    read_rows(str(detail_path), DETAIL_FORMAT, on_row, None, Policy.STRICT)
    keys = [*sorted((k for k in residuals if k != "tag-tag"), key=dataset_id),
            *(["tag-tag"] if "tag-tag" in residuals else [])]
    out = []
    for key in keys:
        values = residuals[key]
        q1, _, q3 = statistics.quantiles(values, n=4) if len(values) > 1 else (values[0],) * 3
        anchor = key != "tag-tag"
        entry = {"anchor": dataset_id(key) if anchor else key, "obstructed": obstructed[key] if anchor else None,
                 "ranges": len(values),
                 "mean_m": statistics.fmean(values), "median_m": statistics.median(values), "iqr_m": q3 - q1}
        for name in ("ekf", "coop-ekf"):
            tested = rejected = 0
            for a, b, status in zip(ranges.from_ids.tolist(), ranges.to_ids.tolist(), results[name].status):
                end = a if a in anchors else b if b in anchors else "tag-tag"
                if end == key and status in ("used", "rejected"):
                    tested += 1
                    rejected += status == "rejected"
            entry[f"{name}_tested"], entry[f"{name}_rejected"] = tested, rejected
        out.append(entry)
    return out


def write_trace(path: pathlib.Path, rows: list, truth: dict[int, tracking.NodeTrack]) -> None:
    """Each row's error against the interpolated truth and the sigmas its covariance claims:
    t,id,err_3d_m,err_h_m,err_z_m,sigma_x_m,sigma_y_m,sigma_z_m,nees_3d (rows without truth skipped)."""
    with open(path, "w") as f:
        f.write("t,id,err_3d_m,err_h_m,err_z_m,sigma_x_m,sigma_y_m,sigma_z_m,nees_3d\n")
        for t_s, node, p_m, cov in rows:
            g = tracking.interpolate_truth(truth[node], t_s) if node in truth else "no_truth"
            if isinstance(g, str) or cov is None:
                continue
            d = p_m - g
            sigma = np.sqrt(np.diag(cov))
            nees = float(d @ np.linalg.solve(cov, d))
            f.write(f"{t_s:.6f},{node},{np.linalg.norm(d):.4f},{np.linalg.norm(d[:2]):.4f},{d[2]:.4f},"
                    f"{sigma[0]:.4f},{sigma[1]:.4f},{sigma[2]:.4f},{nees:.3f}\n")


def cell(entry: dict) -> str:
    if not entry or not entry["points"]:
        return "-"
    return f"{entry['rmse_3d_m']:.2f} / {entry['rmse_h_m']:.2f} / {entry['p95_3d_m']:.2f} ({entry['points']})"


def print_experiment(name: str, summary: dict) -> None:
    s = summary["ranges"]
    print(f"\n### {name}: {len(summary['tags'])} tags, {s['tag_anchor']} tag-anchor and {s['tag_tag']} tag-tag ranges, "
          f"{s['duration_s']:.0f} s\n")
    columns = ["trilateration", "ekf", "coop-ekf", "engine", "engine-body", "self-calibrated", "room-centre"]
    print("| tag | " + " | ".join(TITLES[c] for c in columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for tag in summary["tags"]:
        print(f"| {tag} | " + " | ".join(cell(summary["scores"][c]["nodes"].get(str(tag), {})) for c in columns) + " |")
    print("| **all** | " + " | ".join(cell(summary["scores"][c]["overall"]) for c in columns) + " |")
    print(f"| replica, all (truth ranges + N(0, {REPLICA_NOISE_M} m)) | "
          + " | ".join(cell(summary["replica"][c]["overall"]) if c in summary["replica"] else "-" for c in columns)
          + " |")
    print("\nCells: 3D RMSE / horizontal RMSE / 3D p95 (m) (estimates); (d) after one rigid fit of its trajectory "
          "to the truth (cdro-eval-motion --align), the others in the surveyed anchors' frame.")
    d = summary["calibration"]
    print(f"(d): anchors' RMSE after their own rigid fit {d['anchors']['rmse_3d_m']:.2f} m 3D, "
          f"{d['anchors']['rmse_h_m']:.2f} m horizontal (per anchor: "
          + ", ".join(f"{k} {v:.2f}" for k, v in d["anchors"]["errors_m"].items())
          + f"); replica {d['replica_anchors']['rmse_3d_m']:.2f} m. {d['summary']}")
    notes = []
    for c in ("trilateration", "ekf", "coop-ekf"):
        counts = summary["counts"][c]
        notes.append(f"{c}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    print("Ranges by use: " + "; ".join(notes) + ".")
    never = summary["notes"]["ekf"].get("never_started") or []
    if never:
        print(f"Tags the EKFs never started (no range to an anchor): {never}.")
    inside = [f"{TITLES[c]} {summary['scores'][c]['overall']['inside_95_3d']:.0%}"
              for c in ("ekf", "coop-ekf", "engine", "engine-body")]
    same, ekf = summary["coop_at_ekf_rows"], summary["scores"]["ekf"]["overall"]
    engine_same = summary["engine_at_ekf_rows"]
    print("Errors inside the 95 % region (3D): " + ", ".join(inside) + f". At (b)'s rows: (c-ref) "
          f"{same['rmse_3d_m']:.2f} / {same['rmse_h_m']:.2f} m ({same['points']}), (c) "
          f"{engine_same['rmse_3d_m']:.2f} / {engine_same['rmse_h_m']:.2f} m ({engine_same['points']}), (c) + body "
          f"{summary['body_at_ekf_rows']['rmse_3d_m']:.2f} / {summary['body_at_ekf_rows']['rmse_h_m']:.2f} m, (b) "
          f"{ekf['rmse_3d_m']:.2f} / {ekf['rmse_h_m']:.2f} m.")
    print(f"(c): {summary['engine_summary']}")
    print("\n| anchor | obstructed (label) | ranges | residual mean / median / IQR (m) | (b) beyond the gate | "
          "(c-ref) beyond the gate | (c) down-weighted + refused, of decided |")
    print("|---|---|---|---|---|---|---|")
    for a in summary["anchors"]:
        label = "-" if a["obstructed"] is None else ("yes" if a["obstructed"] else "no")
        ekf = f"{a['ekf_rejected']} of {a['ekf_tested']}" if a["ekf_tested"] else "-"
        n = summary["nlos"].get(a["anchor"])
        engine = "-" if not n else (f"{n['down_weighted']} + {n['refused']} of {n['taken'] + n['refused']} "
                                    f"({(n['down_weighted'] + n['refused']) / max(n['taken'] + n['refused'], 1):.0%})")
        print(f"| {a['anchor']} | {label} | {a['ranges']} | {a['mean_m']:+.3f} / {a['median_m']:+.3f} / "
              f"{a['iqr_m']:.3f} | {ekf} | {a['coop-ekf_rejected']} of {a['coop-ekf_tested']} | {engine} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default=str(DATA), help="the folder that holds the two experiments")
    parser.add_argument("--out", help="write the trajectories and miluv.json here")
    parser.add_argument("--trace", action="store_true", help="with --out: each EKF row's error and claimed sigma")
    parser.add_argument("--speed-sigma", type=float, default=tb.SPEED_SIGMA_M_S,
                        help="EKF: the velocity's stationary sigma per axis, m/s")
    parser.add_argument("--tau", type=float, default=tb.SPEED_TAU_S, help="EKF: the velocity's correlation time, s")
    parser.add_argument("--sigma", type=float, default=tb.RANGE_SIGMA_M, help="EKF range sigma, m")
    parser.add_argument("--gate", action="store_true", help="EKF: reject beyond the gate instead of Huber weights")
    args = parser.parse_args()
    data = pathlib.Path(args.data)
    missing = [data / e for e in EXPERIMENTS if not (data / e / "ranges.csv").is_file()]
    if missing:
        print(f"miluv: {', '.join(map(str, missing))} not found (set CDRO_DATA_DIR or --data)", file=sys.stderr)
        return 2
    out = pathlib.Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    report: dict = {"settings": {"speed_sigma_m_s": args.speed_sigma, "tau_s": args.tau, "sigma_m": args.sigma,
                                 "huber": not args.gate, "gate_chi2": tb.GATE_CHI2,
                                 "reset_after": tb.RESET_AFTER_REJECTS, "window_s": tb.WINDOW_S,
                                 "replica_seed": REPLICA_SEED, "replica_noise_m": REPLICA_NOISE_M}}
    print(f"EKF: velocity sigma {args.speed_sigma:g} m/s per axis, tau {args.tau:g} s, range sigma {args.sigma:g} m, "
          + ("gate" if args.gate else "Huber weights") + f" beyond nu^2/S > {tb.GATE_CHI2:g}, reset after "
          f"{tb.RESET_AFTER_REJECTS} in a row, room: the anchors' box + {tb.ROOM_MARGIN_M:g} m from z = "
          f"{tb.FLOOR_Z_M:g}; trilateration window {tb.WINDOW_S:g} s; replica seed {REPLICA_SEED}")
    hostd = hostd_binary()
    if not hostd.is_file():
        print(f"miluv: {hostd} not found: build it (cmake --build build --target cdro-hostd) or set CDRO_BUILD_DIR",
              file=sys.stderr)
        return 2
    copies = tempfile.TemporaryDirectory(prefix="miluv-")
    for name in EXPERIMENTS:
        folder = renumbered(data / name, pathlib.Path(copies.name))
        bad: list = []
        ranges = tb.read_timed_ranges(str(folder / "ranges.csv"), bad)
        anchors = tb.read_anchors(str(folder / "nodes.csv"), bad)
        truth = tracking.read_node_tracks(str(folder / "tag_truth.csv"), bad)
        if bad:
            print(f"miluv: {len(bad)} bad rows, the first: {bad[0]}", file=sys.stderr)
        results = run_baselines(ranges, anchors, args)
        rows = {n: r.rows for n, r in results.items()}
        tags = sorted({int(t) for t in truth})
        scratch = pathlib.Path(copies.name) / "engine"
        engine_log: list[str] = []
        rows["engine"], engine_summary = run_engine(hostd, folder / "ranges.csv", anchors, tags, scratch, name,
                                                    log=engine_log)
        # (d): only the heights given; the anchors calibrated from the tags' ranges, scored after fits.
        calibration_log: list[str] = []
        rows["self-calibrated"], _ = run_engine(hostd, folder / "ranges.csv", anchors, tags, scratch, f"{name}-d",
                                                calibrate=True, log=calibration_log)
        bodies = body_arguments(data / name / "tags.csv")
        rows["engine-body"], _ = run_engine(hostd, folder / "ranges.csv", anchors, tags, scratch, f"{name}-body",
                                            bodies)
        rows["room-centre"] = centre_rows(ranges, anchors)
        scores = {n: score(r, truth, align=n == "self-calibrated") for n, r in rows.items()}
        replica_ranges = replica(ranges, anchors, truth, REPLICA_SEED)
        replica_scores = {n: score(r.rows, truth) for n, r in run_baselines(replica_ranges, anchors, args).items()}
        write_ranges(scratch / f"{name}-replica-ranges.csv", replica_ranges)
        replica_engine, _ = run_engine(hostd, scratch / f"{name}-replica-ranges.csv", anchors, tags, scratch,
                                       f"{name}-replica")
        replica_scores["engine"] = score(replica_engine, truth)
        replica_body, _ = run_engine(hostd, scratch / f"{name}-replica-ranges.csv", anchors, tags, scratch,
                                     f"{name}-replica-body", bodies)
        replica_scores["engine-body"] = score(replica_body, truth)
        replica_log: list[str] = []
        replica_d, _ = run_engine(hostd, scratch / f"{name}-replica-ranges.csv", anchors, tags, scratch,
                                  f"{name}-replica-d", calibrate=True, log=replica_log)
        replica_scores["self-calibrated"] = score(replica_d, truth, align=True)
        calibration = {"anchors": anchors_aligned(calibrated_anchors(calibration_log), anchors),
                       "replica_anchors": anchors_aligned(calibrated_anchors(replica_log), anchors),
                       "summary": next((line for line in calibration_log if "anchors calibrated from" in line), ""),
                       "estimates": {str(dataset_id(i)): p.tolist()
                                     for i, p in calibrated_anchors(calibration_log).items()}}
        ekf_rows = {(t, node) for t, node, _, _ in results["ekf"].rows}
        coop_at_ekf_rows = score([r for r in results["coop-ekf"].rows if (r[0], r[1]) in ekf_rows], truth)["overall"]
        engine_at_ekf_rows = score([r for r in rows["engine"] if (r[0], r[1]) in ekf_rows], truth)["overall"]
        body_at_ekf_rows = score([r for r in rows["engine-body"] if (r[0], r[1]) in ekf_rows], truth)["overall"]
        kinds = [(a in anchors) != (b in anchors) for a, b in zip(ranges.from_ids.tolist(), ranges.to_ids.tolist())]
        summary = {
            "tags": sorted({int(t) for t in truth}),
            "ranges": {"tag_anchor": sum(kinds), "tag_tag": len(kinds) - sum(kinds),
                       "duration_s": float(ranges.t_s[-1] - ranges.t_s[0]), "bad_rows": len(bad)},
            "scores": scores, "replica": replica_scores, "coop_at_ekf_rows": coop_at_ekf_rows,
            "engine_at_ekf_rows": engine_at_ekf_rows, "engine_summary": engine_summary,
            "body_at_ekf_rows": body_at_ekf_rows, "calibration": calibration, "nlos": nlos_counts(engine_log),
            "counts": {n: r.counts() for n, r in results.items()},
            "notes": {n: r.notes for n, r in results.items()},
            "anchors": anchor_report(folder / "ranges_detail.csv", ranges, anchors, results)}
        print_experiment(name, summary)
        report[name] = {"baselines": {n: scores[n] for n in results}, "room_centre": scores["room-centre"],
                        "engine": scores["engine"], "engine_at_ekf_rows": engine_at_ekf_rows,
                        "engine_body": scores["engine-body"], "engine_body_at_ekf_rows": body_at_ekf_rows,
                        "bodies": bodies,
                        "engine_summary": engine_summary,
                        "replica": {n: s["overall"] for n, s in replica_scores.items()},
                        "coop_at_ekf_rows": coop_at_ekf_rows,
                        "ranges": summary["ranges"], "counts": summary["counts"], "notes": summary["notes"],
                        "anchors": summary["anchors"], "self_calibrated": scores["self-calibrated"],
                        "calibration": calibration,
                        "nlos": {str(k): v for k, v in summary["nlos"].items()}}
        if out:
            shutil.copyfile(scratch / f"{name}-engine.csv", out / f"{name}-engine.csv")
            shutil.copyfile(scratch / f"{name}-body-engine.csv", out / f"{name}-engine-body.csv")
            shutil.copyfile(scratch / f"{name}-d-engine.csv", out / f"{name}-self-calibrated.csv")
            if args.trace:
                write_trace(out / f"{name}-engine-trace.csv", rows["engine"], truth)
            for n, r in results.items():
                tracking.write_trajectory(str(out / f"{name}-{n}.csv"), r.rows)
                if args.trace and n != "trilateration":
                    write_trace(out / f"{name}-{n}-trace.csv", r.rows, truth)
    copies.cleanup()
    if out:
        (out / "miluv.json").write_text(json.dumps(report, indent=1, default=_json_default) + "\n")
    return 0


def _json_default(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    raise TypeError(f"{type(value)} is not JSON")


if __name__ == "__main__":
    sys.exit(main())
