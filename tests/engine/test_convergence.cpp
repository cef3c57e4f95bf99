// convergence.hpp's whole-map checks on small hand-made maps: a node is converged only when the
// nodes that vouch for it determine it. A junction node on a line of fixed nodes, its position
// across the line held by two nodes off the line: when those two are in doubt, so is it.
#include <gtest/gtest.h>

#include "cdro/engine/convergence.hpp"
#include "cdro/engine/params.hpp"

namespace cdro::engine {
namespace {

// Nodes 0-3: fixed, on the x axis; 4: the junction, on the axis too; 5 and 6: off the axis,
// above and below it, each with links to the fixed nodes on the axis, to two fixed nodes further
// out on its side (7, 8 above; 9, 10 below) and to the junction.
constexpr uint32_t kJunction = 4;
constexpr uint32_t kAbove = 5;
constexpr uint32_t kBelow = 6;

Vector2 positionOf(uint32_t node)
{
    switch (node) {
    case 0: return Vector2(0.0, 0.0);
    case 1: return Vector2(5.0, 0.0);
    case 2: return Vector2(15.0, 0.0);
    case 3: return Vector2(20.0, 0.0);
    case kJunction: return Vector2(10.0, 0.0);
    case kAbove: return Vector2(10.0, 6.0);
    case kBelow: return Vector2(10.0, -6.0);
    case 7: return Vector2(0.0, 10.0);
    case 8: return Vector2(20.0, 10.0);
    case 9: return Vector2(0.0, -10.0);
    default: return Vector2(20.0, -10.0);
    }
}

struct JunctionMap {
    MapProblem problem;
    MapEstimate estimate;
    std::vector<StructureNode> nodes;
};

JunctionMap junctionMap()
{
    JunctionMap map;
    const uint32_t count = 11;
    for (uint32_t node = 0; node < count; ++node) {
        map.problem.ids.push_back(static_cast<NodeId>(10 + node));
    }
    const auto link = [&map](uint32_t a, uint32_t b) {
        map.problem.links.push_back(MapLink{a, b, (positionOf(a) - positionOf(b)).norm()});
    };
    for (uint32_t fixed = 0; fixed < 4; ++fixed) {
        link(fixed, kJunction);
        link(fixed, kAbove);
        link(fixed, kBelow);
    }
    link(kJunction, kAbove);
    link(kJunction, kBelow);
    link(7, kAbove);
    link(8, kAbove);
    link(9, kBelow);
    link(10, kBelow);
    map.problem.fixed.assign(count, 0);
    map.problem.fixed_position_m.assign(count, Vector2::Zero());
    for (uint32_t fixed = 0; fixed < count; ++fixed) {
        if (fixed == kJunction || fixed == kAbove || fixed == kBelow) {
            continue;
        }
        map.problem.fixed[fixed] = 1;
        map.problem.fixed_position_m[fixed] = positionOf(fixed);
    }
    map.problem.listens.assign(count, 1);
    map.problem.finish();
    map.estimate = MapEstimate::unplaced(count);
    map.nodes.resize(count);
    for (uint32_t node = 0; node < count; ++node) {
        map.estimate.placed[node] = 1;
        map.estimate.position_m[node] = positionOf(node);
        StructureNode &n = map.nodes[node];
        n.free = node == kJunction || node == kAbove || node == kBelow;
        n.anchored = !n.free;
        n.covariance_m2 = 0.01 * Matrix2::Identity();
        n.solve.solved = true;
        n.solve.position_m = positionOf(node);
        n.solve.covariance_m2 = 0.01 * Matrix2::Identity();
        n.solve.reliability_m = 0.1;
        n.solve.main_part = true;
    }
    return map;
}

StructureVerdict checked(const JunctionMap &map)
{
    const EngineParams params;
    const RangeLikelihood likelihood(params.likelihood);
    return StructureCheck(params, likelihood).run(map.problem, map.estimate, map.nodes);
}

TEST(StructureCheck, AJunctionHeldAcrossItsLineByUndoubtedNodesIsConverged)
{
    const StructureVerdict verdict = checked(junctionMap());
    EXPECT_EQ(verdict.doubt[kJunction], NodeDoubt::None);
    EXPECT_EQ(verdict.doubt[kAbove], NodeDoubt::None);
    EXPECT_EQ(verdict.doubt[kBelow], NodeDoubt::None);
}

TEST(StructureCheck, AJunctionHeldAcrossItsLineOnlyByDoubtedNodesIsFlexible)
{
    JunctionMap map = junctionMap();
    // A rival map puts both off-axis nodes elsewhere: only the line's nodes vouch for the
    // junction, and along the line's normal they say nothing.
    map.nodes[kAbove].solve.disputed = true;
    map.nodes[kBelow].solve.disputed = true;
    const StructureVerdict verdict = checked(map);
    EXPECT_EQ(verdict.doubt[kAbove], NodeDoubt::Ambiguous);
    EXPECT_EQ(verdict.doubt[kBelow], NodeDoubt::Ambiguous);
    EXPECT_EQ(verdict.doubt[kJunction], NodeDoubt::Flexible);
}

TEST(StructureCheck, OneUndoubtedNodeOffTheLineStillHoldsTheJunction)
{
    JunctionMap map = junctionMap();
    map.nodes[kBelow].solve.disputed = true;
    const StructureVerdict verdict = checked(map);
    EXPECT_EQ(verdict.doubt[kJunction], NodeDoubt::None);
}

} // namespace
} // namespace cdro::engine
