// range_model.hpp: the measurement model of every range in the engine, the planar distance
// between a point and a centre:
//
//     h(x, c) = |x - c|
//     dh/dx   =  (x - c)^T / |x - c|  =  u^T      (u: unit vector from c towards x)
//     dh/dc   = -u^T
//
// The Jacobian follows from d|v|/dv = v^T / |v|. It is undefined where x = c; below
// kSingularDistanceM the prediction is flagged singular and carries a zero Jacobian, so that an
// EKF step or a Gauss-Newton step simply takes no information from it instead of dividing by
// zero (compare Bitcraze mm_distance.c and GTSAM RangeFactor). Tested against a numerical
// derivative in tests/engine/test_range_model.cpp.
#pragma once

#include <Eigen/Core>

#include "cdro/engine/types.hpp"

namespace cdro::engine {

constexpr double kSingularDistanceM = 1e-9; // m

struct RangePrediction {
    double range_m = 0.0;                                            // m, h(x, c)
    Eigen::RowVector2d jacobian_point = Eigen::RowVector2d::Zero();  // dh/dx, 1/1 (m per m)
    Eigen::RowVector2d jacobian_center = Eigen::RowVector2d::Zero(); // dh/dc
    bool singular = false;                                           // x and c coincide
};

RangePrediction predictRange(const Vector2 &point_m, const Vector2 &center_m);

// A 3D range between nodes at heights differing by dz, projected to the plane: sqrt(r^2 - dz^2).
// A range shorter than |dz| cannot be projected; it gives 0 and *clamped = true.
double projectRange(double range_m, double height_difference_m, bool *clamped);

} // namespace cdro::engine
