"""Fixed-point conversions, the Python twin of common/include/cdro/fixed.h (same rounding:
half away from zero, saturating; NaN gives 0)."""
from __future__ import annotations

import math


def _round_clamp(value: float, lo: float, hi: float) -> int:
    if math.isnan(value):
        return 0
    value = math.floor(value + 0.5) if value >= 0.0 else math.ceil(value - 0.5)
    return int(min(max(value, lo), hi))


def mm_from_m(metres: float) -> int:
    return _round_clamp(metres * 1000.0, -2147483648.0, 2147483647.0)


def mm_to_m(millimetres: int) -> float:
    return millimetres / 1000.0


def um_from_m(metres: float) -> int:
    return _round_clamp(metres * 1.0e6, 0.0, 4294967295.0)


def um_to_m(micrometres: int) -> float:
    return micrometres / 1.0e6


def q15_from(value: float) -> int:
    return _round_clamp(value * 32767.0, -32767.0, 32767.0)


def q15_to(q15: int) -> float:
    return q15 / 32767.0


def q16_from(value: float) -> int:
    return _round_clamp(value * 65535.0, 0.0, 65535.0)


def q16_to(q16: int) -> float:
    return q16 / 65535.0


def covariance_from(var_x_m2: float, cov_xy_m2: float, var_y_m2: float) -> tuple[int, int, int]:
    """(std_x_um, std_y_um, correlation_q15) of a 2x2 covariance in m^2."""
    def non_negative(v: float) -> float:
        return v if v > 0.0 and math.isfinite(v) else 0.0
    std_x = math.sqrt(non_negative(var_x_m2))
    std_y = math.sqrt(non_negative(var_y_m2))
    denominator = std_x * std_y
    correlation = q15_from(cov_xy_m2 / denominator) if denominator > 0.0 else 0
    return um_from_m(std_x), um_from_m(std_y), correlation


def covariance_to(std_x_um: int, std_y_um: int, correlation_q15: int) -> tuple[float, float, float]:
    """(var_x_m2, cov_xy_m2, var_y_m2)."""
    std_x = um_to_m(std_x_um)
    std_y = um_to_m(std_y_um)
    return std_x * std_x, q15_to(correlation_q15) * std_x * std_y, std_y * std_y
