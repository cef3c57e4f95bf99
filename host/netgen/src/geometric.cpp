#include "cdro/netgen/geometric.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>

#include "cdro/netgen/rigidity.hpp"

namespace cdro::netgen {

namespace {

constexpr double kPi = 3.14159265358979323846;

// The radius (m) whose expected mean degree is `mean_degree` for `nodes` points uniform in a
// square of side side_m: the t with withinProbability(t) = degree / (n - 1), by bisection.
double expectedDegreeRadiusM(uint32_t nodes, double mean_degree, double side_m)
{
    const double wanted = mean_degree / static_cast<double>(nodes - 1);
    if (wanted >= withinProbability(1.0)) {
        // Fewer nodes than the degree asks for (10 nodes: at most 9): every pair is a link.
        return side_m * std::sqrt(2.0) * 1.0001;
    }
    double low = 0.0;
    double high = 1.0;
    for (int i = 0; i < 60; ++i) {
        const double mid = 0.5 * (low + high);
        (withinProbability(mid) < wanted ? low : high) = mid;
    }
    return side_m * 0.5 * (low + high);
}

double sideM(const GeometricOptions &options)
{
    return std::sqrt(static_cast<double>(options.nodes) * options.area_per_node_m2);
}

// Every node with at least min_degree links, and connected if asked.
bool acceptable(uint32_t nodes, const std::vector<GeometricLink> &links, uint32_t min_degree, bool connected)
{
    std::vector<std::vector<uint32_t>> adjacent(nodes);
    for (const GeometricLink &link : links) {
        adjacent[link.a].push_back(link.b);
        adjacent[link.b].push_back(link.a);
    }
    for (const std::vector<uint32_t> &neighbours : adjacent) {
        if (neighbours.size() < min_degree) {
            return false;
        }
    }
    return !connected || connectedGraph(adjacent);
}

} // namespace

double withinProbability(double t) { return kPi * t * t - 8.0 / 3.0 * t * t * t + 0.5 * t * t * t * t; }

double GeometricNetwork::rangeM(size_t link) const
{
    const GeometricLink &l = links[link];
    if (height_m.empty()) {
        return l.distance_m;
    }
    const double dz_m = height_m[l.a] - height_m[l.b];
    return std::sqrt(l.distance_m * l.distance_m + dz_m * dz_m);
}

std::optional<GeometricNetwork> drawGeometricOnce(RandomSource &random, const GeometricOptions &options)
{
    const uint32_t nodes = options.nodes;
    if (nodes < 2) {
        throw std::invalid_argument("a geometric network needs at least 2 nodes");
    }
    GeometricNetwork net;
    net.side_m = sideM(options);
    // 1. positions
    net.position_m.reserve(nodes);
    while (net.position_m.size() < nodes) {
        // Two statements: the order of the draws must not be left to the compiler.
        const double x_m = random.uniform(0.0, net.side_m);
        const double y_m = random.uniform(0.0, net.side_m);
        const Vector2 candidate_m(x_m, y_m);
        bool crowded = false;
        if (options.min_separation_m > 0.0) {
            for (const Vector2 &other_m : net.position_m) {
                crowded = crowded || (other_m - candidate_m).norm() < options.min_separation_m;
            }
        }
        if (!crowded) {
            net.position_m.push_back(candidate_m);
        }
    }
    // 2. heights and ids
    for (uint32_t i = 0; i < nodes; ++i) {
        net.ids.push_back(options.ids == GeometricOptions::Ids::Sequential ? static_cast<NodeId>(i + 1)
                                                                           : static_cast<NodeId>(0x1000 + 37 * i + 5));
        if (options.max_height_m > 0.0) {
            net.height_m.push_back(random.uniform(0.0, options.max_height_m));
        }
    }
    // 3. links
    if (options.radius != GeometricOptions::Radius::ExactDegree) {
        net.radius_m = options.radius == GeometricOptions::Radius::Given
                           ? options.radius_m
                           : expectedDegreeRadiusM(nodes, options.mean_degree, net.side_m);
        for (uint32_t i = 0; i < nodes; ++i) {
            for (uint32_t j = i + 1; j < nodes; ++j) {
                const double d_m = (net.position_m[i] - net.position_m[j]).norm();
                if (d_m <= net.radius_m) {
                    net.links.push_back(GeometricLink{i, j, d_m});
                }
            }
        }
    } else {
        // The (n d / 2) shortest pairs; ties in length go to the lower indices.
        std::vector<std::tuple<double, uint32_t, uint32_t>> pairs;
        for (uint32_t i = 0; i < nodes; ++i) {
            for (uint32_t j = i + 1; j < nodes; ++j) {
                pairs.emplace_back((net.position_m[i] - net.position_m[j]).norm(), i, j);
            }
        }
        std::sort(pairs.begin(), pairs.end());
        const size_t wanted =
            std::min(pairs.size(),
                     static_cast<size_t>(std::lround(0.5 * options.mean_degree * static_cast<double>(nodes))));
        for (size_t k = 0; k < wanted; ++k) {
            const auto [d_m, i, j] = pairs[k];
            net.links.push_back(GeometricLink{i, j, d_m});
            net.radius_m = d_m;
        }
    }
    // 4. directions
    if (options.draw_directions) {
        for (GeometricLink &link : net.links) {
            if (random.uniform() < 0.5) {
                std::swap(link.a, link.b);
            }
        }
    }
    // 5. acceptance
    if (!acceptable(nodes, net.links, options.min_degree, options.require_connected)) {
        return std::nullopt;
    }
    if (options.require_globally_rigid) {
        std::vector<std::pair<size_t, size_t>> pairs;
        pairs.reserve(net.links.size());
        for (const GeometricLink &link : net.links) {
            pairs.emplace_back(link.a, link.b);
        }
        if (!globallyRigid(net.position_m, pairs, random)) {
            return std::nullopt;
        }
    }
    // 6. order
    if (options.shuffle_links) {
        random.shuffle(net.links);
    }
    net.mean_degree = 2.0 * static_cast<double>(net.links.size()) / static_cast<double>(nodes);
    return net;
}

GeometricNetwork drawGeometric(RandomSource &random, const GeometricOptions &options)
{
    for (uint32_t attempt = 0; attempt < options.max_attempts; ++attempt) {
        if (std::optional<GeometricNetwork> net = drawGeometricOnce(random, options)) {
            net->draws = attempt + 1;
            return *std::move(net);
        }
    }
    throw std::runtime_error("no acceptable geometric network in " + std::to_string(options.max_attempts) +
                             " draws of " + std::to_string(options.nodes) + " nodes");
}

GeometricNetwork drawGeometric(uint64_t seed, const GeometricOptions &options)
{
    for (uint32_t attempt = 0; attempt < options.max_attempts; ++attempt) {
        const uint64_t draw_seed = mixSeed(mixSeed(mixSeed(seed) ^ options.nodes) ^ attempt);
        MersenneRandom random(draw_seed);
        if (std::optional<GeometricNetwork> net = drawGeometricOnce(random, options)) {
            net->draw_seed = draw_seed;
            net->draws = attempt + 1;
            return *std::move(net);
        }
    }
    throw std::runtime_error("no acceptable geometric network in " + std::to_string(options.max_attempts) +
                             " draws of " + std::to_string(options.nodes) + " nodes");
}

} // namespace cdro::netgen
