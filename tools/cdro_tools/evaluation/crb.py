"""The anchor-free Cramer-Rao bound of a range network (../shared/docs/algorithm.md, "Frames of
reference and evaluation").

Each range on link (i, j) with Gaussian noise of std sigma adds u u^T / sigma^2 to the
Fisher blocks (i, i) and (j, j) and subtracts it from (i, j) and (j, i), with u the unit
vector between the true positions. Without anchors J is singular (rotation and translation
change no range), and the bound on the mean squared error left after a rigid alignment is
tr(J^+) / M, with J^+ the pseudo-inverse and M the number of nodes. This module returns the
RMSE bound sqrt(tr(J^+) / M).

sigma is the std of the range as the estimator sees it: for 2.5D data the horizontal range
after the height projection (for PLANT the 3D-derivative version, which weights each link by
(horizontal / 3D distance)^2, differs by 1e-4 m).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping

import numpy as np

RANK_TOLERANCE = 1e-9           # relative to the largest eigenvalue of J


@dataclasses.dataclass
class CrbResult:
    rmse_m: float               # sqrt(tr(J^+) / M)
    nodes: int                  # M
    entries: int                # ranges (or links) that entered J
    sigma_m: float
    rank: int                   # rank of J; 2M - 3 for a network that is rigid in the plane
    skipped: int = 0            # entries whose ends lack a true position, or coincide

    @property
    def rigid(self) -> bool:
        """Infinitesimally rigid: only the three rigid motions leave the ranges unchanged.
        Otherwise the pseudo-inverse ignores the flexible directions too and the bound is too
        optimistic."""
        return self.rank == 2 * self.nodes - 3


def fisher_information(positions_m: Mapping[int, np.ndarray], pairs: Iterable[tuple[int, int]],
                       sigma_m: float) -> tuple[np.ndarray, list[int], int, int]:
    """(J (2M x 2M, 1/m^2), node ids in J's order, entries used, entries skipped) for one
    entry per element of `pairs` (repeat a pair to count several ranges on a link). Nodes
    are those that appear in a used entry."""
    if not sigma_m > 0:
        raise ValueError(f"sigma must be above 0 (got {sigma_m} m)")
    used, skipped = [], 0
    for a, b in pairs:
        if a in positions_m and b in positions_m and np.linalg.norm(np.subtract(positions_m[a][:2],
                                                                                positions_m[b][:2])) > 0:
            used.append((a, b))
        else:
            skipped += 1
    ids = sorted({i for pair in used for i in pair})
    index = {node_id: k for k, node_id in enumerate(ids)}
    J = np.zeros((2 * len(ids), 2 * len(ids)))
    for a, b in used:
        u = np.subtract(positions_m[a][:2], positions_m[b][:2]).astype(float)
        u /= np.linalg.norm(u)
        block = np.outer(u, u) / sigma_m ** 2
        i, j = 2 * index[a], 2 * index[b]
        J[i:i + 2, i:i + 2] += block
        J[j:j + 2, j:j + 2] += block
        J[i:i + 2, j:j + 2] -= block
        J[j:j + 2, i:i + 2] -= block
    return J, ids, len(used), skipped


def anchor_free_crb(positions_m: Mapping[int, np.ndarray], pairs: Iterable[tuple[int, int]],
                    sigma_m: float) -> CrbResult:
    """The RMSE bound of an anchor-free, rigidly aligned map (see the module doc)."""
    J, ids, used, skipped = fisher_information(positions_m, pairs, sigma_m)
    if not ids:
        return CrbResult(float("nan"), 0, 0, sigma_m, 0, skipped)
    values = np.linalg.eigvalsh(J)
    rank = int((values > RANK_TOLERANCE * values.max()).sum())
    pinv = np.linalg.pinv(J, rcond=RANK_TOLERANCE, hermitian=True)
    return CrbResult(math.sqrt(max(float(np.trace(pinv)), 0.0) / len(ids)), len(ids), used, sigma_m, rank, skipped)
