// geometric.hpp: the random geometric network, the one drawn by the engine tests
// (tests/engine/support.hpp's randomNetwork) and by cdro-bench-engine (docs/bench.md).
//
// What it draws, in this order from the random stream (the order is part of the contract: the
// same stream gives the same network):
//   1. positions: `nodes` points uniform in a square of side sqrt(nodes * area_per_node_m2) m,
//      x then y of each node in turn; a point closer than min_separation_m to one already drawn
//      is drawn again (0: never);
//   2. heights, if max_height_m > 0: z uniform in [0, max_height_m) m, node by node (else the
//      network is planar and height_m is empty);
//   3. links, the pairs that hear each other:
//        Radius::ExpectedDegree  every pair within the radius whose *expected* mean degree is
//                                `mean_degree` (a closed form for points uniform in a square,
//                                edges included); links in pair order (0,1), (0,2) ... (1,2) ...;
//        Radius::ExactDegree     the round(nodes * mean_degree / 2) shortest pairs, so this
//                                draw's mean degree is the one asked; links shortest first;
//        Radius::Given           every pair within radius_m (mean_degree is not used); links in
//                                pair order;
//      with fewer nodes than the degree asks for, every pair is a link;
//   4. directions, if draw_directions: for each link in that order, who initiates (a) is drawn
//      (else a is the lower index);
//   5. acceptance: the draw is kept if it is connected (unless require_connected is false),
//      every node has at least min_degree links and, if require_globally_rigid, the ranges allow
//      one map only (rigidity.hpp; this draws from the stream too); else the whole draw is made
//      again;
//   6. order, if shuffle_links: the links are shuffled (Fisher-Yates), the order a benchmark
//      feeds them in.
// Distances are planar (m); GeometricNetwork::rangeM adds the height difference.
//
// Ids (the engine must not depend on them): Ids::Sequential is 1..n, Ids::Scattered is
// 0x1000 + 37 i + 5 (neither 1..n nor adjacent, still in the order of the nodes).
//
// The seed: drawGeometric(RandomSource &, ...) draws every attempt from the caller's stream, which
// then goes on (the tests draw their ranges from it next). drawGeometric(seed, ...) draws attempt
// k from its own stream, MersenneRandom(mixSeed(mixSeed(mixSeed(seed) ^ nodes) ^ k)), so one size
// and seed is one network whatever else runs, and draw_seed replays the accepted attempt alone.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include "cdro/netgen/random.hpp"
#include "cdro/netgen/world.hpp"

namespace cdro::netgen {

struct GeometricOptions {
    enum class Radius : uint8_t { ExpectedDegree, ExactDegree, Given };
    enum class Ids : uint8_t { Sequential, Scattered };

    uint32_t nodes = 10;
    double mean_degree = 10.0;      // links per node
    double area_per_node_m2 = 80.0; // m^2 of the square per node
    Radius radius = Radius::ExpectedDegree;
    double radius_m = 0.0; // m, Radius::Given: the longest link
    Ids ids = Ids::Sequential;
    double min_separation_m = 0.0; // m, no two nodes closer (0: no constraint)
    double max_height_m = 0.0;     // m, heights uniform in [0, this); 0: planar
    bool draw_directions = false;  // draw which end of each link initiates
    bool require_connected = true;
    uint32_t min_degree = 1; // links every node must have
    bool require_globally_rigid = false;
    bool shuffle_links = false;    // the links in a random order
    uint32_t max_attempts = 10000; // draws before giving up (std::runtime_error)
};

struct GeometricLink {
    uint32_t a = 0; // node indices; a initiates
    uint32_t b = 0;
    double distance_m = 0.0; // m, planar, true
};

struct GeometricNetwork {
    std::vector<NodeId> ids;
    std::vector<Vector2> position_m; // m
    std::vector<double> height_m;    // m, empty when planar
    std::vector<GeometricLink> links;
    double side_m = 0.0;      // m, the square
    double radius_m = 0.0;    // m, the longest link allowed (ExactDegree: the longest drawn)
    double mean_degree = 0.0; // links per node, of this draw
    uint64_t draw_seed = 0;   // drawGeometric(seed, ...): the accepted attempt's seed
    uint32_t draws = 0;       // attempts made (the rejected ones included)

    double rangeM(size_t link) const; // m, the true range, 3D when there are heights
};

// A network from the caller's stream (attempts one after another on it).
GeometricNetwork drawGeometric(RandomSource &random, const GeometricOptions &options);

// A network from a seed (each attempt from its own MersenneRandom, above).
GeometricNetwork drawGeometric(uint64_t seed, const GeometricOptions &options);

// One attempt: the network if it passes the acceptance (step 5), else nullopt.
std::optional<GeometricNetwork> drawGeometricOnce(RandomSource &random, const GeometricOptions &options);

// Probability that two points uniform in the unit square are within t (0 <= t <= 1) of each
// other: pi t^2 - 8/3 t^3 + 1/2 t^4 (the square's edges make it less than pi t^2).
double withinProbability(double t);

} // namespace cdro::netgen
