"""The Python rigid fit against tests/golden/alignment_cases.json, the cases the C++ fit
(tests/engine/test_alignment.cpp) is held to as well: one fit in two languages."""
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


@pytest.mark.parametrize("case", [c for c in CASES if len(c["source_m"]) >= 3], ids=lambda c: c["name"])
def test_that_the_paper_algorithms_rmse_is_the_same_fit(case):
    assert paper_algorithm1.aligned_rmse_m(np.array(case["source_m"]), np.array(case["target_m"])) == pytest.approx(
        case["rmse_m"], abs=1e-9)
