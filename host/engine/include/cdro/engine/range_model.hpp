// range_model.hpp: the measurement model of every range in the engine. A range between points a
// and b (planar positions, their heights differing by dz) is modelled as
//
//     h = s * d + b,    d = sqrt(|a - b|^2 + dz^2)
//
// with s the range scale and b the offset (m): the movement stage keeps the radios' calibration in
// its state (real UWB ranges read long: antenna delays; the Plaza radios read about 7 % long);
// stage 1 uses the plain planar distance (dz = 0, s = 1, b = 0: h = |a - b|, to the bit). With
// u = (a - b) / d, from d|v|/dv = v^T / |v|:
//
//     dh/da = s u^T,   dh/db = -s u^T,   dh/ds = d,   dh/db_offset = 1.
//
// The Jacobian is undefined where d = 0 (a = b and dz = 0); below kSingularDistanceM the
// prediction is flagged singular and carries zero position Jacobians, so that an EKF step or a
// Gauss-Newton step simply takes no information from it instead of dividing by zero (compare
// Bitcraze mm_distance.c and GTSAM RangeFactor). Tested against numerical derivatives in
// tests/engine/test_range_model.cpp and test_movement_models.cpp.
#pragma once

#include <Eigen/Core>

#include "cdro/engine/types.hpp"

namespace cdro::engine {

constexpr double kSingularDistanceM = 1e-9; // m

struct RangePrediction {
    double range_m = 0.0;                                            // m, h
    double distance_m = 0.0;                                         // m, d (3D when dz is given)
    Eigen::RowVector2d jacobian_point = Eigen::RowVector2d::Zero();  // dh/da, 1/1 (m per m)
    Eigen::RowVector2d jacobian_center = Eigen::RowVector2d::Zero(); // dh/db
    double jacobian_scale = 0.0;                                     // dh/ds, m
    double jacobian_offset = 1.0;                                    // dh/db_offset
    bool singular = false;                                           // d below kSingularDistanceM
};

RangePrediction predictRange(const Vector2 &point_m, const Vector2 &center_m, double height_difference_m = 0.0,
                             double scale = 1.0, double offset_m = 0.0);

// The same between two points of 3D state (nodes of unknown height: motion_track_3d.hpp,
// moving_calibration.hpp), with s = 1 and b = 0: h = |a - b|, dh/da = u^T, dh/db = -u^T.
struct RangePrediction3 {
    double range_m = 0.0;                                           // m, h
    Eigen::RowVector3d jacobian_point = Eigen::RowVector3d::Zero(); // dh/da; dh/db is its negative
    bool singular = false;                                          // h below kSingularDistanceM
};

RangePrediction3 predictRange(const Vector3 &point_m, const Vector3 &center_m);

// A 3D range between nodes at heights differing by dz, projected to the plane: sqrt(r^2 - dz^2).
// A range shorter than |dz| cannot be projected; it gives 0 and *clamped = true.
double projectRange(double range_m, double height_difference_m, bool *clamped);

} // namespace cdro::engine
