// mds: classical MDS on shortest-path distances. Exact (up to a rigid transform) when every
// pair is linked with its exact distance; nothing for disconnected or too small sets.
#include <gtest/gtest.h>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/mds.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::Network;

// A network with the given links at their true distances (representative ranges).
Network networkOf(const std::vector<Vector2> &truth_m, const std::vector<std::pair<size_t, size_t>> &links)
{
    Network network;
    for (size_t i = 0; i < truth_m.size(); ++i) {
        network.addNode(static_cast<NodeId>(100 + 3 * i));
    }
    for (const auto &[a, b] : links) {
        const uint32_t link = network.addLink(static_cast<uint32_t>(a), static_cast<uint32_t>(b), 15);
        network.links[link].representative_m = (truth_m[a] - truth_m[b]).norm();
    }
    return network;
}

std::vector<std::pair<size_t, size_t>> allPairs(size_t count)
{
    std::vector<std::pair<size_t, size_t>> links;
    for (size_t i = 0; i < count; ++i) {
        for (size_t j = i + 1; j < count; ++j) {
            links.emplace_back(i, j);
        }
    }
    return links;
}

TEST(Mds, CompleteExactGraphsAreLaidOutExactly)
{
    const uint64_t seed = testSeed(3401);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    for (size_t count : {3U, 4U, 10U, 25U}) {
        for (int trial = 0; trial < 5; ++trial) {
            std::vector<Vector2> truth_m;
            for (size_t i = 0; i < count; ++i) {
                truth_m.emplace_back(random.uniform(-30.0, 30.0), random.uniform(-30.0, 30.0));
            }
            const Network network = networkOf(truth_m, allPairs(count));
            // Members in a scrambled order: the layout follows the order asked for.
            std::vector<uint32_t> members(count);
            for (size_t i = 0; i < count; ++i) {
                members[i] = static_cast<uint32_t>(i);
            }
            random.shuffle(members);
            const auto layout = engine::mdsLayout(network, members);
            ASSERT_TRUE(layout.has_value());
            ASSERT_EQ(layout->size(), count);
            std::vector<Vector2> target;
            for (uint32_t member : members) {
                target.push_back(truth_m[member]);
            }
            const engine::RigidTransform fit = engine::fitRigid(*layout, target, true);
            EXPECT_LT(fit.rms_error_m, 1e-9) << count << " nodes, trial " << trial;
            // Centred, as classical MDS is.
            Vector2 mean = Vector2::Zero();
            for (const Vector2 &p : *layout) {
                mean += p;
            }
            EXPECT_LT((mean / static_cast<double>(count)).norm(), 1e-9);
        }
    }
}

TEST(Mds, AnIncompleteGraphGivesACoarseLayout)
{
    // A 4 x 4 grid with its edges and the diagonals of its cells: shortest paths overestimate
    // the longer distances, so the layout is not exact, but it lays out every node about right
    // (0.44 m RMS on a 15 m grid; without the diagonals it is 3 m).
    std::vector<Vector2> truth_m;
    for (int y = 0; y < 4; ++y) {
        for (int x = 0; x < 4; ++x) {
            truth_m.emplace_back(5.0 * x, 5.0 * y);
        }
    }
    std::vector<std::pair<size_t, size_t>> links;
    for (size_t i = 0; i < 16; ++i) {
        if (i % 4 != 3) {
            links.emplace_back(i, i + 1);
        }
        if (i + 4 < 16) {
            links.emplace_back(i, i + 4);
            if (i % 4 != 3) {
                links.emplace_back(i, i + 5);
            }
            if (i % 4 != 0) {
                links.emplace_back(i, i + 3);
            }
        }
    }
    const Network network = networkOf(truth_m, links);
    std::vector<uint32_t> members;
    for (uint32_t i = 0; i < 16; ++i) {
        members.push_back(i);
    }
    const auto layout = engine::mdsLayout(network, members);
    ASSERT_TRUE(layout.has_value());
    const engine::RigidTransform fit = engine::fitRigid(*layout, truth_m, true);
    EXPECT_GT(fit.rms_error_m, 1e-3);
    EXPECT_LT(fit.rms_error_m, 1.0);
}

TEST(Mds, DisconnectedOrTooSmallSetsGiveNothing)
{
    const std::vector<Vector2> truth_m = {Vector2(0, 0), Vector2(4, 0), Vector2(0, 4),
                                          Vector2(20, 0), Vector2(24, 0), Vector2(20, 4)};
    // Two triangles with no link between them.
    const Network network = networkOf(truth_m, {{0, 1}, {0, 2}, {1, 2}, {3, 4}, {3, 5}, {4, 5}});
    EXPECT_FALSE(engine::mdsLayout(network, {0, 1, 2, 3, 4, 5}).has_value());
    EXPECT_TRUE(engine::mdsLayout(network, {0, 1, 2}).has_value());
    EXPECT_TRUE(engine::mdsLayout(network, {3, 4, 5}).has_value());
    EXPECT_FALSE(engine::mdsLayout(network, {0, 1}).has_value());
    EXPECT_FALSE(engine::mdsLayout(network, {}).has_value());
    // Connected in the network, but only through a node left out of the set.
    const Network chain = networkOf(truth_m, {{0, 1}, {1, 2}, {2, 3}, {0, 2}});
    EXPECT_TRUE(engine::mdsLayout(chain, {0, 1, 2, 3}).has_value());
    EXPECT_FALSE(engine::mdsLayout(chain, {0, 1, 3}).has_value());
}

} // namespace
} // namespace cdro::enginetest
