// map_connectivity.hpp: the cost of which pairs heard each other, on a corridor whose pairs hear
// each other within 1.6 m (a ladder of nodes 1 m apart, two rows).
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "cdro/engine/map_connectivity.hpp"

namespace cdro::engine {
namespace {

constexpr uint32_t kRungs = 12;  // ladder rungs, 1 m apart
constexpr double kReachM = 1.6;  // m, pairs closer than this heard each other
constexpr double kRowGapM = 1.0; // m, between the two rows

constexpr uint32_t kFoldRung = kRungs / 2; // the folded corridor turns back after this rung

Vector2 truePosition(uint32_t node)
{
    const uint32_t rung = node / 2;
    return Vector2(static_cast<double>(rung), (node % 2) * kRowGapM);
}

MapProblem ladder()
{
    MapProblem problem;
    for (uint32_t node = 0; node < 2 * kRungs; ++node) {
        problem.ids.push_back(static_cast<NodeId>(100 + node));
    }
    for (uint32_t a = 0; a < 2 * kRungs; ++a) {
        for (uint32_t b = a + 1; b < 2 * kRungs; ++b) {
            const double distance_m = (truePosition(a) - truePosition(b)).norm();
            if (distance_m < kReachM) {
                problem.links.push_back(MapLink{a, b, distance_m});
            }
        }
    }
    problem.listens.assign(2 * kRungs, 1);
    problem.finish();
    return problem;
}

MapEstimate placedAt(const MapProblem &problem, Vector2 (*where)(uint32_t))
{
    MapEstimate estimate = MapEstimate::unplaced(problem.nodeCount());
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        estimate.placed[node] = 1;
        estimate.position_m[node] = where(node);
    }
    return estimate;
}

// The corridor bent back on itself after its sixth rung, its second half running back beside the
// first 1.5 m away: every link keeps its length (the bend is a hinge in the ranges only if the
// rung there were a single node; here the rungs near it stretch a little), but pairs that never
// heard each other now stand close.
Vector2 foldedPosition(uint32_t node)
{
    const uint32_t rung = node / 2;
    const double across_m = (node % 2) * kRowGapM;
    if (rung < kFoldRung) {
        return Vector2(static_cast<double>(rung), across_m);
    }
    const double back_m = static_cast<double>(rung - kFoldRung);
    return Vector2(static_cast<double>(kFoldRung) - back_m - 0.5, 2.5 + kRowGapM - across_m);
}

TEST(MapConnectivity, TheTrueMapExplainsWhoHeardWhomBetterThanAFoldedOne)
{
    const MapProblem problem = ladder();
    const ConnectivityFit truth = connectivityCost(problem, placedAt(problem, truePosition));
    const ConnectivityFit folded = connectivityCost(problem, placedAt(problem, foldedPosition));
    std::printf("truth %.2f nats (half %.2f m, width %.3f m), folded %.2f nats\n", truth.cost_nats,
                truth.half_distance_m, truth.width_m, folded.cost_nats);
    EXPECT_EQ(truth.heard_pairs, problem.links.size());
    EXPECT_EQ(truth.heard_pairs + truth.unheard_pairs, kRungs * (2 * kRungs - 1));
    // The fold brings unheard pairs within the reach: each costs about -log(1 - 0.98) = 3.9 nats.
    EXPECT_GT(folded.cost_nats, truth.cost_nats + 20.0);
    // The fitted fall lies between the longest heard pair (sqrt 2 m) and the nearest unheard (2 m).
    EXPECT_GT(truth.half_distance_m, std::sqrt(2.0) - 0.05);
    EXPECT_LT(truth.half_distance_m, 2.0 + 0.05);
}

TEST(MapConnectivity, ANodeThatNeverListenedSaysNothing)
{
    MapProblem problem = ladder();
    const ConnectivityFit all = connectivityCost(problem, placedAt(problem, truePosition));
    problem.listens[5] = 0;
    const ConnectivityFit deaf = connectivityCost(problem, placedAt(problem, truePosition));
    EXPECT_EQ(deaf.heard_pairs, all.heard_pairs);
    EXPECT_EQ(deaf.unheard_pairs, all.unheard_pairs - (2 * kRungs - 1 - problem.neighbours[5].size()));
}

TEST(MapConnectivity, FewerThanThreePlacedNodesCostNothing)
{
    const MapProblem problem = ladder();
    MapEstimate estimate = MapEstimate::unplaced(problem.nodeCount());
    estimate.placed[0] = estimate.placed[1] = 1;
    estimate.position_m[1] = Vector2(0.0, 1.0);
    const ConnectivityFit fit = connectivityCost(problem, estimate);
    EXPECT_EQ(fit.cost_nats, 0.0);
    EXPECT_EQ(fit.heard_pairs + fit.unheard_pairs, 0U);
}

} // namespace
} // namespace cdro::engine
