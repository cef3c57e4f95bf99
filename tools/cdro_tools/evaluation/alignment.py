"""Rigid alignment of an anchor-free map to ground truth (docs/tools.md, cdro-eval).

An anchor-free solution is defined up to rotation, translation and, in 2D, reflection; so
every comparison with truth first fits R (orthogonal: a rotation or a reflection) and t to
minimise sum_i |R p_i + t - g_i|^2 over the nodes that have both, with no scale (a wrong
scale is an error of the map, not of its frame). The RMSE is then
sqrt(mean_i |R p_i + t - g_i|^2). This module is the one implementation in Python (cdro-plot,
cdro-eval, paper_algorithm1 and the firmware-in-the-loop tests use it); the engine's C++ fit
(alignment.hpp) is held to the same answers by tests/golden/alignment_cases.json.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np


def rigid_fit(source: np.ndarray, target: np.ndarray, dim: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """R (dim x dim, orthogonal: rotation or reflection) and t minimising sum |R s_i + t - g_i|^2.

    The orthogonal Procrustes solution: with H = sum (s_i - s_mean)(g_i - g_mean)^T = U S V^T,
    R = V U^T. Not forcing det(R) = +1 is what allows the reflection (a mirror image fits
    ranges as well in 3D as in 2D). One point fixes only the translation; no point gives the
    identity. dim = 3 is for tracks of moving nodes in 3D (evaluation.tracking); the maps are 2D.
    """
    source = np.asarray(source, dtype=float).reshape(-1, dim)
    target = np.asarray(target, dtype=float).reshape(-1, dim)
    if len(source) != len(target):
        raise ValueError(f"rigid_fit: {len(source)} source points but {len(target)} target points")
    if len(source) == 0:
        return np.eye(dim), np.zeros(dim)
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    if len(source) == 1:
        return np.eye(2), target_mean - source_mean
    u, _, vt = np.linalg.svd((source - source_mean).T @ (target - target_mean))
    rotation = vt.T @ u.T
    return rotation, target_mean - rotation @ source_mean


def rmse(errors_m: Mapping[int, float] | Sequence[float]) -> float:
    """sqrt(mean e^2) of per-node errors (m); nan when there are none."""
    values = list(errors_m.values()) if isinstance(errors_m, Mapping) else list(errors_m)
    return math.sqrt(sum(e * e for e in values) / len(values)) if values else float("nan")


@dataclasses.dataclass
class Alignment:
    """The rigid fit of one map to the truth, and what it leaves."""
    rotation: np.ndarray                    # 2x2, det +1 (rotation) or -1 (reflection)
    translation_m: np.ndarray               # (2,)
    errors_m: dict[int, float]              # per node with both an estimate and a truth
    rmse_m: float

    @property
    def reflected(self) -> bool:
        return bool(np.linalg.det(self.rotation) < 0)

    @property
    def nodes(self) -> int:
        return len(self.errors_m)

    def apply(self, xy_m) -> np.ndarray:
        """A point (or an (n, 2) array of points) of the estimate's frame, in the truth's frame."""
        return np.asarray(xy_m, dtype=float) @ self.rotation.T + self.translation_m

    def rotate_covariance(self, cov_m2: np.ndarray) -> np.ndarray:
        """A 2x2 covariance of the estimate's frame, in the truth's frame: R C R^T (t does not
        change a covariance)."""
        return self.rotation @ np.asarray(cov_m2, dtype=float) @ self.rotation.T


def align(estimates_m: Mapping[int, Sequence[float]], truth_m: Mapping[int, Sequence[float]]) -> Alignment:
    """Fit estimates (id -> (x, y) in the engine's frame) to truth (id -> (x, y), extra
    coordinates ignored) over the ids present in both, and give the per-node errors."""
    ids = sorted(i for i in estimates_m if i in truth_m)
    source = np.array([estimates_m[i][:2] for i in ids], dtype=float).reshape(-1, 2)
    target = np.array([truth_m[i][:2] for i in ids], dtype=float).reshape(-1, 2)
    rotation, translation = rigid_fit(source, target)
    moved = source @ rotation.T + translation
    errors = {i: float(np.linalg.norm(m - g)) for i, m, g in zip(ids, moved, target)}
    return Alignment(rotation, translation, errors, rmse(errors))
