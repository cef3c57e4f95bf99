// The families of buildings: a seed is a building (the same seed, the same files, bit for bit);
// each family has the shape its name promises; the streams deliver what a device would, in the
// orders they say.
#include <algorithm>
#include <cmath>
#include <map>
#include <set>

#include <gtest/gtest.h>

#include "cdro/netgen/families.hpp"
#include "cdro/netgen/stream.hpp"

namespace cdro::netgen {
namespace {

bool sameWorld(const World &a, const World &b)
{
    if (a.nodes.size() != b.nodes.size() || a.links.size() != b.links.size()) {
        return false;
    }
    for (size_t i = 0; i < a.nodes.size(); ++i) {
        if (a.nodes[i].id != b.nodes[i].id || a.nodes[i].position_m != b.nodes[i].position_m ||
            a.nodes[i].antenna_delay_m != b.nodes[i].antenna_delay_m) {
            return false;
        }
    }
    for (size_t i = 0; i < a.links.size(); ++i) {
        if (a.links[i].a != b.links[i].a || a.links[i].b != b.links[i].b ||
            a.links[i].excess_m != b.links[i].excess_m) {
            return false;
        }
    }
    return true;
}

TEST(Netgen, ASeedIsABuilding)
{
    for (Family family : allFamilies()) {
        SCOPED_TRACE(familyName(family));
        const World first = makeWorld(family, 7);
        EXPECT_TRUE(sameWorld(first, makeWorld(family, 7)));
        EXPECT_FALSE(sameWorld(first, makeWorld(family, 8)));
        EXPECT_TRUE(first.connected());
        EXPECT_EQ(first.family, familyName(family));
        EXPECT_FALSE(first.description.empty());
        // Ids distinct, never 0, not in the order of the nodes.
        std::set<NodeId> ids;
        for (const WorldNode &node : first.nodes) {
            EXPECT_GE(node.id, 0x1000);
            ids.insert(node.id);
        }
        EXPECT_EQ(ids.size(), first.nodes.size());
        EXPECT_FALSE(std::is_sorted(first.nodes.begin(), first.nodes.end(),
                                    [](const WorldNode &x, const WorldNode &y) { return x.id < y.id; }));
        // No NLOS reading is short: every persistent error is an excess.
        for (const WorldLink &link : first.links) {
            EXPECT_GE(first.biasM(link), 0.0);
        }
    }
}

TEST(Netgen, FamiliesHaveTheirShape)
{
    for (uint64_t seed = 1; seed <= 6; ++seed) {
        SCOPED_TRACE(::testing::Message() << "seed " << seed);
        const World random = makeWorld(Family::Random, seed);
        EXPECT_GE(random.nodes.size(), 15U);
        EXPECT_LE(random.nodes.size(), 19U);
        EXPECT_NEAR(2.0 * static_cast<double>(random.links.size()) / static_cast<double>(random.nodes.size()), 10.0,
                    0.5);

        const World corridor = makeWorld(Family::Corridor, seed);
        EXPECT_GE(corridor.nodes.size(), 30U - 10U); // thinned draws may fall a little short
        EXPECT_LE(corridor.nodes.size(), 80U);
        EXPECT_FALSE(corridor.walls.empty());
        // Links through walls read longer (the excess grows with the walls crossed).
        double through = 0.0;
        double open = 0.0;
        size_t through_count = 0;
        size_t open_count = 0;
        for (const WorldLink &link : corridor.links) {
            (link.walls > 0 ? through : open) += link.excess_m;
            (link.walls > 0 ? through_count : open_count) += 1;
        }
        ASSERT_GT(through_count, 0U);
        ASSERT_GT(open_count, 0U);
        EXPECT_GT(through / static_cast<double>(through_count), open / static_cast<double>(open_count));

        const World wings = makeWorld(Family::Wings, seed);
        size_t joins = 0;
        for (const WorldLink &link : wings.links) {
            joins += link.walls == 1 ? 1U : 0U; // the links between wings, through the wings' walls
        }
        EXPECT_GE(joins, 2U);
        EXPECT_LE(joins, 8U); // 2-4 per pair of wings, two pairs at most

        const World biased = makeWorld(Family::Biased, seed);
        const size_t n = biased.nodes.size();
        EXPECT_EQ(biased.links.size(), n * (n - 1) / 2); // every pair heard
        EXPECT_LT(biased.noise.sigma_m, 0.05);
        double largest = 0.0;
        for (const WorldLink &link : biased.links) {
            largest = std::max(largest, biased.biasM(link));
        }
        EXPECT_GT(largest, 0.8);
        EXPECT_LE(largest, 2.0);
    }
    const World walls = makeWorld(Family::Walls, 3);
    EXPECT_GE(walls.nodes.size(), 100U);
    EXPECT_LE(walls.nodes.size(), 200U);
    std::map<uint32_t, std::pair<double, size_t>> by_walls;
    for (const WorldLink &link : walls.links) {
        by_walls[link.walls].first += link.excess_m;
        by_walls[link.walls].second += 1;
    }
    ASSERT_GE(by_walls.size(), 3U);
    double previous = -1.0;
    for (const auto &[count, sum] : by_walls) {
        const double mean = sum.first / static_cast<double>(sum.second);
        EXPECT_GT(mean, previous) << count << " walls";
        previous = mean;
    }
}

TEST(Netgen, OptionsPinWhatTheyName)
{
    FamilyOptions options;
    options.nodes = 300;
    const World big = makeWorld(Family::Random, 2, options);
    EXPECT_EQ(big.nodes.size(), 300U);
    options.heights_known = false;
    for (const WorldNode &node : makeWorld(Family::Corridor, 2, options).nodes) {
        EXPECT_FALSE(node.height_known);
    }
}

// --nodes is a user's option: every family draws that many nodes (at its own density: a room that
// holds 12 by default holds 60 as a larger room), and never loops forever looking for room.
TEST(Netgen, EveryFamilyDrawsTheNodesAskedFor)
{
    FamilyOptions options;
    options.nodes = 60;
    for (Family family : allFamilies()) {
        SCOPED_TRACE(familyName(family));
        const World world = makeWorld(family, 3, options);
        // Wings share the count among their two or three wings.
        EXPECT_GE(world.nodes.size(), 58U);
        EXPECT_LE(world.nodes.size(), 60U);
    }
}

TEST(Netgen, SweepsRangeEveryLinkOncePerSweep)
{
    const World world = makeWorld(Family::Random, 4);
    StreamOptions options;
    options.sweeps = 5;
    const GeneratedStream stream = generateStream(world, options);
    EXPECT_EQ(stream.ranges.size(), 5 * world.links.size());
    std::map<std::pair<NodeId, NodeId>, int> count;
    for (const GeneratedRange &range : stream.ranges) {
        count[{std::min(range.from, range.to), std::max(range.from, range.to)}] += 1;
        EXPECT_GT(range.range_m, 0.0);
    }
    EXPECT_EQ(count.size(), world.links.size());
    for (const auto &[pair, n] : count) {
        EXPECT_EQ(n, 5);
    }
    for (size_t i = 1; i < stream.ranges.size(); ++i) {
        EXPECT_GT(stream.ranges[i].t_s, stream.ranges[i - 1].t_s);
    }
}

TEST(Netgen, StaggeredAndLateNodesComeOnLater)
{
    const World world = makeWorld(Family::Random, 5);
    StreamOptions staggered;
    staggered.order = StreamOrder::Staggered;
    staggered.stagger_s = 60.0;
    const GeneratedStream on_by_one = generateStream(world, staggered);
    std::map<NodeId, double> first_s;
    for (const GeneratedRange &range : on_by_one.ranges) {
        first_s.emplace(range.from, range.t_s);
        first_s.emplace(range.to, range.t_s);
    }
    double latest = 0.0;
    for (const auto &[id, t] : first_s) {
        latest = std::max(latest, t);
    }
    EXPECT_GT(latest, 10.0); // nodes appear over the first minute
    EXPECT_LT(latest, 70.0);

    StreamOptions late;
    late.order = StreamOrder::Late;
    late.sweeps = 10;
    late.late_sweeps = 6;
    const GeneratedStream one_late = generateStream(world, late);
    ASSERT_NE(one_late.late_node, 0);
    size_t before_late = 0;
    for (const GeneratedRange &range : one_late.ranges) {
        if (range.from == one_late.late_node || range.to == one_late.late_node) {
            break;
        }
        ++before_late;
    }
    // The late node's first range comes after ten sweeps of the others.
    size_t late_links = 0;
    for (const WorldLink &link : world.links) {
        late_links +=
            (world.nodes[link.a].id == one_late.late_node || world.nodes[link.b].id == one_late.late_node) ? 1U : 0U;
    }
    EXPECT_GE(before_late, 10 * (world.links.size() - late_links));
}

TEST(Netgen, AShuffleKeepsTheRanges)
{
    const World world = makeWorld(Family::Wings, 3);
    const GeneratedStream stream = generateStream(world, StreamOptions{});
    const std::vector<GeneratedRange> shuffled = shuffledStream(stream.ranges, 99);
    ASSERT_EQ(shuffled.size(), stream.ranges.size());
    std::vector<double> a;
    std::vector<double> b;
    for (size_t i = 0; i < shuffled.size(); ++i) {
        a.push_back(stream.ranges[i].range_m);
        b.push_back(shuffled[i].range_m);
    }
    EXPECT_NE(a, b);
    std::sort(a.begin(), a.end());
    std::sort(b.begin(), b.end());
    EXPECT_EQ(a, b);
}

TEST(Netgen, WallsAreCountedWhereTheyAre)
{
    const std::vector<WallSegment> walls{{Vector2(1.0, -1.0), Vector2(1.0, 1.0)},
                                         {Vector2(2.0, -1.0), Vector2(2.0, 1.0)}};
    EXPECT_EQ(wallsCrossed(walls, Vector2(0.0, 0.0), Vector2(3.0, 0.0)), 2U);
    EXPECT_EQ(wallsCrossed(walls, Vector2(0.0, 0.0), Vector2(1.5, 0.0)), 1U);
    EXPECT_EQ(wallsCrossed(walls, Vector2(0.0, 2.0), Vector2(3.0, 2.0)), 0U);  // above them
    EXPECT_EQ(wallsCrossed(walls, Vector2(1.0, -2.0), Vector2(1.0, 2.0)), 0U); // along one
}

} // namespace
} // namespace cdro::netgen
