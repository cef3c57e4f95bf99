// bench_networks.hpp: the random networks of docs/bench.md, for the benchmarks (bench/engine's
// draws, bench/service's streamed network). Header-only.
#pragma once

#include <cstdint>

#include "cdro/netgen/geometric.hpp"

namespace cdro::bench {

// netgen's geometric network (cdro/netgen/geometric.hpp, which says what is drawn and how the seed
// is used): ids 1..n, every pair within the radius of the expected mean degree, each link's
// direction drawn, connected, the links in a drawn feeding order; attempt k of a size from its own
// seed, so each size and seed is one network.
inline netgen::GeometricNetwork drawNetwork(uint32_t nodes, double degree, double area_per_node_m2, uint64_t seed)
{
    netgen::GeometricOptions options;
    options.nodes = nodes;
    options.mean_degree = degree;
    options.area_per_node_m2 = area_per_node_m2;
    options.radius = netgen::GeometricOptions::Radius::ExpectedDegree;
    options.ids = netgen::GeometricOptions::Ids::Sequential;
    options.draw_directions = true;
    options.shuffle_links = true;
    return netgen::drawGeometric(seed, options);
}

// docs/bench.md's defaults: degree ~10 at PLANT's density (~3000 m^2 for its 38 surveyed nodes).
constexpr double kNetworkDegree = 10.0;
constexpr double kNetworkAreaPerNodeM2 = 80.0; // m^2

} // namespace cdro::bench
