// world.hpp: a simulated deployment of UWB nodes: where the nodes truly are, which pairs can
// hear each other, and how each link's ranges err. One model for the tests, the benchmarks and
// cdro-netgen (which writes it for cdro-sim and cdro-hostd); families.hpp builds the families of
// buildings, stream.hpp turns a world into a stream of ranges.
//
// The range model of a link (a, b) with true 3D distance d:
//     r = d + delay_a + delay_b + excess_ab + n + s
// delay: the node's uncalibrated antenna delay (m, persistent, >= 0); excess_ab: the link's
// persistent non-line-of-sight excess (m, >= 0: walls and furniture lengthen the first path,
// never shorten it); n ~ N(0, sigma^2); s: a sporadic NLOS reading, with probability
// sporadic_probability an Exp(sporadic_mean_m) excess, else 0. Ranges are clipped at 1 cm.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "cdro/netgen/random.hpp"

namespace cdro::netgen {

using NodeId = uint16_t;
using Vector2 = Eigen::Vector2d; // m
using Vector3 = Eigen::Vector3d; // m

struct WallSegment {
    Vector2 from_m = Vector2::Zero();
    Vector2 to_m = Vector2::Zero();
};

struct WorldNode {
    NodeId id = 0;
    Vector3 position_m = Vector3::Zero(); // m, the truth
    bool height_known = true;             // the user measured z (heights.csv lists it)
    double power_on_s = 0.0;              // s, switched on then (stream.hpp's staggered orders)
    double antenna_delay_m = 0.0;         // m, added to every range of the node
};

struct WorldLink {
    uint32_t a = 0; // node indices
    uint32_t b = 0;
    uint32_t walls = 0;    // walls the straight path crosses
    double excess_m = 0.0; // m, persistent NLOS excess of this link
};

struct RangeNoise {
    double sigma_m = 0.10;             // m, line-of-sight noise std
    double sporadic_probability = 0.0; // per range
    double sporadic_mean_m = 1.0;      // m
};

struct World {
    std::string family;
    uint64_t seed = 0;
    std::string description; // one line: what was drawn
    std::vector<WorldNode> nodes;
    std::vector<WorldLink> links; // the pairs that hear each other
    std::vector<WallSegment> walls;
    RangeNoise noise;

    double distance3dM(const WorldLink &link) const;
    double distance2dM(const WorldLink &link) const;
    // Persistent error of the link: antenna delays + excess (m).
    double biasM(const WorldLink &link) const;
    // One range of the link as measured (3D, m).
    double measureM(const WorldLink &link, Random &random) const;
    // Every node reaches every other through links.
    bool connected() const;
    uint32_t degree(uint32_t node) const;
};

// Whether every node of the graph (each node's neighbours) reaches node 0 through its edges
// (an empty graph is connected).
bool connectedGraph(const std::vector<std::vector<uint32_t>> &adjacent);

// How many walls the segment between two points crosses (touching an end counts).
uint32_t wallsCrossed(const std::vector<WallSegment> &walls, const Vector2 &from_m, const Vector2 &to_m);

// count distinct node ids drawn at random from 0x1000..0xFEFF (never in the order of the nodes,
// so nothing can depend on ids following geometry).
std::vector<NodeId> drawNodeIds(Random &random, size_t count);

} // namespace cdro::netgen
