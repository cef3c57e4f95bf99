// Foldable parts of the link graph (foldable.hpp): hand-made graphs with known cuts, the
// property that a globally rigid network has none (checked against the rigidity-matrix test of
// support.hpp, an independent method), and the engine's outputs on a network with a hinge.
#include <array>
#include <cmath>
#include <cstdio>
#include <set>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/engine/engine.hpp"
#include "cdro/engine/foldable.hpp"
#include "cdro/netgen/geometric.hpp"
#include "support.hpp"

namespace {

using cdro::engine::Engine;
using cdro::engine::findFoldable;
using cdro::engine::Foldable;
using cdro::engine::kNoHinge;
using cdro::engine::NodeOutput;
using cdro::engine::twoLinkCuts;
using cdro::engine::Vector2;
using cdro::enginetest::Random;
using cdro::enginetest::TestNetwork;
using Edges = std::vector<std::pair<uint32_t, uint32_t>>;

void addClique(Edges &edges, std::vector<uint32_t> nodes)
{
    for (size_t i = 0; i < nodes.size(); ++i) {
        for (size_t j = i + 1; j < nodes.size(); ++j) {
            edges.emplace_back(nodes[i], nodes[j]);
        }
    }
}

Foldable foldableOf(uint32_t count, const Edges &edges, std::vector<uint8_t> anchored = {})
{
    anchored.resize(count, 0);
    return findFoldable(count, edges, std::vector<uint8_t>(count, 1), anchored);
}

std::set<uint32_t> marked(const Foldable &folds)
{
    std::set<uint32_t> out;
    for (uint32_t node = 0; node < folds.foldable.size(); ++node) {
        if (folds.foldable[node] != 0) {
            out.insert(node);
        }
    }
    return out;
}

TEST(TwoLinkCuts, TwoLinksJoiningTwoCliquesAreTheOnlyCut)
{
    // Two complete graphs of five, joined by two links: those two, and nothing else.
    Edges edges;
    addClique(edges, {0, 1, 2, 3, 4});
    addClique(edges, {5, 6, 7, 8, 9});
    const auto first = static_cast<uint32_t>(edges.size());
    edges.emplace_back(1, 6);
    edges.emplace_back(3, 9);
    const std::vector<uint8_t> all(10, 1);
    const std::vector<std::array<uint32_t, 2>> cuts = twoLinkCuts(10, edges, all);
    ASSERT_EQ(cuts.size(), 1U);
    EXPECT_EQ(cuts[0], (std::array<uint32_t, 2>{first, first + 1}));
    // The same links listed first: the same cut, by their new indices.
    Edges reordered = {{3, 9}, {1, 6}};
    reordered.insert(reordered.end(), edges.begin(), edges.begin() + first);
    EXPECT_EQ(twoLinkCuts(10, reordered, all), (std::vector<std::array<uint32_t, 2>>{{0, 1}}));
    // A third link makes the joint rigid: no cut of two.
    Edges three = edges;
    three.emplace_back(2, 7);
    EXPECT_TRUE(twoLinkCuts(10, three, all).empty());
    // One link alone is a bridge, not a cut of two.
    Edges bridge = edges;
    bridge.pop_back();
    EXPECT_TRUE(twoLinkCuts(10, bridge, all).empty());
    // Without node 9 (inactive) the second link is gone: a bridge again.
    std::vector<uint8_t> without_nine = all;
    without_nine[9] = 0;
    EXPECT_TRUE(twoLinkCuts(10, edges, without_nine).empty());
}

TEST(TwoLinkCuts, AChainOfThreeCliquesHasTwoAndARingOfCliquesNone)
{
    // Cliques 0-3, 4-7, 8-11 in a chain, each joint of two links.
    Edges chain;
    addClique(chain, {0, 1, 2, 3});
    addClique(chain, {4, 5, 6, 7});
    addClique(chain, {8, 9, 10, 11});
    const auto joints = static_cast<uint32_t>(chain.size());
    chain.emplace_back(0, 4);
    chain.emplace_back(1, 5);
    chain.emplace_back(6, 8);
    chain.emplace_back(7, 9);
    EXPECT_EQ(twoLinkCuts(12, chain, std::vector<uint8_t>(12, 1)),
              (std::vector<std::array<uint32_t, 2>>{{joints, joints + 1}, {joints + 2, joints + 3}}));
    // The same cliques in a ring joined by single links: any two of the three cut it, and none
    // is listed (joints of exactly two links only).
    Edges ring;
    addClique(ring, {0, 1, 2, 3});
    addClique(ring, {4, 5, 6, 7});
    addClique(ring, {8, 9, 10, 11});
    ring.emplace_back(0, 4);
    ring.emplace_back(5, 8);
    ring.emplace_back(9, 1);
    EXPECT_TRUE(twoLinkCuts(12, ring, std::vector<uint8_t>(12, 1)).empty());
}

TEST(Foldable, ACompleteGraphAndAWheelHaveNone)
{
    Edges complete;
    addClique(complete, {0, 1, 2, 3, 4});
    EXPECT_EQ(foldableOf(5, complete).count, 0U);
    // A wheel (hub 0, rim 1..40 in a cycle) is 3-connected.
    Edges wheel;
    for (uint32_t rim = 1; rim <= 40; ++rim) {
        wheel.emplace_back(0, rim);
        wheel.emplace_back(rim, rim == 40 ? 1 : rim + 1);
    }
    EXPECT_EQ(foldableOf(41, wheel).count, 0U);
}

TEST(Foldable, ANodeWithTwoLinksHangsOnThem)
{
    Edges edges;
    addClique(edges, {0, 1, 2, 3});
    edges.emplace_back(4, 1);
    edges.emplace_back(3, 4);
    edges.emplace_back(4, 3); // a duplicate changes nothing
    const Foldable folds = foldableOf(5, edges);
    EXPECT_EQ(marked(folds), (std::set<uint32_t>{4}));
    EXPECT_EQ(folds.hinge[4], (std::array<uint32_t, 2>{1, 3}));
    EXPECT_EQ(folds.count, 1U);
}

// A: 0..5 complete; B: 6, 7, 8 complete, each linked to 4 and 5 only (both link directions).
Edges groupOnTwoNodes()
{
    Edges edges;
    addClique(edges, {0, 1, 2, 3, 4, 5});
    addClique(edges, {6, 7, 8});
    for (uint32_t b : {6U, 7U, 8U}) {
        edges.emplace_back(b, 4);
        edges.emplace_back(5, b);
    }
    return edges;
}

TEST(Foldable, AGroupOnTwoNodesFoldsAndTheLargerPartStays)
{
    Edges edges = groupOnTwoNodes();
    const Foldable folds = foldableOf(9, edges);
    EXPECT_EQ(marked(folds), (std::set<uint32_t>{6, 7, 8}));
    for (uint32_t b : {6U, 7U, 8U}) {
        EXPECT_EQ(folds.hinge[b], (std::array<uint32_t, 2>{4, 5}));
    }
    // One more link from B to A (not to the hinge) makes it rigid.
    edges.emplace_back(7, 0);
    EXPECT_EQ(foldableOf(9, edges).count, 0U);
}

TEST(Foldable, APartOnOneNodeTurnsAboutIt)
{
    Edges edges;
    addClique(edges, {0, 1, 2, 3});
    addClique(edges, {3, 4, 5});
    const Foldable folds = foldableOf(6, edges);
    EXPECT_EQ(marked(folds), (std::set<uint32_t>{4, 5}));
    EXPECT_EQ(folds.hinge[4], (std::array<uint32_t, 2>{3, kNoHinge}));
}

TEST(Foldable, NodesOutsideTheLargestComponentAndInactiveNodes)
{
    Edges edges;
    addClique(edges, {0, 1, 2, 3});
    edges.emplace_back(4, 5);
    Foldable folds = foldableOf(6, edges);
    EXPECT_EQ(marked(folds), (std::set<uint32_t>{4, 5}));
    EXPECT_EQ(folds.hinge[5], (std::array<uint32_t, 2>{kNoHinge, kNoHinge}));
    // Node 6 linked to three of the clique is rigid; without node 6 (inactive: e.g. unplaced)
    // the edge 4-5 is still apart, and node 6 is never marked.
    edges.emplace_back(6, 0);
    edges.emplace_back(6, 1);
    edges.emplace_back(6, 2);
    std::vector<uint8_t> active(7, 1);
    active[6] = 0;
    folds = findFoldable(7, edges, active, std::vector<uint8_t>(7, 0));
    EXPECT_EQ(marked(folds), (std::set<uint32_t>{4, 5}));
}

TEST(Foldable, APartHoldingAFixedNodeIsNotMarked)
{
    std::vector<uint8_t> anchored(9, 0);
    anchored[7] = 1;
    EXPECT_EQ(foldableOf(9, groupOnTwoNodes(), anchored).count, 0U);
}

TEST(Foldable, ATriangleStripFoldsAlongItsLength)
{
    // Each node linked to the next two: 2-connected, every consecutive pair a cut.
    Edges edges;
    for (uint32_t i = 0; i + 1 < 12; ++i) {
        edges.emplace_back(i, i + 1);
        if (i + 2 < 12) {
            edges.emplace_back(i, i + 2);
        }
    }
    const Foldable folds = foldableOf(12, edges);
    EXPECT_GT(folds.count, 0U);
    EXPECT_TRUE(folds.foldable[11] != 0 || folds.foldable[0] != 0);
}

// Property: 3-connectivity is necessary for global rigidity, so a network that the rigidity
// matrix and its stresses call globally rigid has no foldable node; and the sparse draws
// (degree 3-5) give many with folds, which must then be called not globally rigid.
TEST(Foldable, AGloballyRigidNetworkHasNoFoldableNode)
{
    const uint64_t seed = cdro::enginetest::testSeed(20261201);
    SCOPED_TRACE(cdro::enginetest::seedTrace(seed));
    std::printf("Foldable property test: %s\n", cdro::enginetest::seedTrace(seed).c_str());
    Random random(seed);
    uint32_t rigid = 0;
    uint32_t with_folds = 0;
    for (int draw = 0; draw < 150; ++draw) {
        const size_t count = 6 + random.below(20);
        // One node per 100 m^2, linked within 0.3-0.6 of the square's side, connected or not.
        cdro::netgen::GeometricOptions options;
        options.nodes = static_cast<uint32_t>(count);
        options.area_per_node_m2 = 100.0;
        options.radius = cdro::netgen::GeometricOptions::Radius::Given;
        options.radius_m = std::sqrt(100.0 * static_cast<double>(count)) * random.uniform(0.3, 0.6);
        options.require_connected = false;
        options.min_degree = 0;
        options.max_attempts = 1; // every draw is kept
        const TestNetwork network = cdro::enginetest::fromGeometric(cdro::netgen::drawGeometric(random, options));
        Edges edges;
        for (const auto &[a, b] : network.links) {
            edges.emplace_back(static_cast<uint32_t>(a), static_cast<uint32_t>(b));
        }
        const Foldable folds = foldableOf(static_cast<uint32_t>(count), edges);
        const bool globally_rigid = cdro::enginetest::globallyRigid(network, random);
        rigid += globally_rigid ? 1U : 0U;
        with_folds += folds.count > 0 ? 1U : 0U;
        EXPECT_FALSE(globally_rigid && folds.count > 0) << "draw " << draw << ": " << count << " nodes";
    }
    std::printf("Foldable property test: %u of 150 draws globally rigid, %u with foldable nodes\n", rigid, with_folds);
    // The draws must exercise both sides, or the property says nothing.
    EXPECT_GT(rigid, 20U);
    EXPECT_GT(with_folds, 20U);
}

// The engine on a network with a hinge, exact ranges: it explains every link either way, and
// the part that can fold is placed but not called converged; the rest is.
TEST(Foldable, TheEngineDoesNotCallAFoldablePartConverged)
{
    TestNetwork network;
    const std::vector<Vector2> positions_m = {{0, 0},  {8, 0},   {12, 6}, {4, 9},  {10, 12},
                                              {2, 14}, {14, 20}, {6, 21}, {10, 26}};
    for (size_t i = 0; i < positions_m.size(); ++i) {
        network.ids.push_back(static_cast<cdro::engine::NodeId>(0x100 + i));
        network.truth_m.push_back(positions_m[i]);
    }
    // A: 0..5 complete; B: 6, 7, 8 complete, hanging on 4 and 5.
    for (size_t a = 0; a < 6; ++a) {
        for (size_t b = a + 1; b < 6; ++b) {
            network.links.emplace_back(a, b);
        }
    }
    for (const auto &[a, b] : std::vector<std::pair<size_t, size_t>>{
             {6, 7}, {6, 8}, {7, 8}, {6, 4}, {6, 5}, {7, 4}, {7, 5}, {8, 4}, {8, 5}}) {
        network.links.emplace_back(a, b);
    }
    Random random(7);
    Engine engine;
    cdro::enginetest::feed(engine, network, cdro::enginetest::roundRobin(network, random, 60, 0.0));

    size_t foldable = 0;
    for (const NodeOutput &node : engine.estimates()) {
        ASSERT_TRUE(node.placed()) << node.id;
        const bool in_b = node.id >= 0x106;
        EXPECT_EQ(node.doubt == cdro::engine::NodeDoubt::Foldable, in_b) << node.id;
        if (in_b) {
            EXPECT_FALSE(node.converged()) << node.id;
            ASSERT_EQ(node.hinge_nodes, 2) << node.id;
            EXPECT_EQ(node.hinge[0], 0x104);
            EXPECT_EQ(node.hinge[1], 0x105);
            ++foldable;
        } else {
            EXPECT_TRUE(node.converged()) << node.id;
        }
    }
    EXPECT_EQ(foldable, 3U);
    EXPECT_EQ(engine.counters().convergence.foldable_nodes, 3U);
}

} // namespace
