"""Scoring the 3D tracks of moving nodes against their true tracks (cdro-eval-motion
--tag-trajectory; docs/tools.md).

Files:
- the estimate, a per-node trajectory `t,id,x,y,z[,var_x,cov_xy,var_y,var_z,cov_xz,cov_yz]`
  (t in seconds, id decimal or 0x hex, metres, m^2): one row per estimate, any order, any number
  of nodes; the covariance columns are optional (all six, or the first three for the horizontal
  part only; an empty cell means no covariance for that row);
- the truth `t,id,x,y,z` (e.g. mocap at 100 Hz).

Matching: each estimate is compared with its node's truth linearly interpolated at the
estimate's time. An estimate before the node's first or after its last truth row
(`outside_truth`), or between two truth rows more than `max_gap_s` (0.2 s) apart (`across_gap`:
a mocap dropout, where a straight line is no truth), is skipped and counted; so are estimates of a
node that has no truth (`no_truth`). Errors: 3D |p - g| and horizontal |p_xy - g_xy|, per node
and over all estimates of all nodes together: count, RMSE, p95 (numpy's linear percentile), max.

Frame: by default none is fitted: with anchors at surveyed positions the estimate is in the
truth's frame already, and a fit would hide a shifted or rotated solution. `align=True` is for
self-calibrated runs (no anchor known): one rigid fit (rotation, translation, reflection allowed,
no scale; evaluation.alignment.rigid_fit in 3D) over every matched estimate of every node, then
the same figures; covariances are rotated with it.

Consistency, when the file has covariances: the share of estimates whose error is inside their
95 % region: d^T C^-1 d <= 5.991 for the horizontal 2x2 block (chi-square, 2 degrees of freedom)
and <= 7.815 for the 3x3 (3 degrees of freedom). About 0.95 is consistent; far below is
overconfident.
"""
from __future__ import annotations

import bisect
import dataclasses
import math

import numpy as np

from .alignment import rigid_fit
from .inputs import BadRow, Format, Policy, Reader, Row

MAX_TRUTH_GAP_S = 0.2
HORIZONTAL_COVARIANCE_COLUMNS = ("var_x", "cov_xy", "var_y")
COVARIANCE_COLUMNS = (*HORIZONTAL_COVARIANCE_COLUMNS, "var_z", "cov_xz", "cov_yz")
TRAJECTORY_COLUMNS = ("t", "id", "x", "y", "z", *COVARIANCE_COLUMNS)
CHI2_95_2DOF = 5.991
CHI2_95_3DOF = 7.815


@dataclasses.dataclass
class NodeTrack:
    """One node's rows, sorted by time."""
    t_s: np.ndarray                     # (n,)
    p_m: np.ndarray                     # (n, 3)
    cov_m2: np.ndarray | None = None    # (n, 3, 3); NaN where a row has no (3D) covariance


TRACKS_FORMAT = Format(("t", "id", "x", "y", "z"), COVARIANCE_COLUMNS)


def _covariance(row: Row) -> np.ndarray:
    """The 3x3 covariance of a row; NaN entries where the file or the row has none."""
    cov = np.full((3, 3), np.nan)
    if not all(row.has(c) for c in HORIZONTAL_COVARIANCE_COLUMNS) or row.text("var_x") == "":
        return cov
    var_x, cov_xy, var_y = (row.number(c) for c in HORIZONTAL_COVARIANCE_COLUMNS)
    if var_x < 0 or var_y < 0 or cov_xy * cov_xy > var_x * var_y * (1 + 1e-6) + 1e-12:
        row.reject(f"horizontal covariance not positive semi-definite (var_x {var_x:g}, cov_xy {cov_xy:g}, "
                   f"var_y {var_y:g} m^2)")
    cov[:2, :2] = [[var_x, cov_xy], [cov_xy, var_y]]
    if all(row.has(c) for c in COVARIANCE_COLUMNS) and row.text("var_z") != "":
        var_z, cov_xz, cov_yz = (row.number(c) for c in COVARIANCE_COLUMNS[3:])
        cov[2, 2], cov[0, 2], cov[2, 0], cov[1, 2], cov[2, 1] = var_z, cov_xz, cov_xz, cov_yz, cov_yz
        if np.linalg.eigvalsh(cov).min() < -1e-9 * max(1.0, float(np.trace(cov))):
            row.reject("3D covariance not positive semi-definite")
    return cov


def read_node_tracks(path: str, bad: list[BadRow]) -> dict[int, NodeTrack]:
    """`t,id,x,y,z[,covariance]` rows by node id, each sorted by time (stable: equal times keep
    the file order). Covariances are read when the file has the columns (else `cov_m2` is None)."""
    rows: dict[int, list[tuple[float, np.ndarray, np.ndarray]]] = {}

    def on_row(row: Row) -> None:
        t_s, node = row.number("t"), row.node_id("id")
        p_m = np.array([row.number(c) for c in ("x", "y", "z")])
        rows.setdefault(node, []).append((t_s, p_m, _covariance(row)))

    reader = Reader(path, TRACKS_FORMAT, Policy.LENIENT, kept_problems=None)
    has_cov = all(c in reader.columns for c in HORIZONTAL_COVARIANCE_COLUMNS)
    try:
        reader.for_each(on_row)
    finally:
        bad.extend(reader.summary.problems)
    out = {}
    for node, values in rows.items():
        values.sort(key=lambda v: v[0])
        out[node] = NodeTrack(np.array([v[0] for v in values]), np.array([v[1] for v in values]).reshape(-1, 3),
                              np.array([v[2] for v in values]).reshape(-1, 3, 3) if has_cov else None)
    return out


def write_trajectory(path: str, rows: list[tuple[float, int, np.ndarray, np.ndarray | None]]) -> None:
    """Write (t_s, id, p_m (3,), cov_m2 (3, 3) or None) rows in the trajectory format (the
    covariance cells of a row without one are empty)."""
    with open(path, "w") as f:
        f.write(",".join(TRAJECTORY_COLUMNS) + "\n")
        for t_s, node, p_m, cov in rows:
            cells = [f"{t_s:.6f}", str(node), *(f"{v:.4f}" for v in p_m)]
            if cov is None:
                cells += [""] * len(COVARIANCE_COLUMNS)
            else:
                cells += [f"{v:.6g}" for v in (cov[0, 0], cov[0, 1], cov[1, 1], cov[2, 2], cov[0, 2], cov[1, 2])]
            f.write(",".join(cells) + "\n")


def interpolate_truth(truth: NodeTrack, t_s: float, max_gap_s: float = MAX_TRUTH_GAP_S) -> np.ndarray | str:
    """The truth at t_s (linear between the rows around it), or why there is none:
    'outside_truth' or 'across_gap'."""
    times = truth.t_s
    if len(times) == 0 or t_s < times[0] or t_s > times[-1]:
        return "outside_truth"
    i = bisect.bisect_right(times, t_s)
    if i == len(times):                 # exactly the last row
        return truth.p_m[-1]
    if times[i - 1] == t_s:
        return truth.p_m[i - 1]
    if times[i] - times[i - 1] > max_gap_s:
        return "across_gap"
    f = (t_s - times[i - 1]) / (times[i] - times[i - 1])
    return truth.p_m[i - 1] + f * (truth.p_m[i] - truth.p_m[i - 1])


def error_stats(errors_3d_m: np.ndarray, errors_h_m: np.ndarray) -> dict:
    """points, RMSE, p95 and max of the 3D and the horizontal errors (None without points)."""
    out: dict = {"points": len(errors_3d_m)}
    for name, errors in (("3d", errors_3d_m), ("h", errors_h_m)):
        empty = len(errors) == 0
        out[f"rmse_{name}_m"] = None if empty else float(np.sqrt(np.mean(np.square(errors))))
        out[f"p95_{name}_m"] = None if empty else float(np.percentile(errors, 95))
        out[f"max_{name}_m"] = None if empty else float(np.max(errors))
    return out


def _inside_95(d: np.ndarray, cov: np.ndarray) -> tuple[bool | None, bool | None]:
    """(horizontal, 3D) inside the 95 % region of cov; None where cov has no such block."""
    h = v = None
    if np.all(np.isfinite(cov[:2, :2])):
        try:
            h = bool(d[:2] @ np.linalg.solve(cov[:2, :2], d[:2]) <= CHI2_95_2DOF)
        except np.linalg.LinAlgError:
            h = False                   # a singular covariance claims certainty it cannot have
    if np.all(np.isfinite(cov)):
        try:
            v = bool(d @ np.linalg.solve(cov, d) <= CHI2_95_3DOF)
        except np.linalg.LinAlgError:
            v = False
    return h, v


def evaluate_tracking(estimates: dict[int, NodeTrack], truth: dict[int, NodeTrack], align: bool = False,
                      max_gap_s: float = MAX_TRUTH_GAP_S) -> dict:
    """Per-node and overall figures (module docstring). Returns a JSON-ready report; node ids
    are the keys of report['nodes'] as decimal strings."""
    matched: list[tuple[int, float, np.ndarray, np.ndarray, np.ndarray | None]] = []
    skipped: dict[int, dict[str, int]] = {}
    for node in sorted(estimates):
        track = estimates[node]
        counts = skipped.setdefault(node, {"outside_truth": 0, "across_gap": 0, "no_truth": 0})
        if node not in truth:
            counts["no_truth"] = len(track.t_s)
            continue
        for k, t_s in enumerate(track.t_s):
            g = interpolate_truth(truth[node], float(t_s), max_gap_s)
            if isinstance(g, str):
                counts[g] += 1
                continue
            matched.append((node, float(t_s), track.p_m[k], g, None if track.cov_m2 is None else track.cov_m2[k]))
    report: dict = {"aligned": align, "max_gap_s": max_gap_s}
    rotation, translation = np.eye(3), np.zeros(3)
    if align:
        if len(matched) < 4:
            raise ValueError(f"align: {len(matched)} estimates match the truth in time; a 3D fit needs at least 4")
        rotation, translation = rigid_fit(np.array([m[2] for m in matched]), np.array([m[3] for m in matched]), dim=3)
        report["alignment"] = {"rotation": rotation.tolist(), "translation_m": translation.tolist(),
                               "reflected": bool(np.linalg.det(rotation) < 0)}
    nodes: dict[str, dict] = {}
    all_3d, all_h, all_in_h, all_in_3d = [], [], [], []
    for node in sorted(estimates):
        rows = [m for m in matched if m[0] == node]
        d = np.array([rotation @ m[2] + translation - m[3] for m in rows]).reshape(-1, 3)
        e3, eh = np.linalg.norm(d, axis=1), np.linalg.norm(d[:, :2], axis=1)
        entry = error_stats(e3, eh)
        entry.update(skipped[node])
        inside = [_inside_95(dk, rotation @ m[4] @ rotation.T) for dk, m in zip(d, rows) if m[4] is not None]
        in_h = [h for h, _ in inside if h is not None]
        in_3d = [v for _, v in inside if v is not None]
        entry["inside_95_h"] = float(np.mean(in_h)) if in_h else None
        entry["inside_95_3d"] = float(np.mean(in_3d)) if in_3d else None
        if len(rows):
            entry["from_s"], entry["to_s"] = rows[0][1], rows[-1][1]
        nodes[str(node)] = entry
        all_3d.append(e3)
        all_h.append(eh)
        all_in_h += in_h
        all_in_3d += in_3d
    overall = error_stats(np.concatenate(all_3d) if all_3d else np.zeros(0),
                          np.concatenate(all_h) if all_h else np.zeros(0))
    for key in ("outside_truth", "across_gap", "no_truth"):
        overall[key] = sum(s[key] for s in skipped.values())
    overall["inside_95_h"] = float(np.mean(all_in_h)) if all_in_h else None
    overall["inside_95_3d"] = float(np.mean(all_in_3d)) if all_in_3d else None
    overall["nodes"] = sum(1 for e in nodes.values() if e["points"])
    report["nodes"] = nodes
    report["overall"] = overall
    report["nodes_without_truth"] = [n for n in sorted(estimates) if n not in truth]
    report["truth_nodes_without_estimates"] = [n for n in sorted(truth) if n not in estimates]
    return report


def format_table(report: dict, label=str) -> str:
    """The per-node table cdro-eval-motion prints (3D and horizontal RMSE, 3D p95 and max, count,
    skipped) and an overall row."""
    def fmt(value) -> str:
        return "-" if value is None or (isinstance(value, float) and not math.isfinite(value)) else f"{value:.3f}"

    header = ("node", "n", "3D RMSE (m)", "horiz. RMSE (m)", "3D p95 (m)", "3D max (m)", "skipped")
    body = []
    for key, entry in [*report["nodes"].items(), ("all", report["overall"])]:
        skipped = entry["outside_truth"] + entry["across_gap"] + entry["no_truth"]
        body.append((label(int(key)) if key != "all" else "all", str(entry["points"]), fmt(entry["rmse_3d_m"]),
                     fmt(entry["rmse_h_m"]), fmt(entry["p95_3d_m"]), fmt(entry["max_3d_m"]), str(skipped)))
    widths = [max(len(row[k]) for row in [header, *body]) for k in range(len(header))]
    return "\n".join("  ".join(f"{cell:>{w}}" for cell, w in zip(row, widths)) for row in [header, *body])
