"""The helpers the firmware-in-the-loop tests share with the coming cdro-hostd test: the rigid
alignment of a range-only map to the truth, and the truth file's interpolation."""
from __future__ import annotations

import math
import random

import pytest

from fil_support import Truth, align_2d


def test_alignment_recovers_rotation_translation_and_reflection():
    seed = 20261122
    print(f"seed {seed}")
    rng = random.Random(seed)
    truth = {i: (rng.uniform(0, 10), rng.uniform(0, 8)) for i in range(1, 8)}
    for reflect in (False, True):
        angle, tx, ty = rng.uniform(-math.pi, math.pi), rng.uniform(-5, 5), rng.uniform(-5, 5)
        c, s = math.cos(angle), math.sin(angle)
        mapped = {}
        for i, (x, y) in truth.items():
            y = -y if reflect else y
            mapped[i] = (c * x - s * y + tx, s * x + c * y + ty)
        transform, rms = align_2d(mapped, truth)
        assert rms == pytest.approx(0.0, abs=1e-9)
        for i in truth:
            assert math.dist(transform(mapped[i]), truth[i]) == pytest.approx(0.0, abs=1e-9)
    # Noise shows in the residual: 5 cm per coordinate gives an RMS of about 7 cm.
    noisy = {i: (x + rng.gauss(0, 0.05), y + rng.gauss(0, 0.05)) for i, (x, y) in truth.items()}
    _, rms = align_2d(noisy, truth)
    assert 0.01 < rms < 0.15
    with pytest.raises(AssertionError):
        align_2d({1: (0, 0), 2: (1, 0)}, truth)


def test_truth_interpolates_between_samples(tmp_path):
    path = tmp_path / "truth.csv"
    path.write_text("t,id,x,y,z\n0.0,1,0,0,1\n0.0,2,3,4,1\n1.0,1,2,0,1\n1.0,2,3,4,1\n")
    truth = Truth(path)
    assert truth.position(1, 0.25) == pytest.approx((0.5, 0.0, 1.0))
    assert truth.position(1, 5.0) == pytest.approx((2.0, 0.0, 1.0))
    assert truth.distance(1, 2, 0.0) == pytest.approx(5.0)
