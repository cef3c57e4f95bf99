"""Convergence over the ranges processed, from the engine's trace (cdro-hostd --trace-csv).

A trace is a list of snapshots (ranges processed so far, id -> estimate), one after every
K-th range. Time is counted in ranges, not seconds, so that runs at different speeds, or
replays, compare directly.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from .alignment import align
from .inputs import NodeEstimate

MIN_ALIGNED_NODES = 3           # two nodes always align almost perfectly: no information


def convergence_ranges(snapshots: list[tuple[int, dict[int, NodeEstimate]]]) -> dict[int, int | None]:
    """Per node: the first `ranges` value from which the node is converged in that snapshot
    and every later one, or None ("never"). A snapshot in which a node is missing counts as
    not converged for it (it is not even placed there)."""
    ids = sorted({i for _, snapshot in snapshots for i in snapshot})
    out: dict[int, int | None] = {}
    for node_id in ids:
        since = None
        for count, snapshot in snapshots:
            estimate = snapshot.get(node_id)
            if estimate is not None and estimate.converged:
                if since is None:
                    since = count
            else:
                since = None
        out[node_id] = since
    return out


def all_converged_at(times: Mapping[int, int | None]) -> int | None:
    """When the last node converged for good; None if one never did (or there are none)."""
    if not times or any(t is None for t in times.values()):
        return None
    return max(times.values())


@dataclasses.dataclass
class RmsePoint:
    ranges: int
    rmse_m: float
    nodes: int                  # nodes aligned (estimate and truth)


def rmse_over_ranges(snapshots: list[tuple[int, dict[int, NodeEstimate]]], truth_m: Mapping[int, np.ndarray],
                     min_nodes: int = MIN_ALIGNED_NODES) -> list[RmsePoint]:
    """The aligned RMSE at every snapshot, each aligned on its own over the nodes present
    (snapshots with fewer than min_nodes nodes with truth are left out)."""
    out = []
    for count, snapshot in snapshots:
        if sum(1 for i in snapshot if i in truth_m) < min_nodes:
            continue
        alignment = align({i: e.xy_m for i, e in snapshot.items()}, truth_m)
        out.append(RmsePoint(count, alignment.rmse_m, alignment.nodes))
    return out
