// alignment.hpp: the rigid transform (rotation, translation, optionally a reflection, no
// scale) that best maps one planar point set onto another in the least-squares sense
// (Kabsch/Umeyama without scale). An anchor-free map is only defined up to such a transform.
#pragma once

#include <vector>

#include "cdro/engine/types.hpp"

namespace cdro::engine {

struct RigidTransform {
    Matrix2 rotation = Matrix2::Identity(); // orthonormal; determinant -1 when reflected
    Vector2 translation_m = Vector2::Zero();
    bool reflected = false;
    double rms_error_m = 0.0; // m, over the fitted points

    Vector2 apply(const Vector2 &point_m) const { return rotation * point_m + translation_m; }
    Matrix2 applyToCovariance(const Matrix2 &covariance_m2) const
    {
        return symmetricPart(rotation * covariance_m2 * rotation.transpose());
    }
};

// Maps source onto target (same length) by least squares. allow_reflection: try both
// handednesses and keep the better; the reflection only when it is better by more than rounding
// (1e-9 of the points' spread), so a collinear set, which both fit alike, gets the rotation.
// One point gives the translation only, none (or lengths that differ) the identity. The tools'
// Python fit (cdro_tools/evaluation/alignment.py) is the same fit, step for step:
// tests/golden/alignment_cases.json holds both to the same answers.
RigidTransform fitRigid(const std::vector<Vector2> &source_m, const std::vector<Vector2> &target_m,
                        bool allow_reflection);

} // namespace cdro::engine
