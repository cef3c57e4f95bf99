#include "support.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>

#include "cdro/csv/reader.hpp"
#include "cdro/engine/alignment.hpp"
#include "cdro/netgen/rigidity.hpp"

#ifndef CDRO_SOURCE_DIR
#error "CDRO_SOURCE_DIR must be defined (tests/engine/CMakeLists.txt)"
#endif

namespace cdro::enginetest {

std::vector<uint64_t> testSeeds(const std::vector<uint64_t> &defaults)
{
    if (const char *env = std::getenv("CDRO_TEST_SEED")) {
        return {std::strtoull(env, nullptr, 0)};
    }
    return defaults;
}

uint64_t testSeed(uint64_t fallback) { return testSeeds({fallback}).front(); }

std::string seedTrace(uint64_t seed)
{
    std::printf("seed %llu (set CDRO_TEST_SEED=%llu to replay)\n", static_cast<unsigned long long>(seed),
                static_cast<unsigned long long>(seed));
    std::fflush(stdout);
    return "seed " + std::to_string(seed) + " (set CDRO_TEST_SEED=" + std::to_string(seed) + " to replay)";
}

Vector2 uniformPoint(netgen::RandomSource &random, double low_m, double high_m)
{
    const double y_m = random.uniform(low_m, high_m);
    const double x_m = random.uniform(low_m, high_m);
    return Vector2(x_m, y_m);
}

Vector2 normalPoint(netgen::RandomSource &random)
{
    const double y = random.normal();
    const double x = random.normal();
    return Vector2(x, y);
}

double TestNetwork::trueRange(size_t link) const
{
    const auto [a, b] = links[link];
    const double planar_m = (truth_m[a] - truth_m[b]).norm();
    if (height_m.empty()) {
        return planar_m;
    }
    const double dz_m = height_m[a] - height_m[b];
    return std::sqrt(planar_m * planar_m + dz_m * dz_m);
}

bool globallyRigid(const TestNetwork &network, Random &random)
{
    return netgen::globallyRigid(network.truth_m, network.links, random);
}

TestNetwork randomNetwork(Random &random, size_t nodes, double degree, bool heights)
{
    netgen::GeometricOptions options;
    options.nodes = static_cast<uint32_t>(nodes);
    options.mean_degree = degree;
    options.area_per_node_m2 = 25.0;
    options.radius = netgen::GeometricOptions::Radius::ExactDegree;
    // Ids that are neither 1..n nor adjacent: the engine must not care.
    options.ids = netgen::GeometricOptions::Ids::Scattered;
    options.min_separation_m = 1.0;
    options.max_height_m = heights ? 3.0 : 0.0;
    options.min_degree = 3;
    options.require_globally_rigid = true;
    return fromGeometric(netgen::drawGeometric(random, options));
}

TestNetwork fromGeometric(const netgen::GeometricNetwork &drawn)
{
    TestNetwork network;
    network.ids = drawn.ids;
    network.truth_m = drawn.position_m;
    network.height_m = drawn.height_m;
    for (const netgen::GeometricLink &link : drawn.links) {
        network.links.emplace_back(link.a, link.b);
    }
    return network;
}

std::vector<TestRange> roundRobin(const TestNetwork &network, Random &random, uint32_t sweeps, double noise_sigma_m)
{
    std::vector<TestRange> ranges;
    std::vector<size_t> order(network.links.size());
    for (size_t i = 0; i < order.size(); ++i) {
        order[i] = i;
    }
    for (uint32_t sweep = 0; sweep < sweeps; ++sweep) {
        random.shuffle(order);
        for (size_t link : order) {
            auto [a, b] = network.links[link];
            if (random.uniform() < 0.5) {
                std::swap(a, b);
            }
            const double noise_m = noise_sigma_m > 0.0 ? noise_sigma_m * random.normal() : 0.0;
            ranges.push_back(TestRange{network.ids[a], network.ids[b], network.trueRange(link) + noise_m});
        }
    }
    return ranges;
}

void feed(engine::Engine &engine, const TestNetwork &network, const std::vector<TestRange> &ranges, bool settle)
{
    for (size_t i = 0; i < network.height_m.size(); ++i) {
        engine.setHeight(network.ids[i], network.height_m[i]);
    }
    for (const TestRange &range : ranges) {
        engine.addRange(range.from, range.to, range.range_m);
    }
    if (settle) {
        // The offline mode's budget (host/hostd/src/offline.cpp).
        engine.settle(200ULL * engine.map().nodes.size() + 1000ULL);
    }
}

AlignedError alignedError(const std::vector<engine::NodeOutput> &estimates, const std::vector<NodeId> &ids,
                          const std::vector<Vector2> &truth_m)
{
    std::map<NodeId, Vector2> truth;
    for (size_t i = 0; i < ids.size(); ++i) {
        truth[ids[i]] = truth_m[i];
    }
    AlignedError error;
    std::vector<engine::MapPoint> placed;
    for (const engine::NodeOutput &node : estimates) {
        if (node.link_count == 0 && !node.fixed()) {
            continue;
        }
        ++error.nodes;
        error.converged += node.converged() ? 1U : 0U;
        if (!node.placed() || truth.count(node.id) == 0) {
            continue;
        }
        ++error.placed;
        placed.push_back({node.id, node.position_m});
    }
    if (placed.size() < 2) {
        error.rmse_m = std::numeric_limits<double>::infinity();
        error.max_m = std::numeric_limits<double>::infinity();
        return error;
    }
    const engine::AlignedErrors aligned = engine::alignedErrors(placed, truth, true);
    error.rmse_m = aligned.rmse_m;
    error.max_m = aligned.worst_m;
    return error;
}

namespace {

bool sameBytes(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

bool sameBytes(const engine::Matrix2 &a, const engine::Matrix2 &b)
{
    return std::memcmp(a.data(), b.data(), sizeof(double) * 4) == 0;
}

} // namespace

bool identical(const std::vector<engine::NodeOutput> &a, const std::vector<engine::NodeOutput> &b)
{
    if (a.size() != b.size()) {
        return false;
    }
    for (size_t i = 0; i < a.size(); ++i) {
        const engine::NodeOutput &x = a[i];
        const engine::NodeOutput &y = b[i];
        if (x.id != y.id || x.role != y.role || x.lifecycle != y.lifecycle || x.doubt != y.doubt ||
            x.hinge != y.hinge || x.hinge_nodes != y.hinge_nodes || x.height_known != y.height_known ||
            !sameBytes(x.height_m, y.height_m) || x.link_count != y.link_count ||
            !sameBytes(x.position_m.x(), y.position_m.x()) || !sameBytes(x.position_m.y(), y.position_m.y()) ||
            !sameBytes(x.covariance_m2, y.covariance_m2)) {
            return false;
        }
    }
    return true;
}

std::optional<PlantData> loadPlant(std::string *where)
{
    std::string data = std::string(CDRO_SOURCE_DIR) + "/../shared/data";
    if (const char *env = std::getenv("CDRO_DATA_DIR")) {
        data = env;
    }
    const std::string plant = data + "/plant";
    *where = plant;
    const std::string ranges_path = plant + "/ranges.csv";
    const std::string nodes_path = plant + "/nodes.csv";
    if (!std::ifstream(ranges_path) || !std::ifstream(nodes_path)) {
        return std::nullopt;
    }
    // Strict (csv/reader.hpp): a bad row fails the test that loads PLANT, with its file and line.
    PlantData out;
    csv::Reader nodes(nodes_path, csv::Format{{"id", "x", "y", "z"}, {}, {}}, csv::Policy::Strict);
    nodes.forEach([&](const csv::Row &row) {
        NodeId id = 0;
        double x_m = 0.0;
        double y_m = 0.0;
        double z_m = 0.0;
        if (row.nodeId("id", &id) && row.number("x", &x_m) && row.number("y", &y_m) && row.number("z", &z_m)) {
            out.ids.push_back(id);
            out.truth_m.emplace_back(x_m, y_m);
            out.height_m.push_back(z_m);
        }
    });
    csv::Reader ranges(ranges_path, csv::Format{{"from", "to", "range_m"}, {}, {}}, csv::Policy::Strict);
    ranges.forEach([&](const csv::Row &row) {
        TestRange range{};
        if (row.nodeId("from", &range.from) && row.nodeId("to", &range.to) && row.number("range_m", &range.range_m)) {
            out.ranges.push_back(range);
        }
    });
    return out;
}

} // namespace cdro::enginetest
