#include "cdro/engine/map_lift.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>

#include "cdro/engine/map_mds.hpp"

namespace cdro::engine {

namespace {

// Turns the placed rows so that the coordinates are the principal directions, widest first.
void principalAxes(const std::vector<uint8_t> &placed, Eigen::MatrixXd &positions)
{
    const Eigen::Index dims = positions.cols();
    Eigen::VectorXd mean = Eigen::VectorXd::Zero(dims);
    double count = 0.0;
    for (Eigen::Index node = 0; node < positions.rows(); ++node) {
        if (placed[static_cast<size_t>(node)] != 0) {
            mean += positions.row(node).transpose();
            count += 1.0;
        }
    }
    if (count < 2.0) {
        return;
    }
    mean /= count;
    Eigen::MatrixXd scatter = Eigen::MatrixXd::Zero(dims, dims);
    for (Eigen::Index node = 0; node < positions.rows(); ++node) {
        if (placed[static_cast<size_t>(node)] != 0) {
            const Eigen::VectorXd centred = positions.row(node).transpose() - mean;
            scatter += centred * centred.transpose();
        }
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(scatter);
    Eigen::MatrixXd axes(dims, dims);
    for (Eigen::Index k = 0; k < dims; ++k) {
        axes.col(k) = eigen.eigenvectors().col(dims - 1 - k);
    }
    for (Eigen::Index node = 0; node < positions.rows(); ++node) {
        if (placed[static_cast<size_t>(node)] != 0) {
            positions.row(node) = ((positions.row(node).transpose() - mean).transpose() * axes);
        }
    }
}

} // namespace

MapRefineResult liftedRefine(const MapProblem &problem, MapEstimate &estimate, const RangeLikelihood &likelihood,
                             const MapLiftParams &params, bool mds_start)
{
    const auto dims = static_cast<Eigen::Index>(std::clamp<uint32_t>(params.dimensions, 3U, kMaxEmbeddingDimensions));
    Eigen::MatrixXd positions = Eigen::MatrixXd::Zero(problem.nodeCount(), dims);
    std::vector<uint32_t> part;
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (estimate.placed[node] != 0) {
            part.push_back(node);
        }
    }
    bool started = false;
    if (mds_start) {
        if (std::optional<Eigen::MatrixXd> embedding = mdsEmbedding(problem, part, static_cast<uint32_t>(dims))) {
            positions = *embedding;
            started = true;
        }
    }
    if (!started) {
        // A planar start has no gradient out of the plane: lift it a little, deterministically.
        for (uint32_t node : part) {
            positions.row(node).head<2>() = estimate.position_m[node].transpose();
            for (Eigen::Index d = 2; d < dims; ++d) {
                const double phase = 2.399963 * static_cast<double>(node + 1) * static_cast<double>(d);
                positions(node, d) = params.lift_m * std::sin(phase);
            }
        }
    }
    const bool fixed_frame = problem.fixedCount() >= 2;
    MapRefineParams refine;
    MapRefineResult result;
    auto add = [&](const MapRefineResult &part_result) {
        result.iterations += part_result.iterations;
        result.refused += part_result.refused;
    };
    if (!fixed_frame) {
        add(refineEmbedding(problem, estimate.placed, positions, likelihood, params.stages, params.iterations_per_stage,
                            0.0, refine));
        for (double squeeze : params.squeeze) {
            principalAxes(estimate.placed, positions);
            add(refineEmbedding(problem, estimate.placed, positions, likelihood, {RefineStage{}},
                                params.iterations_per_stage, squeeze, refine));
        }
        principalAxes(estimate.placed, positions);
    }
    for (uint32_t node : part) {
        if (problem.fixed[node] == 0) {
            estimate.position_m[node] = positions.row(node).head<2>().transpose();
        }
    }
    MapRefineParams planar;
    planar.stages = {RefineStage{}};
    add(refineMap(problem, estimate, likelihood, planar));
    result.cost = mapCost(problem, estimate, likelihood);
    return result;
}

} // namespace cdro::engine
