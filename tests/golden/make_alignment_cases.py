"""Writes tests/golden/alignment_cases.json: point sets and the rigid fit that maps one onto the
other, which the C++ fit (host/engine alignment.hpp, tests/engine/test_alignment.cpp) and the
Python fit (cdro_tools.evaluation.alignment, tests/tools/test_alignment_golden.py) must both give.

The exact cases are made by a known transform, and the file stores that transform, not a fit's
answer; the noisy cases store the Python fit's answer (checked here against the transform that
made them), which the C++ fit must reproduce. Collinear sets (two points among them) fit a
rotation and a reflection equally well; both fits then take the rotation, which these cases hold
them to, with a nearly collinear reflected set that must still give the reflection. Both fits are
planar only in the C++ (the Python one also fits 3D tracks), so there is no 3D case.

    .venv/bin/python tests/golden/make_alignment_cases.py > tests/golden/alignment_cases.json
"""
from __future__ import annotations

import json
import math
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "tools"))

from cdro_tools.evaluation.alignment import rigid_fit  # noqa: E402

SEED = 20261203


def rotation(angle_rad: float, reflected: bool = False) -> np.ndarray:
    r = np.array([[math.cos(angle_rad), -math.sin(angle_rad)], [math.sin(angle_rad), math.cos(angle_rad)]])
    return r @ np.diag([1.0, -1.0]) if reflected else r


def case(name, source, target, r, t, rmse):
    return {"name": name, "source_m": np.asarray(source).tolist(), "target_m": np.asarray(target).tolist(),
            "rotation": np.asarray(r).tolist(), "translation_m": np.asarray(t).tolist(), "rmse_m": float(rmse)}


def main() -> None:
    rng = np.random.Generator(np.random.PCG64(SEED))
    cases = []
    source = rng.uniform(-30.0, 30.0, (7, 2))
    for name, angle, reflected, shift in [("rotation", 0.7, False, (3.0, -2.0)),
                                          ("reflection", -2.1, True, (-12.5, 40.0)),
                                          ("half turn", math.pi, False, (0.0, 0.0))]:
        r, t = rotation(angle, reflected), np.array(shift)
        cases.append(case(name, source, source @ r.T + t, r, t, 0.0))
    for name, count, noise_m, reflected in [("noisy", 12, 0.1, False), ("noisy, reflected", 9, 0.5, True),
                                            ("noisy, far from the origin", 15, 0.05, False)]:
        points = rng.uniform(-40.0, 40.0, (count, 2)) + (1000.0 if "far" in name else 0.0)
        made_r, made_t = rotation(rng.uniform(-math.pi, math.pi), reflected), rng.uniform(-50.0, 50.0, 2)
        target = points @ made_r.T + made_t + rng.normal(0.0, noise_m, (count, 2))
        r, t = rigid_fit(points, target)
        assert np.allclose(r, made_r, atol=0.05) and np.linalg.det(r) * np.linalg.det(made_r) > 0, name
        rmse = math.sqrt(np.mean(np.sum((points @ r.T + t - target) ** 2, axis=1)))
        cases.append(case(name, points, target, r, t, rmse))
    point = rng.uniform(-10.0, 10.0, (1, 2))
    cases.append(case("one point", point, point + (4.0, -1.5), np.eye(2), (4.0, -1.5), 0.0))
    # Collinear: the answer is the rotation (det +1), whether the target was made by one or not.
    along = rng.uniform(-25.0, 25.0, 6)
    direction = np.array([math.cos(0.4), math.sin(0.4)])
    line = np.array([5.0, -3.0]) + along[:, None] * direction
    for name, points, angle, reflected, noise_m in [("two points", line[:2], 1.9, False, 0.0),
                                                    ("collinear", line, -0.8, False, 0.0),
                                                    ("collinear, mirrored", line, 2.5, True, 0.0),
                                                    ("collinear, noisy", line, 0.3, False, 0.2)]:
        made_r, made_t = rotation(angle, reflected), np.array([-7.0, 11.0])
        target = points @ made_r.T + made_t + rng.normal(0.0, noise_m, points.shape)
        r, t = rigid_fit(points, target)
        rmse = math.sqrt(np.mean(np.sum((points @ r.T + t - target) ** 2, axis=1)))
        assert np.linalg.det(r) > 0, name
        assert reflected or noise_m > 0 or np.allclose(r, made_r, atol=1e-12), name
        assert noise_m > 0 or rmse < 1e-12, name
        cases.append(case(name, points, target, r, t, rmse))
    # Nearly collinear (5 cm off a 50 m line), mirrored: the reflection fits better, and is found.
    points = line + rng.uniform(-0.05, 0.05, (len(line), 1)) * np.array([-direction[1], direction[0]])
    made_r, made_t = rotation(-0.6, True), np.array([2.0, 2.0])
    r, t = rigid_fit(points, points @ made_r.T + made_t)
    assert np.allclose(r, made_r, atol=1e-9) and np.linalg.det(r) < 0
    cases.append(case("nearly collinear, mirrored", points, points @ made_r.T + made_t, made_r, made_t, 0.0))
    json.dump({"seed": SEED, "cases": cases}, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
