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


# A reflection is taken only when it fits better than the rotation by more than this share of the
# points' spread: on a collinear set (in 3D, a coplanar one) both fit exactly as well, and which
# one rounding favours differs between LAPACK and Eigen. The engine's fitRigid keeps the same rule.
REFLECTION_TIE = 1e-9


def _proper_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation (det +1) and t minimising sum |R s_i + t - g_i|^2 (Kabsch): with
    H = sum (s_i - s_mean)(g_i - g_mean)^T = U S V^T, R = V diag(1, .., det(V U^T)) U^T."""
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - source_mean).T @ (target - target_mean))
    correction = np.ones(source.shape[1])
    if np.linalg.det(vt.T @ u.T) < 0.0:
        correction[-1] = -1.0
    rotation = vt.T @ np.diag(correction) @ u.T
    return rotation, target_mean - rotation @ source_mean


def _rms_m(source: np.ndarray, target: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> float:
    return math.sqrt(float(np.mean(np.sum((source @ rotation.T + translation - target) ** 2, axis=1))))


def _spread_m(points: np.ndarray) -> float:
    """sqrt(mean |p_i - p_mean|^2): how far the points lie from their centre."""
    return math.sqrt(float(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))


def rigid_fit(source: np.ndarray, target: np.ndarray, dim: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """R (dim x dim, orthogonal: rotation or reflection) and t minimising sum |R s_i + t - g_i|^2.

    The best rotation (Kabsch) and the best reflection (the rotation of the mirrored source,
    mirror = diag(1, .., -1)), and the one that fits better; the reflection only when it is
    better by more than rounding (REFLECTION_TIE), so that a collinear set gets the rotation. This
    is the engine's fitRigid (alignment.hpp) step for step; tests/golden/alignment_cases.json holds
    the two to the same answers. One point fixes only the translation; no point gives the
    identity. dim = 3 is for tracks of moving nodes in 3D (evaluation.tracking); the maps are 2D.
    """
    source = np.asarray(source, dtype=float).reshape(-1, dim)
    target = np.asarray(target, dtype=float).reshape(-1, dim)
    if len(source) != len(target):
        raise ValueError(f"rigid_fit: {len(source)} source points but {len(target)} target points")
    if len(source) == 0:
        return np.eye(dim), np.zeros(dim)
    if len(source) == 1:
        return np.eye(dim), target[0] - source[0]
    proper = _proper_fit(source, target)
    mirror = np.diag([1.0] * (dim - 1) + [-1.0])
    rotation, translation = _proper_fit(source @ mirror, target)
    mirrored = (rotation @ mirror, translation)
    tie_m = REFLECTION_TIE * (_spread_m(source) + _spread_m(target))
    if _rms_m(source, target, *mirrored) < _rms_m(source, target, *proper) - tie_m:
        return mirrored
    return proper


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
