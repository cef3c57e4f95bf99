// The one simulated flight of the tests of nodes that never stop (3D tracks, anchors calibrated
// from moving tags, checkpoints of the tracks): tags flying smooth closed loops, about 0.4-0.8 m/s
// and 0.3-1.3 m high, in a 4 m x 4 m room under six nearly coplanar anchors at 1.6-1.9 m (the
// geometry of MiLUV's obstacle runs, ../shared/data/miluv), ranged one pair at a time on a fixed
// schedule with Gaussian noise.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "cdro/engine/engine.hpp"
#include "cdro/engine/motion_track_3d.hpp"

namespace cdro::enginetest {

constexpr std::array<engine::NodeId, 6> kFlightAnchors = {1, 2, 3, 4, 5, 6};
extern const std::array<engine::Vector3, 6> kFlightAnchorPositionsM; // m, x, y, height

// Tag k's true position at t_s (k = 0, 1, 2 fly distinct loops).
engine::Vector3 flightTagPositionM(size_t k, double t_s);

struct FlightRange {
    double t_s = 0.0; // s
    engine::NodeId from = 0;
    engine::NodeId to = 0;
    double range_m = 0.0; // m
};

// Slots of slot_s; in every cycle of slots_per_cycle, the last slot ranges two tags (the pairs in
// turn: 0-1, 1-2, ... with wrap-around; with two tags always 0-1), the others a tag to an anchor:
// the i-th such slot ranges tag i mod T to anchor (i / T) mod 6, so each anchor is ranged by every
// tag in turn. Each slot draws its noise whether it is used or not, so that without the tag-to-tag
// ranges the tag-anchor ranges are the same.
struct FlightSchedule {
    size_t slots_per_cycle = 5;
    bool tag_to_tag = true;   // false: the tag-to-tag slots are left empty
    double slot_s = 0.1;      // s
    double duration_s = 60.0; // s
    double noise_m = 0.1;     // m, std of the ranges' Gaussian noise
};

// The ranges of tags[k] (flying flightTagPositionM(k, t)) and the anchors, `from` the tag.
std::vector<FlightRange> simulateFlight(uint64_t seed, const std::vector<engine::NodeId> &tags,
                                        const FlightSchedule &schedule = {});

// The anchors fixed (position and height given) in `engine`.
void fixFlightAnchors(engine::Engine &engine);

} // namespace cdro::enginetest
