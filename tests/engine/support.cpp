#include "support.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include "cdro/csv/reader.hpp"
#include "cdro/engine/alignment.hpp"

#ifndef CDRO_SOURCE_DIR
#error "CDRO_SOURCE_DIR must be defined (tests/engine/CMakeLists.txt)"
#endif

namespace cdro::enginetest {

namespace {
constexpr double kPi = 3.14159265358979323846;
} // namespace

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

// splitmix64 (Steele, Lea, Flood 2014): tiny, full period, good enough for test geometry.
uint64_t Random::next()
{
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

double Random::uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }

double Random::uniform(double low, double high) { return low + (high - low) * uniform(); }

double Random::normal()
{
    // 1 - uniform() is in (0, 1]: the logarithm is finite.
    const double radius = std::sqrt(-2.0 * std::log(1.0 - uniform()));
    return radius * std::cos(2.0 * kPi * uniform());
}

size_t Random::below(size_t count) { return static_cast<size_t>(uniform() * static_cast<double>(count)); }

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

namespace {

bool usable(const TestNetwork &network)
{
    const size_t count = network.ids.size();
    std::vector<size_t> degree(count, 0);
    std::vector<std::vector<size_t>> adjacent(count);
    for (const auto &[a, b] : network.links) {
        ++degree[a];
        ++degree[b];
        adjacent[a].push_back(b);
        adjacent[b].push_back(a);
    }
    for (size_t d : degree) {
        if (d < 3) {
            return false;
        }
    }
    std::vector<bool> seen(count, false);
    std::vector<size_t> stack{0};
    seen[0] = true;
    size_t reached = 0;
    while (!stack.empty()) {
        const size_t node = stack.back();
        stack.pop_back();
        ++reached;
        for (size_t other : adjacent[node]) {
            if (!seen[other]) {
                seen[other] = true;
                stack.push_back(other);
            }
        }
    }
    return reached == count;
}

} // namespace

bool globallyRigid(const TestNetwork &network, Random &random)
{
    // Rigidity matrix: one row per link, d|p_a - p_b| / d(p_a, p_b).
    const Eigen::Index n = static_cast<Eigen::Index>(network.truth_m.size());
    const Eigen::Index m = static_cast<Eigen::Index>(network.links.size());
    if (n < 4) {
        return n == 3 && m == 3;
    }
    Eigen::MatrixXd rigidity = Eigen::MatrixXd::Zero(m, 2 * n);
    for (Eigen::Index l = 0; l < m; ++l) {
        const auto [a, b] = network.links[static_cast<size_t>(l)];
        const Vector2 d = network.truth_m[a] - network.truth_m[b];
        rigidity.block<1, 2>(l, 2 * static_cast<Eigen::Index>(a)) = d.transpose();
        rigidity.block<1, 2>(l, 2 * static_cast<Eigen::Index>(b)) = -d.transpose();
    }
    const Eigen::JacobiSVD<Eigen::MatrixXd> svd(rigidity, Eigen::ComputeFullU);
    const Eigen::VectorXd &singular = svd.singularValues();
    if (singular.size() == 0) {
        return false; // no link (and, for gcc's -Wnull-dereference, no empty vector read below)
    }
    const double tolerance = 1e-9 * singular(0);
    Eigen::Index rank = 0;
    for (Eigen::Index i = 0; i < singular.size(); ++i) {
        rank += singular(i) > tolerance ? 1 : 0;
    }
    if (rank != 2 * n - 3) {
        return false; // not even infinitesimally rigid
    }
    // Equilibrium stresses: the left null space of the rigidity matrix. A generic random
    // combination of them has the largest stress-matrix rank there is; n - 3 means globally
    // rigid (Connelly; Gortler, Healy, Thurston).
    const Eigen::MatrixXd stresses = svd.matrixU().rightCols(m - rank);
    if (stresses.cols() == 0) {
        return false;
    }
    Eigen::VectorXd mix(stresses.cols());
    for (Eigen::Index i = 0; i < mix.size(); ++i) {
        mix(i) = random.normal();
    }
    const Eigen::VectorXd omega = stresses * mix;
    Eigen::MatrixXd stress = Eigen::MatrixXd::Zero(n, n);
    for (Eigen::Index l = 0; l < m; ++l) {
        const auto [a, b] = network.links[static_cast<size_t>(l)];
        const Eigen::Index i = static_cast<Eigen::Index>(a);
        const Eigen::Index j = static_cast<Eigen::Index>(b);
        stress(i, j) -= omega(l);
        stress(j, i) -= omega(l);
        stress(i, i) += omega(l);
        stress(j, j) += omega(l);
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(stress);
    const Eigen::VectorXd values = eigen.eigenvalues().cwiseAbs();
    const double largest = values.maxCoeff();
    Eigen::Index stress_rank = 0;
    for (Eigen::Index i = 0; i < values.size(); ++i) {
        stress_rank += values(i) > 1e-9 * largest ? 1 : 0;
    }
    return stress_rank == n - 3;
}

TestNetwork randomNetwork(Random &random, size_t nodes, double degree, bool heights)
{
    const double area_per_node_m2 = 25.0;
    const double side_m = std::sqrt(area_per_node_m2 * static_cast<double>(nodes));
    for (;;) {
        TestNetwork network;
        while (network.truth_m.size() < nodes) {
            const Vector2 candidate(random.uniform(0.0, side_m), random.uniform(0.0, side_m));
            bool crowded = false;
            for (const Vector2 &other : network.truth_m) {
                crowded = crowded || (other - candidate).norm() < 1.0;
            }
            if (!crowded) {
                network.truth_m.push_back(candidate);
            }
        }
        for (size_t i = 0; i < nodes; ++i) {
            // Ids that are neither 1..n nor in the order of the nodes: the engine must not care.
            network.ids.push_back(static_cast<NodeId>(0x1000 + 37 * i + 5));
            if (heights) {
                network.height_m.push_back(random.uniform(0.0, 3.0));
            }
        }
        // The radius that gives exactly the mean degree asked for: the (n d / 2)-th shortest pair.
        std::vector<std::pair<double, std::pair<size_t, size_t>>> pairs;
        for (size_t i = 0; i < nodes; ++i) {
            for (size_t j = i + 1; j < nodes; ++j) {
                pairs.push_back({(network.truth_m[i] - network.truth_m[j]).norm(), {i, j}});
            }
        }
        std::sort(pairs.begin(), pairs.end());
        const size_t wanted = std::min(pairs.size(), static_cast<size_t>(std::lround(0.5 * degree * static_cast<double>(nodes))));
        for (size_t k = 0; k < wanted; ++k) {
            network.links.push_back(pairs[k].second);
        }
        if (usable(network) && globallyRigid(network, random)) {
            return network;
        }
    }
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
    std::vector<Vector2> source;
    std::vector<Vector2> target;
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
        source.push_back(node.position_m);
        target.push_back(truth[node.id]);
    }
    if (source.size() < 2) {
        error.rmse_m = std::numeric_limits<double>::infinity();
        error.max_m = std::numeric_limits<double>::infinity();
        return error;
    }
    const engine::RigidTransform transform = engine::fitRigid(source, target, true);
    error.rmse_m = transform.rms_error_m;
    for (size_t i = 0; i < source.size(); ++i) {
        error.max_m = std::max(error.max_m, (transform.apply(source[i]) - target[i]).norm());
    }
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
            !sameBytes(x.height_m, y.height_m) ||
            x.link_count != y.link_count || !sameBytes(x.position_m.x(), y.position_m.x()) ||
            !sameBytes(x.position_m.y(), y.position_m.y()) || !sameBytes(x.covariance_m2, y.covariance_m2)) {
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
