#include "cdro/engine/point_solver.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

std::vector<RangeConstraint> placedConstraints(const MapState &map, uint32_t node)
{
    std::vector<RangeConstraint> constraints;
    const NodeState &state = map.nodes[node];
    constraints.reserve(state.links.size());
    for (uint32_t link : state.links) {
        const NodeState &other = map.nodes[map.otherNode(link, node)];
        // A moving node is tracked by the others, never an anchor for them.
        if (!other.placed() || other.moving()) {
            continue;
        }
        RangeConstraint constraint;
        constraint.anchor_m = other.position_m;
        constraint.anchor_covariance_m2 = other.fixed() ? Matrix2::Zero() : other.covariance_m2;
        constraint.range_m = map.links[link].representative_m;
        constraint.link = link;
        constraints.push_back(constraint);
    }
    return constraints;
}

std::vector<RangeConstraint> placedConstraints(const MapProblem &problem, const MapEstimate &estimate, uint32_t node)
{
    std::vector<RangeConstraint> constraints;
    for (uint32_t link : problem.node_links[node]) {
        const uint32_t other = problem.other(link, node);
        if (estimate.placed[other] != 0) {
            RangeConstraint constraint;
            constraint.anchor_m = estimate.position_m[other];
            constraint.range_m = problem.links[link].range_m;
            constraint.link = link;
            constraints.push_back(constraint);
        }
    }
    return constraints;
}

namespace {

// evaluate()'s floor of a link's log-density (nats).
constexpr double kLogDensityFloor = -690.0;

double residualVariance(const RangeConstraint &constraint, const RangePrediction &prediction, double sigma_m,
                        bool with_anchor = true)
{
    if (!with_anchor) {
        return sigma_m * sigma_m;
    }
    const Eigen::RowVector2d h = prediction.jacobian_point;
    return sigma_m * sigma_m + (h * constraint.anchor_covariance_m2 * h.transpose())(0, 0);
}

} // namespace

double robustCost(const std::vector<RangeConstraint> &constraints, const Vector2 &position_m,
                  const RangeLikelihood &likelihood, double range_sigma_m)
{
    double cost = 0.0;
    for (const RangeConstraint &constraint : constraints) {
        const RangePrediction prediction = predictRange(position_m, constraint.anchor_m);
        const double variance = residualVariance(constraint, prediction, range_sigma_m);
        cost -= likelihood.logDensity(constraint.range_m - prediction.range_m, variance);
    }
    return cost;
}

PointSolution solvePoint(const std::vector<RangeConstraint> &constraints, const Vector2 &start_m,
                         const RangeLikelihood &likelihood, const PointSolverParams &params,
                         std::vector<double> *inlier_probabilities)
{
    PointSolution solution;
    solution.position_m = start_m;
    Matrix2 information = Matrix2::Zero();
    // What the last linearization saw of each link. When the step it gave is below the
    // tolerance, the bookkeeping takes it from there instead of evaluating every link again at a
    // point less than step_tolerance_m away (half of the refinement's likelihood evaluations in
    // the steady state, docs/bench.md).
    std::vector<double> density_per_m(constraints.size(), 0.0);
    std::vector<double> inlier(constraints.size(), 1.0);
    Matrix2 reported_information = Matrix2::Zero();
    bool converged = false;
    for (uint32_t iteration = 0; iteration < params.max_iterations; ++iteration) {
        information.setZero();
        reported_information.setZero();
        Eigen::Vector2d gradient = Eigen::Vector2d::Zero();
        for (size_t i = 0; i < constraints.size(); ++i) {
            const RangeConstraint &constraint = constraints[i];
            const RangePrediction prediction = predictRange(solution.position_m, constraint.anchor_m);
            const double variance =
                residualVariance(constraint, prediction, params.range_sigma_m, params.anchor_uncertainty_in_solve);
            const double residual = constraint.range_m - prediction.range_m;
            const RangeLikelihood::DensityWithInlier at = likelihood.densityWithInlier(residual, variance);
            density_per_m[i] = at.density_per_m;
            inlier[i] = at.inlier_probability;
            if (prediction.singular) {
                continue;
            }
            const double weight = at.inlier_probability;
            const Eigen::Vector2d h = prediction.jacobian_point.transpose();
            information += (weight / variance) * h * h.transpose();
            gradient += (weight / variance) * residual * h;
            const double reported_variance = params.anchor_uncertainty_in_solve
                                                 ? variance
                                                 : residualVariance(constraint, prediction, params.range_sigma_m, true);
            reported_information += (weight / reported_variance) * h * h.transpose();
        }
        solution.iterations = iteration + 1;
        if (minEigenvalue(information) < params.min_information) {
            solution.well_posed = false;
            break;
        }
        solution.well_posed = true;
        Eigen::Vector2d step = information.ldlt().solve(gradient);
        const double length = step.norm();
        if (length > params.max_step_m) {
            step *= params.max_step_m / length;
        }
        solution.position_m += step;
        if (step.norm() < params.step_tolerance_m) {
            converged = true;
            break;
        }
    }
    solution.cost = 0.0;
    solution.downweighted = 0;
    if (converged) {
        for (size_t i = 0; i < constraints.size(); ++i) {
            solution.cost -= std::max(std::log(density_per_m[i]), kLogDensityFloor);
            solution.downweighted += inlier[i] < 0.5 ? 1U : 0U;
        }
        if (inlier_probabilities != nullptr) {
            *inlier_probabilities = inlier;
        }
        information = reported_information;
    } else {
        // Final bookkeeping at the solution: cost, weights, covariance.
        information.setZero();
        if (inlier_probabilities != nullptr) {
            inlier_probabilities->assign(constraints.size(), 1.0);
        }
        for (size_t i = 0; i < constraints.size(); ++i) {
            const RangeConstraint &constraint = constraints[i];
            const RangePrediction prediction = predictRange(solution.position_m, constraint.anchor_m);
            const double variance =
                residualVariance(constraint, prediction, params.range_sigma_m, params.anchor_uncertainty_in_solve);
            const ResidualEvaluation evaluation =
                likelihood.evaluate(constraint.range_m - prediction.range_m, variance);
            solution.cost -= evaluation.log_density;
            if (evaluation.inlier_probability < 0.5) {
                ++solution.downweighted;
            }
            if (inlier_probabilities != nullptr) {
                (*inlier_probabilities)[i] = evaluation.inlier_probability;
            }
            if (!prediction.singular) {
                const Eigen::Vector2d h = prediction.jacobian_point.transpose();
                const double reported_variance = residualVariance(constraint, prediction, params.range_sigma_m, true);
                information += (evaluation.inlier_probability / reported_variance) * h * h.transpose();
            }
        }
    }
    solution.well_posed = solution.well_posed && minEigenvalue(information) >= params.min_information;
    if (solution.well_posed) {
        solution.covariance_m2 = symmetricPart(information.inverse());
    }
    return solution;
}

} // namespace cdro::engine
