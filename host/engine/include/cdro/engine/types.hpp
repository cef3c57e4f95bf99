// types.hpp: the engine's basic types. Positions are planar (x, y) in metres in the engine's
// frame; covariances are 2x2 in m^2. Node ids are Pozyx 16-bit network ids.
#pragma once

#include <cmath>
#include <cstdint>

#include <Eigen/Core>

namespace cdro::engine {

using NodeId = uint16_t;
using Vector2 = Eigen::Vector2d; // m
using Matrix2 = Eigen::Matrix2d; // m^2 when it is a covariance
using Vector3 = Eigen::Vector3d; // m (nodes of unknown height)
using Matrix3 = Eigen::Matrix3d; // m^2 when it is a covariance

// A planar Gaussian: the belief about one position.
struct Gaussian2 {
    Vector2 mean_m = Vector2::Zero();
    Matrix2 covariance_m2 = Matrix2::Zero();
};

// The symmetric part of a covariance: products such as (c h) h^T round their two off-diagonal
// entries differently, and a state saved as three numbers must come back bit for bit.
inline Matrix2 symmetricPart(const Matrix2 &m) { return 0.5 * (m + m.transpose()); }

// Smallest eigenvalue of a symmetric 2x2 matrix, in closed form (no iterative solver).
inline double minEigenvalue(const Matrix2 &m)
{
    const double half_trace = 0.5 * (m(0, 0) + m(1, 1));
    const double half_difference = 0.5 * (m(0, 0) - m(1, 1));
    const double off_diagonal = 0.5 * (m(0, 1) + m(1, 0));
    return half_trace - std::sqrt(half_difference * half_difference + off_diagonal * off_diagonal);
}

} // namespace cdro::engine
