"""Views of a map that need no truth (cdro-plot --residuals, --convergence; the live map shows
the same): how well each link agrees with the map, and how the map settled over time.

Residual of a link = the median of its ranges (both directions; projected onto the plane where
both heights are known, as the engine does) minus the distance between its two nodes' estimates.
Distances do not depend on the map's frame, so the estimates are used as they are. A link that
reads long (no line of sight) has a positive residual; a node placed in the wrong spot shows as
residuals of one sign on all its links. The colour bands are the live map's.

Convergence: per node, the 2-sigma radius (twice the square root of the covariance's largest
eigenvalue, the 2-sigma ellipse's major half-axis) over time, and the number of converged nodes
over time (a node counts from its latest estimate at or before that time).
"""
from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np

RESIDUAL_WARN_M = 0.15          # m; |residual| below: fine (green), the live map's bands
RESIDUAL_BAD_M = 0.5            # m; at or above: red (NLOS or a misplaced node)
RESIDUAL_COLOURS = {"ok": "#2e8540", "warn": "#c98a00", "bad": "#b52b27"}


@dataclasses.dataclass
class LinkResidual:
    a: int
    b: int
    ranges: int                     # ranges on the link (both directions)
    range_median_m: float
    fitted_distance_m: float
    residual_m: float

    @property
    def band(self) -> str:
        r = abs(self.residual_m)
        return "ok" if r < RESIDUAL_WARN_M else "warn" if r < RESIDUAL_BAD_M else "bad"


def link_residuals(link_ranges_m: Mapping[tuple[int, int], Sequence[float]],
                   positions_m: Mapping[int, Sequence[float]]) -> tuple[list[LinkResidual], int]:
    """Residuals of the links whose two ends have an estimate, largest |residual| first; and how
    many links were left out for want of an estimate."""
    out, left_out = [], 0
    for (a, b), ranges in sorted(link_ranges_m.items()):
        if a not in positions_m or b not in positions_m or not ranges:
            left_out += 1
            continue
        median = float(np.median(np.asarray(ranges, dtype=float)))
        fitted = float(math.dist(positions_m[a], positions_m[b]))
        out.append(LinkResidual(a, b, len(ranges), median, fitted, median - fitted))
    out.sort(key=lambda r: (-abs(r.residual_m), r.a, r.b))
    return out, left_out


def two_sigma_radius_m(cov_m2) -> float:
    values = np.linalg.eigvalsh((np.asarray(cov_m2, dtype=float) + np.asarray(cov_m2, dtype=float).T) / 2.0)
    return 2.0 * math.sqrt(max(float(values[-1]), 0.0))


@dataclasses.dataclass
class Sample:
    t: float                        # s, or ranges processed (a trace without times)
    cov_m2: np.ndarray
    converged: bool


def converged_counts(series: Mapping[int, Sequence[Sample]]) -> list[tuple[float, int]]:
    """(t, converged nodes) at every time any node has a sample."""
    times = sorted({s.t for samples in series.values() for s in samples})
    keyed = {i: ([s.t for s in samples], samples) for i, samples in series.items()}
    out = []
    for t in times:
        count = 0
        for ts, samples in keyed.values():
            k = bisect.bisect_right(ts, t)
            count += 1 if k and samples[k - 1].converged else 0
        out.append((t, count))
    return out


def plot_residuals(path: str, residuals: list[LinkResidual], positions_m: Mapping[int, Sequence[float]],
                   title: str, label) -> None:
    """Left: the map with each link coloured by its residual's band; right: the residuals as
    bars, largest first."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    fig, (map_ax, bar_ax) = plt.subplots(1, 2, figsize=(12, 6), dpi=100, gridspec_kw={"width_ratios": [1.1, 1]})
    try:
        for r in sorted(residuals, key=lambda r: abs(r.residual_m)):   # the worst drawn on top
            (xa, ya), (xb, yb) = positions_m[r.a], positions_m[r.b]
            map_ax.plot([xa, xb], [ya, yb], color=RESIDUAL_COLOURS[r.band],
                        linewidth={"ok": 1.0, "warn": 2.0, "bad": 3.0}[r.band], zorder=2)
        ids = sorted({i for r in residuals for i in (r.a, r.b)})
        xy = np.array([positions_m[i] for i in ids]) if ids else np.zeros((0, 2))
        map_ax.scatter(xy[:, 0], xy[:, 1], s=30, color="black", zorder=3)
        for i, p in zip(ids, xy):
            map_ax.annotate(label(i), p, textcoords="offset points", xytext=(4, 4), fontsize=8)
        map_ax.set_aspect("equal", adjustable="datalim")
        map_ax.set_xlabel("x (m)")
        map_ax.set_ylabel("y (m)")
        map_ax.grid(True, linewidth=0.3)
        map_ax.legend(handles=[Line2D([], [], color=RESIDUAL_COLOURS["ok"], label=f"|residual| < {RESIDUAL_WARN_M} m"),
                               Line2D([], [], color=RESIDUAL_COLOURS["warn"], linewidth=2,
                                      label=f"|residual| < {RESIDUAL_BAD_M} m"),
                               Line2D([], [], color=RESIDUAL_COLOURS["bad"], linewidth=3,
                                      label=f"|residual| >= {RESIDUAL_BAD_M} m")], fontsize=8, loc="best")
        shown = residuals[:40]                                          # the 40 largest
        names = [f"{label(r.a)}-{label(r.b)}" for r in shown]
        bar_ax.barh(range(len(shown)), [r.residual_m for r in shown],
                    color=[RESIDUAL_COLOURS[r.band] for r in shown])
        bar_ax.set_yticks(range(len(shown)), names, fontsize=7)
        bar_ax.invert_yaxis()
        bar_ax.axvline(0.0, color="black", linewidth=0.8)
        for edge in (-RESIDUAL_BAD_M, -RESIDUAL_WARN_M, RESIDUAL_WARN_M, RESIDUAL_BAD_M):
            bar_ax.axvline(edge, color="0.6", linewidth=0.6, linestyle="--")
        bar_ax.set_xlabel("median range - distance on the map (m)")
        bar_ax.grid(True, axis="x", linewidth=0.3)
        more = f" (the {len(shown)} largest of {len(residuals)})" if len(residuals) > len(shown) else ""
        bar_ax.set_title("link residuals" + more, fontsize=10)
        map_ax.set_title(title, fontsize=10)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)


def plot_convergence(path: str, series: Mapping[int, Sequence[Sample]], counts: list[tuple[float, int]],
                     xlabel: str, title: str, label) -> None:
    """Top: every node's 2-sigma radius (log scale); bottom: converged nodes, both over time."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (radius_ax, count_ax) = plt.subplots(2, 1, figsize=(8, 6), dpi=100, sharex=True,
                                              gridspec_kw={"height_ratios": [2, 1]})
    try:
        for node_id, samples in sorted(series.items()):
            radius_ax.plot([s.t for s in samples], [max(two_sigma_radius_m(s.cov_m2), 1e-4) for s in samples],
                           linewidth=1.0, label=label(node_id))
        radius_ax.set_yscale("log")
        radius_ax.set_ylabel("2-sigma radius (m)")
        radius_ax.grid(True, which="both", linewidth=0.3)
        if len(series) <= 20:
            radius_ax.legend(fontsize=7, ncol=2, loc="upper right")
        radius_ax.set_title(title, fontsize=10)
        count_ax.step([t for t, _ in counts], [c for _, c in counts], where="post", color="tab:green")
        count_ax.set_ylabel("converged nodes")
        count_ax.set_ylim(0, max(len(series), 1) + 0.5)
        count_ax.set_xlabel(xlabel)
        count_ax.grid(True, linewidth=0.3)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
