"""Does "converged" keep its promise? The nodes an estimate calls converged, judged on their own.

The converged nodes are fitted to the truth by themselves (a rigid fit, alignment.py), so that
the nodes the engine does not vouch for cannot hide or cause their errors. Then:
- wrong: the converged nodes more than WRONG_M from the truth (the promise is that there are none);
- coverage: the share whose truth lies inside the reported 2-sigma ellipse (Mahalanobis distance
  squared <= 4; an exact Gaussian covers 86.5 %, so an honest, slightly cautious covariance covers
  a little more and an optimistic one less);
- NEES: the mean of the squared Mahalanobis distances over the nodes (2 for an exact covariance
  in 2D; larger is optimistic).
The covariance is turned into the truth's frame with the fit's rotation (or reflection).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from .alignment import Alignment

WRONG_M = 1.0                 # m: what "converged" promises at most
TWO_SIGMA_SQUARED = 4.0       # Mahalanobis distance squared of the 2-sigma ellipse


@dataclasses.dataclass
class Honesty:
    wrong: list[int]          # ids of converged nodes more than WRONG_M off
    coverage: float           # share of converged nodes inside their 2-sigma ellipse (0..1)
    nees: float               # mean squared Mahalanobis distance


def mahalanobis_squared(error_m: np.ndarray, covariance_m2: np.ndarray) -> float:
    """e^T C^-1 e; infinite when C is singular and e is not in its range."""
    try:
        return float(error_m @ np.linalg.solve(covariance_m2, error_m))
    except np.linalg.LinAlgError:
        return float("inf") if float(np.linalg.norm(error_m)) > 0 else 0.0


def converged_honesty(converged: Mapping[int, object], alignment: Alignment,
                      truth_xy_m: Mapping[int, np.ndarray]) -> Honesty:
    """`converged`: id -> an estimate with `xy_m` and `cov_m2` (inputs.NodeEstimate);
    `alignment`: the fit of exactly these nodes to `truth_xy_m` (id -> (x, y), m)."""
    wrong, inside, distances = [], 0, []
    for i in sorted(alignment.errors_m):
        if alignment.errors_m[i] > WRONG_M:
            wrong.append(i)
        error_m = alignment.apply(converged[i].xy_m) - np.asarray(truth_xy_m[i][:2], dtype=float)
        d2 = mahalanobis_squared(error_m, alignment.rotate_covariance(converged[i].cov_m2))
        distances.append(d2)
        inside += d2 <= TWO_SIGMA_SQUARED
    n = len(distances)
    return Honesty(wrong, inside / n if n else float("nan"), float(np.mean(distances)) if n else float("nan"))
