// alignment.hpp: the rigid transform (rotation, translation, optionally a reflection, no
// scale) that best maps one planar point set onto another in the least-squares sense
// (Kabsch/Umeyama without scale). An anchor-free map is only defined up to such a transform.
#pragma once

#include <cstddef>
#include <limits>
#include <map>
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

// One node of a map: its id and where the map places it (m).
struct MapPoint {
    NodeId id = 0;
    Vector2 position_m = Vector2::Zero();
};

// A map's errors against a reference map (the truth, a survey, another solve) once the frame,
// which an anchor-free map does not fix, is taken out: see alignedErrors.
struct AlignedErrors {
    RigidTransform fit;          // the map onto the reference: fitRigid over the compared nodes
    std::vector<NodeId> ids;     // the compared nodes, in the map's order (empty in the paired form)
    std::vector<double> error_m; // m, |fit.apply(map) - reference| of each compared node, in that order
    double rmse_m = std::numeric_limits<double>::quiet_NaN();  // m, = fit.rms_error_m; NaN: none compared
    double worst_m = std::numeric_limits<double>::quiet_NaN(); // m, the largest of error_m; NaN: none

    size_t compared() const { return error_m.size(); }
    // The compared nodes more than limit_m (m) off, strictly.
    size_t countOver(double limit_m) const;
};

// alignedErrors: the one "aligned RMSE" (and per-node error) of the benchmarks, cdro-reference and
// the tests: how far a map is from a reference, after the rigid fit of the map onto it.
//
//   map_m             the nodes the map places, each id once (std::invalid_argument otherwise), in
//                     any order: the fit sums in that order, and ids and error_m keep it
//   reference_m       where the nodes should be (m), by id
//   allow_reflection  as fitRigid: true when the map may be the reference's mirror image (an
//                     anchor-free map has no handedness; every comparison with the truth allows it)
//
// Compared are the nodes both maps place: a node of the map that the reference lacks, and a node of
// the reference that the map does not place, take no part in the fit and have no error. The
// figures are then those of the fit: rmse_m = sqrt(mean of error_m^2) = fit.rms_error_m, worst_m,
// countOver(1.0) (the "more than 1 m off" of the scorecard). With no node compared the fit is the
// identity and the figures NaN; with one it is a shift and its error 0 m (to rounding): a caller
// that reports a figure only from 2 or 3 nodes checks compared() itself. Positions are expected
// finite: one NaN makes every figure NaN (leave such nodes out first).
//
//   std::vector<MapPoint> placed;   // e.g. from Engine::estimates(): placed nodes only
//   for (const NodeOutput &node : engine.estimates()) {
//       if (node.placed()) {
//           placed.push_back({node.id, node.position_m});
//       }
//   }
//   const AlignedErrors aligned = alignedErrors(placed, truth_m, true);
//   std::printf("%.3f m over %zu nodes, %zu more than 1 m off\n", aligned.rmse_m, aligned.compared(),
//               aligned.countOver(1.0));
AlignedErrors alignedErrors(const std::vector<MapPoint> &map_m, const std::map<NodeId, Vector2> &reference_m,
                            bool allow_reflection);

// The paired form, for callers that hold the compared nodes already: map_m[i] and reference_m[i]
// are one node (lengths that differ: std::invalid_argument); ids stays empty.
AlignedErrors alignedErrors(const std::vector<Vector2> &map_m, const std::vector<Vector2> &reference_m,
                            bool allow_reflection);

} // namespace cdro::engine
