// point_solver: robust Gauss-Newton for one node against ranges to known positions: exact
// recovery, a corrupted (NLOS) constraint written off, the covariance, the step limit, the
// constraints read from a network.
#include <cmath>
#include <limits>

#include <Eigen/LU>
#include <gtest/gtest.h>

#include "cdro/engine/point_solver.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::Matrix2;
using engine::PointSolverParams;
using engine::RangeConstraint;
using engine::RangeLikelihood;
using engine::RangeLikelihoodParams;
using engine::solvePoint;

constexpr double kTwoPi = 6.28318530717958647692;

std::vector<RangeConstraint> ringOfAnchors(const Vector2 &truth_m, size_t count, double radius_m, Random &random)
{
    std::vector<RangeConstraint> constraints;
    for (size_t i = 0; i < count; ++i) {
        // Around the point, with some jitter: a well-posed geometry.
        const double angle = kTwoPi * static_cast<double>(i) / static_cast<double>(count) + random.uniform(-0.3, 0.3);
        RangeConstraint c;
        c.anchor_m = truth_m + radius_m * random.uniform(0.7, 1.3) * Vector2(std::cos(angle), std::sin(angle));
        c.range_m = (c.anchor_m - truth_m).norm();
        c.link = static_cast<uint32_t>(i);
        constraints.push_back(c);
    }
    return constraints;
}

RangeLikelihood gaussianLikelihood()
{
    RangeLikelihoodParams params;
    params.robust = false;
    return RangeLikelihood(params);
}

TEST(PointSolver, RecoversThePointExactlyFromExactRanges)
{
    const uint64_t seed = testSeed(3201);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    for (const bool robust : {true, false}) {
        const RangeLikelihood likelihood = robust ? RangeLikelihood() : gaussianLikelihood();
        for (size_t count : {3U, 4U, 7U}) {
            for (int trial = 0; trial < 10; ++trial) {
                const Vector2 truth_m = uniformPoint(random, -30.0, 30.0);
                const auto constraints = ringOfAnchors(truth_m, count, random.uniform(3.0, 15.0), random);
                // Started up to 1 m away: inside the basin of the true solution.
                const Vector2 start_m = truth_m + uniformPoint(random, -0.7, 0.7);
                std::vector<double> inliers;
                const auto solution = solvePoint(constraints, start_m, likelihood, PointSolverParams{}, &inliers);
                EXPECT_TRUE(solution.well_posed);
                EXPECT_LT((solution.position_m - truth_m).norm(), 1e-7)
                    << (robust ? "robust" : "gaussian") << ", " << count << " constraints, trial " << trial;
                EXPECT_EQ(solution.downweighted, 0U);
                ASSERT_EQ(inliers.size(), count);
                for (double p : inliers) {
                    // 0.973 for a residual just above 0: the NLOS density eps lambda starts there.
                    EXPECT_GT(p, 0.95);
                }
                // The reported cost is the robust cost at the solution (evaluated at the last
                // linearization, less than step_tolerance_m away: a quadratic's worth of it).
                const double flat_nats =
                    static_cast<double>(count) * std::pow(PointSolverParams{}.step_tolerance_m / 0.10, 2.0);
                EXPECT_NEAR(solution.cost, engine::robustCost(constraints, solution.position_m, likelihood, 0.10),
                            flat_nats);
            }
        }
    }
}

TEST(PointSolver, WritesOffOneLongNlosConstraint)
{
    const uint64_t seed = testSeed(3202);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    for (int trial = 0; trial < 10; ++trial) {
        const Vector2 truth_m = uniformPoint(random, -10.0, 10.0);
        auto constraints = ringOfAnchors(truth_m, 5, 8.0, random);
        const size_t corrupted = random.below(constraints.size());
        constraints[corrupted].range_m += random.uniform(1.0, 3.0); // NLOS: reads long
        const Vector2 start_m = truth_m + Vector2(0.3, -0.2);
        std::vector<double> inliers;
        const auto robust = solvePoint(constraints, start_m, RangeLikelihood(), PointSolverParams{}, &inliers);
        EXPECT_LT((robust.position_m - truth_m).norm(), 1e-4) << "trial " << trial;
        EXPECT_EQ(robust.downweighted, 1U);
        for (size_t i = 0; i < inliers.size(); ++i) {
            if (i == corrupted) {
                EXPECT_LT(inliers[i], 0.01);
            } else {
                EXPECT_GT(inliers[i], 0.9);
            }
        }
        // The plain Gaussian is pulled off by the same constraint.
        const auto plain = solvePoint(constraints, start_m, gaussianLikelihood(), PointSolverParams{});
        EXPECT_GT((plain.position_m - truth_m).norm(), 0.1) << "trial " << trial;
        EXPECT_EQ(plain.downweighted, 0U);
    }
}

TEST(PointSolver, CovarianceIsTheInverseInformationAndShrinksWithMoreConstraints)
{
    const uint64_t seed = testSeed(3203);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const Vector2 truth_m(2.0, 3.0);
    const RangeLikelihood likelihood = gaussianLikelihood();
    PointSolverParams params;
    params.range_sigma_m = 0.2;
    std::vector<RangeConstraint> all = ringOfAnchors(truth_m, 24, 10.0, random);
    double previous_trace = std::numeric_limits<double>::infinity();
    for (size_t count : {3U, 6U, 12U, 24U}) {
        // Every other anchor of the denser sets: similar geometry, more of it.
        std::vector<RangeConstraint> subset;
        for (size_t i = 0; i < count; ++i) {
            subset.push_back(all[i * (24 / count)]);
        }
        const auto solution = solvePoint(subset, truth_m, likelihood, params);
        ASSERT_TRUE(solution.well_posed);
        Matrix2 information = Matrix2::Zero();
        for (const RangeConstraint &c : subset) {
            const Vector2 u = (truth_m - c.anchor_m).normalized();
            information += u * u.transpose() / (0.2 * 0.2);
        }
        const Matrix2 expected = information.inverse();
        EXPECT_NEAR((solution.covariance_m2 - expected).norm(), 0.0, 1e-9 * expected.norm()) << count;
        const double trace = solution.covariance_m2.trace();
        EXPECT_LT(trace, previous_trace) << count;
        previous_trace = trace;
    }
    // Uncertain anchors widen the reported covariance.
    std::vector<RangeConstraint> unsure = ringOfAnchors(truth_m, 4, 10.0, random);
    const auto sure_solution = solvePoint(unsure, truth_m, likelihood, params);
    for (RangeConstraint &c : unsure) {
        c.anchor_covariance_m2 = 0.09 * Matrix2::Identity();
    }
    const auto unsure_solution = solvePoint(unsure, truth_m, likelihood, params);
    EXPECT_GT(unsure_solution.covariance_m2.trace(), 2.0 * sure_solution.covariance_m2.trace());
}

TEST(PointSolver, StepsAreLimitedToMaxStep)
{
    const Vector2 truth_m(0.0, 0.0);
    std::vector<RangeConstraint> constraints;
    for (const Vector2 &anchor : {Vector2(10.0, 0.0), Vector2(-10.0, 0.0), Vector2(0.0, 10.0), Vector2(0.0, -10.0)}) {
        RangeConstraint c;
        c.anchor_m = anchor;
        c.range_m = (anchor - truth_m).norm();
        constraints.push_back(c);
    }
    const Vector2 start_m(6.0, 5.0); // the first Gauss-Newton step is several metres long
    PointSolverParams one_step;
    one_step.max_iterations = 1;
    const RangeLikelihood likelihood = gaussianLikelihood();
    const auto limited = solvePoint(constraints, start_m, likelihood, one_step);
    EXPECT_NEAR((limited.position_m - start_m).norm(), one_step.max_step_m, 1e-12);
    one_step.max_step_m = 100.0;
    const auto free_step = solvePoint(constraints, start_m, likelihood, one_step);
    EXPECT_GT((free_step.position_m - start_m).norm(), 3.0);
    // The shortened step points the same way as the full one.
    const Vector2 a = (limited.position_m - start_m).normalized();
    const Vector2 b = (free_step.position_m - start_m).normalized();
    EXPECT_NEAR(a.dot(b), 1.0, 1e-12);
    // Given the iterations, the limited solver still gets there.
    const auto converged = solvePoint(constraints, start_m, likelihood, PointSolverParams{});
    EXPECT_LT((converged.position_m - truth_m).norm(), 1e-6);
}

TEST(PointSolver, DegenerateGeometryIsNotWellPosed)
{
    // Two anchors and the point on one line: nothing constrains the point across the line.
    std::vector<RangeConstraint> constraints(2);
    constraints[0].anchor_m = Vector2(0.0, 0.0);
    constraints[0].range_m = 3.0;
    constraints[1].anchor_m = Vector2(10.0, 0.0);
    constraints[1].range_m = 7.0;
    const auto solution = solvePoint(constraints, Vector2(3.0, 0.0), gaussianLikelihood(), PointSolverParams{});
    EXPECT_FALSE(solution.well_posed);
    EXPECT_TRUE(solution.position_m.allFinite());
    // No constraints at all: the start is returned, not well posed.
    const auto none = solvePoint({}, Vector2(1.0, 2.0), RangeLikelihood(), PointSolverParams{});
    EXPECT_FALSE(none.well_posed);
    EXPECT_EQ(none.position_m, Vector2(1.0, 2.0));
}

TEST(PointSolver, PlacedConstraintsListOnlyPlacedNeighbours)
{
    engine::MapState network;
    const uint32_t node = network.addNode(10);
    const uint32_t placed = network.addNode(20);
    const uint32_t unplaced = network.addNode(30);
    const uint32_t fixed = network.addNode(40);
    network.nodes[placed].lifecycle = engine::NodeLifecycle::Placed;
    network.nodes[placed].position_m = Vector2(1.0, 2.0);
    network.nodes[placed].covariance_m2 = 0.04 * Matrix2::Identity();
    network.nodes[fixed].lifecycle = engine::NodeLifecycle::Converged;
    network.nodes[fixed].role = engine::NodeRole::Fixed;
    network.nodes[fixed].position_m = Vector2(-3.0, 0.5);
    network.nodes[fixed].covariance_m2 = Matrix2::Identity(); // ignored: a fixed node is certain
    const uint32_t link_placed = network.addLink(node, placed, 15);
    network.addLink(unplaced, node, 15);
    const uint32_t link_fixed = network.addLink(fixed, node, 15);
    network.links[link_placed].representative_m = 4.5;
    network.links[link_fixed].representative_m = 6.25;
    const auto constraints = engine::placedConstraints(network, node);
    ASSERT_EQ(constraints.size(), 2U);
    EXPECT_EQ(constraints[0].link, link_placed);
    EXPECT_EQ(constraints[0].anchor_m, Vector2(1.0, 2.0));
    EXPECT_EQ(constraints[0].range_m, 4.5);
    EXPECT_EQ(constraints[0].anchor_covariance_m2, 0.04 * Matrix2::Identity());
    EXPECT_EQ(constraints[1].link, link_fixed);
    EXPECT_EQ(constraints[1].range_m, 6.25);
    EXPECT_TRUE(constraints[1].anchor_covariance_m2.isZero(0.0));
}

} // namespace
} // namespace cdro::enginetest
