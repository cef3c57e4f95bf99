#include "cdro/engine/range_offsets.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

#include "cdro/engine/map_refine.hpp"

namespace cdro::engine {

namespace {

constexpr double kCommonMinM = -0.3;      // m, the common part searched (radios read long, rarely short)
constexpr double kCommonMaxM = 1.5;       // m
constexpr uint32_t kGoldenSteps = 8;      // the common part to (1.8 m) 0.618^8 = 0.04 m
constexpr uint32_t kRounds = 6;           // map and offsets in turn, per common part
constexpr uint32_t kWarmRounds = 2;       // ... from a neighbouring common part's map and offsets
constexpr uint32_t kOffsetIterations = 3; // IRLS steps of the offsets per round
constexpr double kNatsPerOffset = 2.0;    // nats an offset must earn to be adopted
constexpr double kGoldenRatio = 0.6180339887498949;

struct Trial {
    MapEstimate estimate;
    std::vector<double> deviation_m; // the offsets' deviations from the common part
    std::vector<double> offset_m;
    double cost_nats = 0.0;
};

// The node offsets' deviations from `common_m` given the map: IRLS over the links' robust cost,
// each deviation a Gaussian prior of kRangeOffsetSpreadSigmaM.
void solveDeviations(const MapProblem &problem, const MapEstimate &map, const RangeLikelihood &likelihood,
                     double common_m, std::vector<double> &deviation_m)
{
    const auto n = static_cast<Eigen::Index>(problem.nodeCount());
    const double variance = problem.sigma_m * problem.sigma_m;
    const double prior = 1.0 / (kRangeOffsetSpreadSigmaM * kRangeOffsetSpreadSigmaM);
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver;
    bool analysed = false;
    for (uint32_t iteration = 0; iteration < kOffsetIterations; ++iteration) {
        std::vector<Eigen::Triplet<double>> triplets;
        triplets.reserve(static_cast<size_t>(n) + 4 * problem.links.size());
        Eigen::VectorXd descent(n);
        for (Eigen::Index i = 0; i < n; ++i) {
            triplets.emplace_back(static_cast<int>(i), static_cast<int>(i), prior);
            descent[i] = -prior * deviation_m[static_cast<size_t>(i)];
        }
        for (const MapLink &link : problem.links) {
            if (map.placed[link.a] == 0 || map.placed[link.b] == 0) {
                continue;
            }
            const double distance = (map.position_m[link.a] - map.position_m[link.b]).norm();
            const double residual =
                link.range_m - 2.0 * common_m - deviation_m[link.a] - deviation_m[link.b] - distance;
            const ResidualEvaluation at = likelihood.evaluate(residual, variance);
            const double weight = likelihood.irlsWeight(residual, variance, at);
            const int a = static_cast<int>(link.a);
            const int b = static_cast<int>(link.b);
            triplets.emplace_back(a, a, weight);
            triplets.emplace_back(b, b, weight);
            triplets.emplace_back(a, b, weight);
            triplets.emplace_back(b, a, weight);
            // cost -log p(e), e = r - ... - d_a - d_b: d cost / d deviation = slope.
            descent[a] -= at.slope_per_m;
            descent[b] -= at.slope_per_m;
        }
        Eigen::SparseMatrix<double> normal(n, n);
        normal.setFromTriplets(triplets.begin(), triplets.end());
        if (!analysed) {
            solver.analyzePattern(normal);
            analysed = true;
        }
        solver.factorize(normal);
        if (solver.info() != Eigen::Success) {
            return;
        }
        const Eigen::VectorXd step = solver.solve(descent);
        for (Eigen::Index i = 0; i < n; ++i) {
            deviation_m[static_cast<size_t>(i)] += step[i];
        }
    }
}

// The map and offsets for one common part: from `start` (the map without offsets) through the
// refinement's stages, or, warm, from a neighbouring common part's trial, whose map and
// deviations are already near (the common part moves every range by a few centimetres between
// neighbours), in fewer rounds at the nominal noise.
Trial tryCommon(const MapProblem &problem, const MapEstimate &start, const RangeLikelihood &likelihood, double common_m,
                const Trial *warm = nullptr)
{
    Trial trial;
    trial.estimate = warm != nullptr ? warm->estimate : start;
    std::vector<double> deviation = warm != nullptr ? warm->deviation_m : std::vector<double>(problem.nodeCount(), 0.0);
    auto offsets = [&]() {
        std::vector<double> out(problem.nodeCount(), 0.0);
        for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
            out[node] = common_m + deviation[node];
        }
        return out;
    };
    MapRefineParams final_stage;
    final_stage.stages = {RefineStage{}};
    if (warm == nullptr) {
        refineMap(withRangeOffsets(problem, offsets()), trial.estimate, likelihood);
    }
    for (uint32_t round = 0; round < (warm != nullptr ? kWarmRounds : kRounds); ++round) {
        solveDeviations(problem, trial.estimate, likelihood, common_m, deviation);
        refineMap(withRangeOffsets(problem, offsets()), trial.estimate, likelihood, final_stage);
    }
    trial.offset_m = offsets();
    trial.deviation_m = deviation;
    double prior_nats = 0.0;
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (start.placed[node] != 0) {
            prior_nats +=
                0.5 * deviation[node] * deviation[node] / (kRangeOffsetSpreadSigmaM * kRangeOffsetSpreadSigmaM);
        }
    }
    trial.cost_nats = mapCost(withRangeOffsets(problem, trial.offset_m), trial.estimate, likelihood) + prior_nats;
    return trial;
}

} // namespace

MapProblem withRangeOffsets(const MapProblem &problem, const std::vector<double> &offset_m)
{
    MapProblem corrected = problem;
    for (MapLink &link : corrected.links) {
        link.range_m -= offset_m[link.a] + offset_m[link.b];
    }
    return corrected;
}

RangeOffsets calibrateRangeOffsets(const MapProblem &problem, const MapEstimate &start,
                                   const RangeLikelihood &likelihood)
{
    RangeOffsets out;
    out.estimate = start;
    out.offset_m.assign(problem.nodeCount(), 0.0);
    out.cost_without_nats = mapCost(problem, start, likelihood);
    out.cost_nats = out.cost_without_nats;
    const uint32_t placed = start.placedCount();
    if (placed < 4 || problem.links.size() < 2 * static_cast<size_t>(placed)) {
        return out; // the links cannot tell an offset per node from the map
    }
    // Golden section over the common part: the first two trials from the map without offsets,
    // each later one warm from the kept trial next to it.
    double low = kCommonMinM;
    double high = kCommonMaxM;
    double x1 = high - kGoldenRatio * (high - low);
    double x2 = low + kGoldenRatio * (high - low);
    Trial t1 = tryCommon(problem, start, likelihood, x1);
    Trial t2 = tryCommon(problem, start, likelihood, x2);
    out.evaluations = 2;
    for (uint32_t step = 0; step < kGoldenSteps; ++step) {
        if (t1.cost_nats < t2.cost_nats) {
            high = x2;
            x2 = x1;
            t2 = std::move(t1);
            x1 = high - kGoldenRatio * (high - low);
            t1 = tryCommon(problem, start, likelihood, x1, &t2);
        } else {
            low = x1;
            x1 = x2;
            t1 = std::move(t2);
            x2 = low + kGoldenRatio * (high - low);
            t2 = tryCommon(problem, start, likelihood, x2, &t1);
        }
        ++out.evaluations;
    }
    Trial &best = t1.cost_nats < t2.cost_nats ? t1 : t2;
    const double margin = kNatsPerOffset * static_cast<double>(placed + 1);
    out.decision_nats = out.cost_without_nats - (best.cost_nats + margin);
    if (!(out.decision_nats > 0.0)) {
        out.other_estimate = std::move(best.estimate);
        out.other_offset_m = std::move(best.offset_m);
    } else {
        out.other_estimate = start;
        out.other_offset_m.assign(problem.nodeCount(), 0.0);
        out.adopted = true;
        out.common_m = t1.cost_nats < t2.cost_nats ? x1 : x2;
        out.offset_m = std::move(best.offset_m);
        out.estimate = std::move(best.estimate);
        out.cost_nats = best.cost_nats;
    }
    return out;
}

} // namespace cdro::engine
