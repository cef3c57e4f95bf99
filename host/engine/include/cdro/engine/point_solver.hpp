// point_solver.hpp: one node's position from its links to placed nodes, by robust Gauss-Newton
// (iteratively reweighted least squares over the mixture of range_likelihood.hpp: each link's
// weight is its line-of-sight probability at the current estimate, an EM step).
//
// Used by placement (trilateration: every local optimum is a candidate) and by refinement
// (the merged SoG estimate polished against every link, with the links' robust ranges).
// The residual of a link to neighbour m is e = r_m - |x - p_m| with r_m the link's median
// range; its variance is sigma_r^2 + u^T C_m u (the neighbour's uncertainty along the link),
// or sigma_r^2 alone while solving for refinement (see anchor_uncertainty_in_solve).
// The cost, the links' inlier probabilities and the covariance are those of the last
// linearization when its step was below step_tolerance_m (the position is then at most that far
// from where they were evaluated; near the optimum the cost differs by at most about
// links x (step_tolerance_m / sigma)^2 nats: 8e-6 for 8 links at 0.1 m), else evaluated again
// at the position returned.
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/map_problem.hpp"
#include "cdro/engine/map_state.hpp"
#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {

// One constraint on the point: a range to a known position.
struct RangeConstraint {
    Vector2 anchor_m = Vector2::Zero();             // m, the neighbour's position
    Matrix2 anchor_covariance_m2 = Matrix2::Zero(); // m^2
    double range_m = 0.0;                           // m
    uint32_t link = kNoIndex;                       // for the caller's bookkeeping
};

// The links of `node` to placed neighbours that are not moving, as constraints (in the order
// of the node's links).
std::vector<RangeConstraint> placedConstraints(const MapState &map, uint32_t node);
// The same for a plain map problem: the links of `node` to the nodes `estimate` places.
std::vector<RangeConstraint> placedConstraints(const MapProblem &problem, const MapEstimate &estimate, uint32_t node);

struct PointSolution {
    Vector2 position_m = Vector2::Zero();        // m
    Matrix2 covariance_m2 = Matrix2::Identity(); // m^2, inverse of the weighted information
    double cost = 0.0;                           // -sum log p(e), nats
    uint32_t iterations = 0;
    uint32_t downweighted = 0; // constraints with inlier probability < 0.5
    bool well_posed = false;   // the information matrix was invertible
};

struct PointSolverParams {
    double range_sigma_m = 0.10; // m
    uint32_t max_iterations = 8;
    double step_tolerance_m = 1e-4; // m, stop when a step is shorter
    double max_step_m = 2.0;        // m, longer Gauss-Newton steps are shortened to this (a
                                    // nearly degenerate geometry must not throw a node away)
    double min_information = 1e-6;  // 1/m^2, smallest eigenvalue of a well-posed information
    // Whether the neighbours' uncertainty widens the residuals while solving. Placement: yes
    // (one node against fixed neighbours). Refinement: no. There every node is solved in turn
    // against the others, and a link must weigh the same at both of its ends: with weights
    // that differ (each end seeing the other's covariance), the forces along a link no longer
    // cancel and the whole map drifts, a few mm per update, forever. The reported covariance
    // always includes the neighbours' uncertainty.
    bool anchor_uncertainty_in_solve = true;
};

PointSolution solvePoint(const std::vector<RangeConstraint> &constraints, const Vector2 &start_m,
                         const RangeLikelihood &likelihood, const PointSolverParams &params,
                         std::vector<double> *inlier_probabilities = nullptr);

double robustCost(const std::vector<RangeConstraint> &constraints, const Vector2 &position_m,
                  const RangeLikelihood &likelihood, double range_sigma_m);

} // namespace cdro::engine
