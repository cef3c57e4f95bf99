// stream.hpp: the ranges a world produces, in the order a device would deliver them.
//
//   sweeps     every node on from the start; each sweep ranges every link once, in an order
//              drawn anew for every sweep (who initiates, too).
//   staggered  nodes switched on one by one over the first `stagger_s` seconds (a deployment
//              being installed); a sweep ranges the links whose both ends are on.
//   late       as sweeps, except one node that is switched on only after `sweeps` sweeps, when
//              the map of the others has long formed; then `late_sweeps` more sweeps.
// Time advances by 1 / range_rate_hz per range. shuffledStream() gives the same ranges in a
// random order (times reassigned in the new order): the strongest test of order independence.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "cdro/netgen/world.hpp"

namespace cdro::netgen {

enum class StreamOrder : uint8_t { Sweeps, Staggered, Late };
const char *streamOrderName(StreamOrder order);
std::optional<StreamOrder> parseStreamOrder(const std::string &name);

struct StreamOptions {
    StreamOrder order = StreamOrder::Sweeps;
    uint32_t sweeps = 20;        // sweeps with every node on (after the last one is switched on)
    uint32_t late_sweeps = 20;   // late: sweeps after the late node is switched on
    double range_rate_hz = 80.0; // ranges per second, the whole network
    double stagger_s = 120.0;    // s, staggered: nodes switched on over this long
    uint64_t seed = 1;
};

struct GeneratedRange {
    NodeId from = 0;
    NodeId to = 0;
    double range_m = 0.0; // m, as measured (3D)
    double t_s = 0.0;     // s
};

struct GeneratedStream {
    std::vector<GeneratedRange> ranges;
    NodeId late_node = 0; // late: the node switched on last (0 otherwise)
};

GeneratedStream generateStream(const World &world, const StreamOptions &options);

// The same ranges in an order drawn from `seed`; t_s renumbered in the new order.
std::vector<GeneratedRange> shuffledStream(const std::vector<GeneratedRange> &ranges, uint64_t seed);

} // namespace cdro::netgen
