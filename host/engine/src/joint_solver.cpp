#include "cdro/engine/joint_solver.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

double jointCost(const Network &network, const RangeLikelihood &likelihood, double sigma_m)
{
    const double variance = sigma_m * sigma_m;
    double cost = 0.0;
    for (const LinkState &link : network.links) {
        const NodeState &a = network.nodes[link.node_a];
        const NodeState &b = network.nodes[link.node_b];
        if (a.placed && b.placed) {
            cost -= likelihood.logDensity(link.representative_m - (a.position_m - b.position_m).norm(), variance);
        }
    }
    return cost;
}

JointSolveResult solveJointly(Network &network, const RangeLikelihood &likelihood, const JointSolveParams &params)
{
    JointSolveResult result;
    // Unknowns: the free nodes, two coordinates each.
    std::vector<int> column(network.nodes.size(), -1);
    std::vector<uint32_t> free_nodes;
    for (uint32_t node = 0; node < network.nodes.size(); ++node) {
        const NodeState &state = network.nodes[node];
        if (state.placed && !state.fixed && !state.pinned && !state.moving) {
            column[node] = static_cast<int>(2 * free_nodes.size());
            free_nodes.push_back(node);
        }
    }
    result.nodes = static_cast<uint32_t>(free_nodes.size());
    if (free_nodes.empty()) {
        result.cost = jointCost(network, likelihood, params.range_sigma_m);
        return result;
    }
    const Eigen::Index size = static_cast<Eigen::Index>(2 * free_nodes.size());
    std::vector<Vector2> saved(free_nodes.size());
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver;
    std::vector<Eigen::Triplet<double>> triplets;

    for (double scale : params.sigma_scales) {
        const double sigma = params.range_sigma_m * scale;
        const double variance = sigma * sigma;
        double damping = params.initial_damping;
        double cost = jointCost(network, likelihood, sigma);
        for (uint32_t iteration = 0; iteration < params.iterations_per_stage; ++iteration) {
            // Normal equations of the weighted residuals r = measured - |p_a - p_b|.
            triplets.clear();
            // Every diagonal entry exists (the damping goes there), whatever the links are.
            for (Eigen::Index i = 0; i < size; ++i) {
                triplets.emplace_back(static_cast<int>(i), static_cast<int>(i), 0.0);
            }
            Eigen::VectorXd gradient = Eigen::VectorXd::Zero(size);
            for (const LinkState &link : network.links) {
                const NodeState &a = network.nodes[link.node_a];
                const NodeState &b = network.nodes[link.node_b];
                const int ca = column[link.node_a];
                const int cb = column[link.node_b];
                if (!a.placed || !b.placed || (ca < 0 && cb < 0)) {
                    continue;
                }
                const RangePrediction prediction = predictRange(a.position_m, b.position_m);
                if (prediction.singular) {
                    continue;
                }
                const double residual = link.representative_m - prediction.range_m;
                const double weight = likelihood.inlierProbability(residual, variance) / variance;
                const Eigen::Vector2d u = prediction.jacobian_point.transpose(); // d|a-b|/da
                const Eigen::Matrix2d block = weight * u * u.transpose();
                auto add = [&](int row, int col, const Eigen::Matrix2d &m) {
                    for (int i = 0; i < 2; ++i) {
                        for (int j = 0; j < 2; ++j) {
                            triplets.emplace_back(row + i, col + j, m(i, j));
                        }
                    }
                };
                if (ca >= 0) {
                    add(ca, ca, block);
                    gradient.segment<2>(ca) += weight * residual * u;
                }
                if (cb >= 0) {
                    add(cb, cb, block);
                    gradient.segment<2>(cb) -= weight * residual * u;
                }
                if (ca >= 0 && cb >= 0) {
                    add(ca, cb, -block);
                    add(cb, ca, -block);
                }
            }
            Eigen::SparseMatrix<double> normal(size, size);
            normal.setFromTriplets(triplets.begin(), triplets.end());
            const double mean_diagonal = std::max(normal.diagonal().mean(), 1e-9);
            bool accepted = false;
            for (int attempt = 0; attempt < 8 && !accepted; ++attempt) {
                Eigen::SparseMatrix<double> damped = normal;
                for (Eigen::Index i = 0; i < size; ++i) {
                    damped.coeffRef(i, i) += damping * mean_diagonal;
                }
                // The pattern can change between iterations (a link becomes singular): analyse
                // every time; it is cheap next to the factorisation.
                solver.compute(damped);
                if (solver.info() != Eigen::Success) {
                    damping *= 10.0;
                    continue;
                }
                const Eigen::VectorXd step = solver.solve(gradient);
                for (size_t i = 0; i < free_nodes.size(); ++i) {
                    NodeState &state = network.nodes[free_nodes[i]];
                    saved[i] = state.position_m;
                    state.position_m += step.segment<2>(static_cast<Eigen::Index>(2 * i));
                }
                const double trial = jointCost(network, likelihood, sigma);
                if (trial < cost) {
                    accepted = true;
                    cost = trial;
                    damping = std::max(damping / 3.0, 1e-9);
                    ++result.iterations;
                    double longest = 0.0;
                    for (Eigen::Index i = 0; i < size; i += 2) {
                        longest = std::max(longest, step.segment<2>(i).norm());
                    }
                    if (longest < params.step_tolerance_m) {
                        iteration = params.iterations_per_stage; // this stage has converged
                    }
                } else {
                    for (size_t i = 0; i < free_nodes.size(); ++i) {
                        network.nodes[free_nodes[i]].position_m = saved[i];
                    }
                    damping *= 10.0;
                    ++result.refused;
                }
            }
            if (!accepted) {
                break; // no step lowers the cost at this noise: on to the next stage
            }
        }
    }
    result.cost = jointCost(network, likelihood, params.range_sigma_m);
    return result;
}

} // namespace cdro::engine
