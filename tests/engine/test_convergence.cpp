// convergence.hpp's whole-map checks on small hand-made maps: a node is converged only when the
// nodes that vouch for it determine it. A junction node on a line of fixed nodes, its position
// across the line held by two nodes off the line: when those two are in doubt, so is it. And
// through the whole engine, a network whose map depends on a decision the ranges barely make.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/convergence.hpp"
#include "cdro/engine/engine.hpp"
#include "cdro/engine/params.hpp"
#include "cdro/netgen/families.hpp"
#include "cdro/netgen/stream.hpp"
#include "support.hpp"

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

// "Converged" promises the node within the metre wherever a map about as good places it. A node
// whose 95 % region is 0.4 m: a rival map 0.7 m away, with a region as large, could hold it 1.1 m
// from here, so it is disputed; 0.5 m away, 0.9 m, it is not. Where offsets-or-none was barely
// decided the other model's map reaches as far as it says. A region of a metre or more is not
// judged here: the node is flexible.
TEST(Convergence, ANodeIsDisputedWhereAMapAboutAsGoodCouldHoldItBeyondTheMetre)
{
    EXPECT_TRUE(disputedByOtherMaps(0.4, 0.7, 0.0, 1.0));
    EXPECT_FALSE(disputedByOtherMaps(0.4, 0.5, 0.0, 1.0));
    EXPECT_TRUE(disputedByOtherMaps(0.4, 0.0, 1.0, 1.0));
    EXPECT_FALSE(disputedByOtherMaps(0.4, 0.0, 0.9, 1.0));
    EXPECT_FALSE(disputedByOtherMaps(1.2, 3.0, 3.0, 1.0));
}

// What the map holds is what the fallback motion detector measures a node's ranges against: a
// still node settled where the global solve put it, converged, or flexible with its 95 % region
// within the metre (a small room's corner held across by one wall link); not one with a rival
// position, nor one whose estimate still moves, nor a moving one.
TEST(Convergence, TheMapHoldsSettledNodesThatAreConvergedOrOnlyFlexible)
{
    const EngineParams params;
    const RangeLikelihood likelihood(params.likelihood);
    const Convergence convergence(params, likelihood);
    MapState map;
    const uint32_t node = map.addNode(1);
    NodeState &state = map.nodes[node];
    state.lifecycle = NodeLifecycle::Placed;
    state.position_m = Vector2(3.0, 4.0);
    state.solve.solved = true;
    state.solve.position_m = state.position_m;
    state.still_updates = params.convergence.consecutive;
    state.update_count = params.convergence.min_updates;

    state.doubt = NodeDoubt::Flexible;
    EXPECT_TRUE(convergence.holds(map, node));
    state.still_updates = params.convergence.consecutive - 1; // eq. 16 not still yet
    EXPECT_FALSE(convergence.holds(map, node));
    state.still_updates = params.convergence.consecutive;
    state.position_m += Vector2(params.convergence.reliable_m, 0.0); // away from the solve's map
    EXPECT_FALSE(convergence.holds(map, node));
    state.position_m = state.solve.position_m;
    state.solve.covariance_m2 = Matrix2::Identity() * 0.25; // m^2: its 95 % region 1.2 m, beyond the metre
    EXPECT_FALSE(convergence.holds(map, node));
    state.solve.covariance_m2 = Matrix2::Identity() * 0.01; // m^2: 0.24 m
    EXPECT_TRUE(convergence.holds(map, node));
    for (const NodeDoubt rival : {NodeDoubt::Ambiguous, NodeDoubt::TooFewLinks, NodeDoubt::Foldable}) {
        state.doubt = rival;
        EXPECT_FALSE(convergence.holds(map, node)) << nodeDoubtName(rival);
    }
    state.doubt = NodeDoubt::None;
    state.lifecycle = NodeLifecycle::Converged;
    EXPECT_TRUE(convergence.holds(map, node));
    state.lifecycle = NodeLifecycle::Moving;
    EXPECT_FALSE(convergence.holds(map, node));
    state.lifecycle = NodeLifecycle::Placed;
    state.role = NodeRole::Fixed;
    EXPECT_TRUE(convergence.holds(map, node));
}

// Runs a netgen stream through the engine (heights known) and checks the promise: no node the
// engine calls converged is more than 1 m off, the converged nodes fitted on their own.
void expectNoConvergedNodeBeyondTheMetre(const netgen::World &world, const std::vector<netgen::GeneratedRange> &ranges)
{
    Engine engine;
    for (const netgen::WorldNode &node : world.nodes) {
        engine.setHeight(node.id, node.position_m.z());
    }
    for (const netgen::GeneratedRange &range : ranges) {
        engine.addRange(range.from, range.to, range.range_m, range.t_s);
    }
    engine.settle(200ULL * world.nodes.size() + 1000ULL);

    std::vector<Vector2> estimated_m;
    std::vector<Vector2> truth_m;
    std::vector<NodeId> converged;
    for (const netgen::WorldNode &node : world.nodes) {
        const std::optional<NodeOutput> out = engine.estimate(node.id);
        ASSERT_TRUE(out.has_value());
        if (out->converged()) {
            estimated_m.push_back(out->position_m);
            truth_m.push_back(node.position_m.head<2>());
            converged.push_back(node.id);
        }
    }
    std::vector<Vector2> all_m;
    std::vector<Vector2> all_truth_m;
    for (const netgen::WorldNode &node : world.nodes) {
        all_m.push_back(engine.estimate(node.id)->position_m);
        all_truth_m.push_back(node.position_m.head<2>());
    }
    const RigidTransform all = fitRigid(all_m, all_truth_m, true);
    double squared_m2 = 0.0;
    for (size_t i = 0; i < all_m.size(); ++i) {
        squared_m2 += (all.apply(all_m[i]) - all_truth_m[i]).squaredNorm();
    }
    std::printf("map %.3f m RMSE, %zu of %zu nodes converged\n",
                std::sqrt(squared_m2 / static_cast<double>(all_m.size())), converged.size(), world.nodes.size());
    if (converged.size() < 2) {
        return; // nothing to fit: no promise made that could be broken
    }
    const RigidTransform fit = fitRigid(estimated_m, truth_m, true);
    for (size_t i = 0; i < converged.size(); ++i) {
        EXPECT_LE((fit.apply(estimated_m[i]) - truth_m[i]).norm(), 1.0) << "node " << converged[i];
    }
}

// Uncalibrated radios in a small room (netgen's `biased` family, seed 10: 8 nodes, every pair,
// delays of 0-0.9 m, 0.02 m noise), in the order the scorecard shuffles it into (docs/results.md).
// In that order the range offsets win by less than their margin (16 nats for 18), so the map is the
// one bent to fit the delays (0.72 m RMSE; with the offsets, in the other orders, 0.28 m), and it
// called all 8 nodes converged, 3 of them 1.0-1.1 m off, inside 2-sigma ellipses of 0.15 m. Where
// the evidence barely tells the two models apart, the other model's map and its 95 % regions are
// where the node may be too: no node the engine calls converged may be more than 1 m off.
TEST(Convergence, NoNodeIsConvergedWhereOffsetsOrNoneIsBarelyDecided)
{
    const netgen::World world = netgen::makeWorld(netgen::Family::Biased, 10);
    netgen::StreamOptions options;
    options.seed = 10;
    expectNoConvergedNodeBeyondTheMetre(world,
                                        netgen::shuffledStream(netgen::generateStream(world, options).ranges, 1001));
}

// Two wings at 20 % NLOS (`cdro-netgen --family wings --seed 33 --nlos-fraction 0.2 --order late`,
// docs/results.md, "Variants nobody had run"): node 0x63CC has three of its six links 0.8-1.5 m
// long, and the map puts it 1.27 m off, where two of them fit, its neighbours bent 0.1-0.5 m to
// suit. With them held, its place on the truth's side costs 3.6 nats more and it was called
// converged; with them following it (second_place.hpp), 2.5 nats: a rival, so it is ambiguous.
TEST(Convergence, NoNodeIsConvergedWhereItsNeighboursCouldFollowItToASecondPlace)
{
    netgen::FamilyOptions family;
    family.nlos_fraction = 0.2;
    const netgen::World world = netgen::makeWorld(netgen::Family::Wings, 33, family);
    netgen::StreamOptions options;
    options.seed = 33;
    options.order = netgen::StreamOrder::Late;
    expectNoConvergedNodeBeyondTheMetre(world, netgen::generateStream(world, options).ranges);
}

// Three wings joined by two to four links each, two of the four between wings 0 and 1 through a
// wall 0.64-0.69 m long (`cdro-netgen --family wings --seed 45`, docs/results.md, "Seeds nobody had
// run"): each wing is mapped within 3 cm, but where wing 0 stands against wing 1 only the four
// links say, one redundant, and the two long ones turn it: eight of its nodes were called
// converged, up to 1.48 m off, though one link error too small to be noticed could move the far
// ones 1.5-2.3 m (Baarda's reliability): under the 2.5 m the check allowed, beyond the metre
// promised.
TEST(Convergence, NoNodeIsConvergedThatOneUnnoticedLinkErrorCouldMoveBeyondTheMetre)
{
    CDRO_SKIP_WHEN_SANITIZED(); // 61 nodes, 492 links
    const netgen::World world = netgen::makeWorld(netgen::Family::Wings, 45);
    netgen::StreamOptions options;
    options.seed = 45;
    expectNoConvergedNodeBeyondTheMetre(world, netgen::generateStream(world, options).ranges);
}

} // namespace
} // namespace cdro::engine
