"""Map drawing shared by cdro-plot and cdro-eval (matplotlib, headless).

Both tools draw the same things the same way: truth as hollow circles, estimates as dots
with their 2-sigma ellipses and ids, ranged links as thin grey lines. matplotlib is imported
inside the functions so that reading and computing never pay for it.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

MAP_SIZE_IN = (8, 7)                # 800 x 700 px at DPI
CURVE_SIZE_IN = (8, 4)              # 800 x 400 px
DPI = 100
ELLIPSE_SIGMAS = 2.0


def node_label(node_id: int) -> str:
    """Pozyx ids (16-bit, 0x6001...) in hex as the firmware prints them; small dataset ids
    (PLANT's 1..38) as they are written in the files."""
    return f"0x{node_id:04X}" if node_id >= 0x1000 else str(node_id)


def new_figure(size_in=MAP_SIZE_IN):
    import matplotlib
    matplotlib.use("Agg")          # no display: the tools run on servers and in CI
    import matplotlib.pyplot as plt
    return plt.subplots(figsize=size_in, dpi=DPI)


def covariance_ellipse(ax, centre_m, cov_m2, sigmas: float = ELLIPSE_SIGMAS, **style) -> None:
    """The `sigmas`-sigma ellipse of a 2x2 covariance (m^2) at centre_m."""
    from matplotlib.patches import Ellipse
    cov = np.asarray(cov_m2, dtype=float)
    values, vectors = np.linalg.eigh((cov + cov.T) / 2.0)
    values = np.clip(values, 0.0, None)     # rounding can make a flat covariance slightly negative
    angle_deg = math.degrees(math.atan2(vectors[1, 1], vectors[0, 1]))
    width_m, height_m = 2 * sigmas * math.sqrt(values[1]), 2 * sigmas * math.sqrt(values[0])
    ax.add_patch(Ellipse(tuple(centre_m), width_m, height_m, angle=angle_deg, fill=False, **style))


def draw_links(ax, links: Iterable[tuple[int, int]], positions_m: Mapping[int, np.ndarray], **style) -> int:
    """A line per link whose two ends have a position; returns how many were drawn."""
    style = {"color": "0.85", "linewidth": 0.8, "zorder": 1, **style}
    drawn = 0
    for a, b in sorted(links):
        if a in positions_m and b in positions_m:
            ax.plot(*zip(positions_m[a], positions_m[b]), **style)
            drawn += 1
    return drawn


def draw_truth(ax, xy_m, label: str | None = "truth") -> None:
    xy = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    if len(xy):
        ax.scatter(xy[:, 0], xy[:, 1], s=90, facecolors="none", edgecolors="black", zorder=4, label=label)


def draw_estimates(ax, positions_m: Mapping[int, np.ndarray], covariances_m2: Mapping[int, np.ndarray] | None,
                   label: str, color: str = "tab:blue", marker: str = "o", ids: bool = True) -> None:
    """Dots (with ellipses when covariances are given, and id labels) for a set of nodes."""
    first = True
    for node_id in sorted(positions_m):
        p = positions_m[node_id]
        if covariances_m2 is not None and node_id in covariances_m2:
            covariance_ellipse(ax, p, covariances_m2[node_id], edgecolor=color, linewidth=0.8, zorder=5)
        ax.scatter([p[0]], [p[1]], s=20, color=color, marker=marker, zorder=6, label=label if first else None)
        first = False
    if ids:
        draw_ids(ax, positions_m)


def draw_ids(ax, positions_m: Mapping[int, np.ndarray]) -> None:
    for node_id, p in sorted(positions_m.items()):
        ax.annotate(node_label(node_id), p, textcoords="offset points", xytext=(5, 5), fontsize=8)


def finish(fig, ax, path: str, title: str, xlabel: str = "x (m)", ylabel: str = "y (m)", equal: bool = True) -> None:
    """Axes, grid, legend; write the PNG and free the figure."""
    import matplotlib.pyplot as plt
    if equal:
        ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, linewidth=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    try:
        fig.savefig(path)
    finally:
        plt.close(fig)
