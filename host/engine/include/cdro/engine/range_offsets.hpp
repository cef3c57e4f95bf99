// range_offsets.hpp: each node's range offset, estimated with the map from all the links.
//
// A UWB radio whose antenna delay is not calibrated adds its own offset to every range it takes
// part in: a link reads d + b_a + b_b + noise (+ NLOS excess). DW1000 radios straight from the
// box read 0.2-0.9 m long a node (kolakowski-nlos: +0.22 m in line of sight), so links of a
// network of them read up to ~2 m long with tiny noise, and no map explains them: the best one is
// metres off and sure of itself. With the offsets as unknowns the same links give the map back.
//
// The estimate: the map is refined under the corrected ranges r - b_a - b_b while the offsets
// are solved from the map (IRLS over the robust likelihood, each offset a prior N(common,
// kRangeOffsetSpreadSigmaM^2) around a common part); the common part, which a map can absorb by growing,
// is searched explicitly (golden section over [kCommonMinM, kCommonMaxM]). The offsets are
// adopted only when they explain the links better by more than kNatsPerOffset per offset
// estimated (a model-selection margin): in walled buildings the NLOS excess of a node behind
// walls looks like an offset, and a few nats must not buy a distorted map.
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/map_problem.hpp"

namespace cdro::engine {

constexpr double kRangeOffsetSpreadSigmaM = 0.5; // m, how far a node's offset strays from the common part

struct RangeOffsets {
    bool adopted = false;
    double common_m = 0.0;          // m, the offset every node shares
    std::vector<double> offset_m;   // m, per node (problem numbering); zeros when not adopted
    MapEstimate estimate;           // the map under the corrected ranges (adopted), else the start
    double cost_nats = 0.0;         // the links' cost under the corrected ranges, with the prior
    double cost_without_nats = 0.0; // ... of the start under the ranges as read
    uint32_t evaluations = 0;       // maps refined in the search
    // nats: the cost without offsets less the best trial's with them and the margin; > 0 adopted
    double decision_nats = 0.0;
    // the model not taken: the start and no offsets when adopted, else the best trial's map and offsets
    MapEstimate other_estimate;
    std::vector<double> other_offset_m; // m, per node
};

// The offsets that best explain `problem`'s links from the map `start` (placed nodes only).
RangeOffsets calibrateRangeOffsets(const MapProblem &problem, const MapEstimate &start,
                                   const RangeLikelihood &likelihood);

// The problem with every link's range corrected by its ends' offsets (m).
MapProblem withRangeOffsets(const MapProblem &problem, const std::vector<double> &offset_m);

} // namespace cdro::engine
