// scaled_range_model.hpp: the range model of the movement stage, with the radios' calibration
// in the state. Real UWB ranges read long (antenna delays; the Plaza radios read about 7 %
// long), so a measured range between points a and b (planar positions, known height
// difference dz) is modelled as
//
//     h = s * d + b,    d = sqrt(|a - b|^2 + dz^2)
//
// with s the range scale (1 = calibrated) and b the offset (m). Jacobians, with u = (a - b)/d:
//     dh/da = s u^T,  dh/db_pos = -s u^T,  dh/ds = d,  dh/doffset = 1.
// Singular when a and b coincide and dz = 0: flagged, zero position Jacobians.
// Tested against numerical derivatives (tests/engine).
#pragma once

#include <Eigen/Core>

#include "cdro/engine/types.hpp"

namespace cdro::engine {

struct ScaledRangePrediction {
    double range_m = 0.0;    // m, h
    double distance_m = 0.0; // m, d (3D)
    Eigen::RowVector2d jacobian_a = Eigen::RowVector2d::Zero();
    Eigen::RowVector2d jacobian_b = Eigen::RowVector2d::Zero();
    double jacobian_scale = 0.0;  // dh/ds, m
    double jacobian_offset = 1.0; // dh/db
    bool singular = false;
};

ScaledRangePrediction predictScaledRange(const Vector2 &a_m, const Vector2 &b_m, double height_difference_m,
                                         double scale, double offset_m);

} // namespace cdro::engine
