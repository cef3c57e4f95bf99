// The random geometric network (geometric.hpp): a seed is one network, and each option draws
// what geometric.hpp says it does. The engine tests and cdro-bench-engine rely on both.
#include <algorithm>
#include <cmath>
#include <set>
#include <string>
#include <utility>

#include <gtest/gtest.h>

#include "cdro/netgen/geometric.hpp"
#include "cdro/netgen/rigidity.hpp"

namespace cdro::netgen {
namespace {

bool sameNetwork(const GeometricNetwork &a, const GeometricNetwork &b)
{
    if (a.ids != b.ids || a.position_m != b.position_m || a.height_m != b.height_m ||
        a.links.size() != b.links.size()) {
        return false;
    }
    for (size_t i = 0; i < a.links.size(); ++i) {
        if (a.links[i].a != b.links[i].a || a.links[i].b != b.links[i].b ||
            a.links[i].distance_m != b.links[i].distance_m) {
            return false;
        }
    }
    return true;
}

std::set<std::pair<uint32_t, uint32_t>> pairsOf(const GeometricNetwork &net)
{
    std::set<std::pair<uint32_t, uint32_t>> out;
    for (const GeometricLink &link : net.links) {
        out.insert(std::minmax(link.a, link.b));
    }
    return out;
}

GeometricOptions benchOptions(uint32_t nodes)
{
    GeometricOptions options;
    options.nodes = nodes;
    options.draw_directions = true;
    options.shuffle_links = true;
    return options;
}

TEST(Geometric, ASeedIsOneNetworkAndTheDrawSeedReplaysIt)
{
    // A degree of 4 is often disconnected: the accepted draw is seldom the first.
    GeometricOptions options = benchOptions(40);
    options.mean_degree = 4.0;
    const GeometricNetwork first = drawGeometric(3, options);
    EXPECT_GT(first.draws, 1U);
    EXPECT_TRUE(sameNetwork(first, drawGeometric(3, options)));
    EXPECT_FALSE(sameNetwork(first, drawGeometric(4, options)));
    MersenneRandom replay(first.draw_seed);
    const std::optional<GeometricNetwork> again = drawGeometricOnce(replay, options);
    ASSERT_TRUE(again.has_value());
    EXPECT_TRUE(sameNetwork(first, *again));
}

// docs/bench.md's figures were measured on cdro-bench-engine's networks (bench_engine.cpp's
// options): two of them pinned as cdro-bench-engine --one-network N --seed S --write-csv wrote them
// before the generator moved here (truth.csv, and the first link of ranges.csv as fed).
TEST(Geometric, TheBenchmarkNetworksAreTheOnesDocsBenchMdWasMeasuredOn)
{
    struct Pinned {
        uint32_t nodes;
        double degree;
        uint64_t seed;
        size_t links;
        uint32_t draws;
        uint64_t draw_seed;
        Vector2 first_m;   // m, node 1
        Vector2 last_m;    // m, node n
        NodeId first_from; // the first link fed
        NodeId first_to;
    };
    const Pinned pinned[] = {
        {100, 10.0, 2, 501, 1, 17236537114025726793ULL, Vector2(39.520180642108208, 47.043539376494685),
         Vector2(27.264937294329144, 42.297439962710236), 23, 13},
        {40, 4.0, 3, 72, 74, 11336161459575425111ULL, Vector2(35.35713079912135, 8.5942544061839818),
         Vector2(44.375868574209328, 15.828300067286412), 5, 28},
    };
    for (const Pinned &p : pinned) {
        SCOPED_TRACE(std::to_string(p.nodes) + " nodes, seed " + std::to_string(p.seed));
        GeometricOptions options = benchOptions(p.nodes);
        options.mean_degree = p.degree;
        const GeometricNetwork net = drawGeometric(p.seed, options);
        EXPECT_EQ(net.links.size(), p.links);
        EXPECT_EQ(net.draws, p.draws);
        EXPECT_EQ(net.draw_seed, p.draw_seed);
        EXPECT_EQ(net.position_m.front(), p.first_m); // bit for bit (%.17g reads back exactly)
        EXPECT_EQ(net.position_m.back(), p.last_m);
        EXPECT_EQ(net.ids[net.links.front().a], p.first_from);
        EXPECT_EQ(net.ids[net.links.front().b], p.first_to);
    }
}

TEST(Geometric, ExpectedDegreeLinksEveryPairWithinTheRadius)
{
    double degree_sum = 0.0;
    const int draws = 20;
    for (int seed = 0; seed < draws; ++seed) {
        const GeometricNetwork net = drawGeometric(static_cast<uint64_t>(seed), benchOptions(100));
        EXPECT_NEAR(net.side_m, std::sqrt(100.0 * 80.0), 1e-9);
        const std::set<std::pair<uint32_t, uint32_t>> linked = pairsOf(net);
        EXPECT_EQ(linked.size(), net.links.size()) << "a pair linked twice";
        for (uint32_t i = 0; i < 100; ++i) {
            EXPECT_EQ(net.ids[i], i + 1U);
            for (uint32_t j = i + 1; j < 100; ++j) {
                const bool within = (net.position_m[i] - net.position_m[j]).norm() <= net.radius_m;
                EXPECT_EQ(within, linked.count({i, j}) == 1) << i << "-" << j;
            }
        }
        degree_sum += net.mean_degree;
    }
    // The radius is chosen for a mean degree of 10 in expectation (the square's edges included);
    // 20 draws of 100 nodes average within a few percent of it.
    EXPECT_NEAR(degree_sum / draws, 10.0, 0.6);
}

TEST(Geometric, DirectionsAndOrderAreDrawnOnlyWhenAsked)
{
    GeometricOptions plain = benchOptions(30);
    plain.draw_directions = false;
    plain.shuffle_links = false;
    const GeometricNetwork ordered = drawGeometric(5, plain);
    for (size_t k = 0; k < ordered.links.size(); ++k) {
        EXPECT_LT(ordered.links[k].a, ordered.links[k].b);
        if (k > 0) {
            EXPECT_LT(std::make_pair(ordered.links[k - 1].a, ordered.links[k - 1].b),
                      std::make_pair(ordered.links[k].a, ordered.links[k].b))
                << "pair order";
        }
    }
    const GeometricNetwork drawn = drawGeometric(5, benchOptions(30));
    EXPECT_EQ(pairsOf(drawn), pairsOf(ordered)) << "the same pairs: directions and order come after the links";
    size_t reversed = 0;
    for (const GeometricLink &link : drawn.links) {
        reversed += link.a > link.b ? 1U : 0U;
    }
    EXPECT_GT(reversed, drawn.links.size() / 4);
    EXPECT_LT(reversed, 3 * drawn.links.size() / 4);
}

TEST(Geometric, AGivenRadiusLinksThePairsWithinItConnectedOrNot)
{
    GeometricOptions options;
    options.nodes = 30;
    options.area_per_node_m2 = 100.0;
    options.radius = GeometricOptions::Radius::Given;
    options.radius_m = 12.0;
    options.require_connected = false;
    options.min_degree = 0;
    options.max_attempts = 1;
    size_t disconnected = 0;
    for (uint64_t seed = 1; seed <= 20; ++seed) {
        Random random(seed);
        const GeometricNetwork net = drawGeometric(random, options);
        EXPECT_EQ(net.radius_m, 12.0);
        const std::set<std::pair<uint32_t, uint32_t>> linked = pairsOf(net);
        for (uint32_t i = 0; i < 30; ++i) {
            for (uint32_t j = i + 1; j < 30; ++j) {
                EXPECT_EQ((net.position_m[i] - net.position_m[j]).norm() <= 12.0, linked.count({i, j}) == 1);
            }
        }
        GeometricOptions connected = options;
        connected.require_connected = true;
        Random again(seed);
        disconnected += drawGeometricOnce(again, connected).has_value() ? 0U : 1U;
    }
    // A 55 m square and a 12 m reach: some draws fall apart, and are kept only when allowed.
    EXPECT_GT(disconnected, 0U);
}

TEST(Geometric, ExactDegreeWithTheTestsOptions)
{
    GeometricOptions options;
    options.nodes = 20;
    options.mean_degree = 8.0;
    options.area_per_node_m2 = 25.0;
    options.radius = GeometricOptions::Radius::ExactDegree;
    options.ids = GeometricOptions::Ids::Scattered;
    options.min_separation_m = 1.0;
    options.max_height_m = 3.0;
    options.min_degree = 3;
    options.require_globally_rigid = true;
    for (uint64_t seed = 1; seed <= 10; ++seed) {
        Random random(seed);
        const GeometricNetwork net = drawGeometric(random, options);
        ASSERT_EQ(net.links.size(), 80U) << "20 nodes of degree 8: exactly 80 links";
        EXPECT_DOUBLE_EQ(net.mean_degree, 8.0);
        EXPECT_DOUBLE_EQ(net.radius_m, net.links.back().distance_m);
        for (size_t k = 1; k < net.links.size(); ++k) {
            EXPECT_LE(net.links[k - 1].distance_m, net.links[k].distance_m) << "shortest first";
        }
        std::vector<uint32_t> degree(20, 0);
        std::vector<std::pair<size_t, size_t>> pairs;
        for (const GeometricLink &link : net.links) {
            ++degree[link.a];
            ++degree[link.b];
            pairs.emplace_back(link.a, link.b);
        }
        EXPECT_GE(*std::min_element(degree.begin(), degree.end()), 3U);
        ASSERT_EQ(net.height_m.size(), 20U);
        for (uint32_t i = 0; i < 20; ++i) {
            EXPECT_EQ(net.ids[i], 0x1000 + 37 * i + 5);
            EXPECT_GE(net.height_m[i], 0.0);
            EXPECT_LT(net.height_m[i], 3.0);
            for (uint32_t j = i + 1; j < 20; ++j) {
                EXPECT_GE((net.position_m[i] - net.position_m[j]).norm(), 1.0);
            }
        }
        const GeometricLink &link = net.links.front();
        const double dz_m = net.height_m[link.a] - net.height_m[link.b];
        EXPECT_DOUBLE_EQ(net.rangeM(0), std::sqrt(link.distance_m * link.distance_m + dz_m * dz_m));
        Random check(seed + 100);
        EXPECT_TRUE(globallyRigid(net.position_m, pairs, check));
    }
}

TEST(Geometric, WithinProbabilityIsThatOfTheUnitSquare)
{
    // Two uniform points of the unit square closer than t: the closed form against counting.
    Random random(11);
    const double t = 0.3;
    const int samples = 200000;
    int within = 0;
    for (int i = 0; i < samples; ++i) {
        const double dx = random.uniform() - random.uniform(); // either order: the same |dx|
        const double dy = random.uniform() - random.uniform();
        within += std::hypot(dx, dy) <= t ? 1 : 0;
    }
    EXPECT_NEAR(static_cast<double>(within) / samples, withinProbability(t), 0.004); // ~4 sigma
    EXPECT_NEAR(withinProbability(1.0), 3.14159265358979323846 - 8.0 / 3.0 + 0.5, 1e-12);
}

} // namespace
} // namespace cdro::netgen
