"""The Python rigid fit against tests/golden/alignment_cases.json, the cases the C++ fit
(tests/engine/test_alignment.cpp) is held to as well: one fit in two languages. Collinear sets,
which a rotation and a reflection fit alike, get the rotation in both."""
from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

from cdro_tools.evaluation import paper_algorithm1
from cdro_tools.evaluation.alignment import align, rigid_fit

CASES = json.loads((pathlib.Path(__file__).resolve().parents[1] / "golden" / "alignment_cases.json")
                   .read_text())["cases"]


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_that_the_fit_gives_the_golden_transform(case):
    # Act
    rotation, translation = rigid_fit(np.array(case["source_m"]), np.array(case["target_m"]))
    fit = align(dict(enumerate(case["source_m"])), dict(enumerate(case["target_m"])))

    # Assert
    assert np.allclose(rotation, case["rotation"], rtol=0.0, atol=1e-9)
    assert np.allclose(translation, case["translation_m"], rtol=0.0, atol=1e-9)
    assert fit.rmse_m == pytest.approx(case["rmse_m"], abs=1e-9)
    assert fit.reflected == (np.linalg.det(np.array(case["rotation"])) < 0)
    assert (np.linalg.det(rotation) < 0) == fit.reflected


@pytest.mark.parametrize("case", [c for c in CASES if len(c["source_m"]) >= 3], ids=lambda c: c["name"])
def test_that_the_paper_algorithms_rmse_is_the_same_fit(case):
    assert paper_algorithm1.aligned_rmse_m(np.array(case["source_m"]), np.array(case["target_m"])) == pytest.approx(
        case["rmse_m"], abs=1e-9)


def test_that_one_point_in_3d_gives_the_shift():
    # Act
    rotation, translation = rigid_fit(np.array([[1.0, 2.0, 3.0]]), np.array([[2.0, 0.0, 3.5]]), dim=3)

    # Assert
    assert np.array_equal(rotation, np.eye(3))
    assert np.allclose(translation, [1.0, -2.0, 0.5])


def test_that_a_coplanar_track_in_3d_gets_the_rotation():
    # Fixture: a track at one height, turned about z; its mirror image across its own plane
    # fits as well, and the rule takes the rotation
    rng = np.random.Generator(np.random.PCG64(7))
    track = np.column_stack([rng.uniform(-5.0, 5.0, (20, 2)), np.full(20, 1.2)])
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

    # Act
    rotation, translation = rigid_fit(track, track @ turn.T + [1.0, 2.0, 0.0], dim=3)

    # Assert
    assert np.allclose(rotation, turn, atol=1e-12)
    assert np.allclose(translation, [1.0, 2.0, 0.0], atol=1e-12)
