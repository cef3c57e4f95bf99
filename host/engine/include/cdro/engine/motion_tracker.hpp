// motion_tracker.hpp: nodes that move (paper Fig. 4, params.hpp MotionParams). A node reported
// moving (MOTION frames, the motion CSV), or found moving by the fallback detector (its recent
// ranges, as far as they read from the map and from their links' own history, fit a walk far
// better than standing; without range times: several of them, on different links, read far),
// stops being an anchor and a witness for the others; its links start afresh, the SoGs centred on
// it are dropped, and every range to it resets the SoG around the ranging neighbour (sog_bank.hpp).
// A constant-velocity track (motion_track.hpp) follows it between ranges. When it stops, the
// track, at rest, stays its estimate until every link has a range from where it stopped
// (Settling); then its SoGs are generated again and it converges again.
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "cdro/engine/map_state.hpp"
#include "cdro/engine/params.hpp"
#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/sog_bank.hpp"

namespace cdro::engine {

struct MotionCounters {
    uint64_t motion_starts = 0; // nodes that started moving (reported or inferred)
    uint64_t motion_stops = 0;
    uint64_t motion_inferred = 0; // ... of the starts, found by the range detector
    uint64_t track_updates = 0;   // ranges taken by a moving node's track
    uint64_t track_refused = 0;   // ... refused as outliers
};

class MotionTracker {
public:
    MotionTracker(const EngineParams &params, const RangeLikelihood &likelihood);

    using Trace = std::function<void(const std::string &)>;

    // A motion report. Returns whether the node changed between moving and still (its
    // neighbours then lose or regain an anchor).
    bool report(MapState &map, SogBank &sogs, uint32_t node, bool moving, const Trace &trace);
    // The fallback detector, after a range on `link` at t_s (NaN: no time) whose distance from the
    // map (and from the link's history) is `residual_m`. Returns whether the node was found moving.
    bool watch(MapState &map, SogBank &sogs, uint32_t node, uint32_t link, double residual_m, double t_s,
               const Trace &trace);
    // A range from a placed anchor to a moving (or settling) node, at t_s, for its track.
    void track(MapState &map, uint32_t moving_node, uint32_t anchor_node, double range_m, double t_s);
    // After an update of a moving or settling node: its estimate from the track (if warm), and
    // whether it stopped (an inferred motion that stood still long enough, or a settling node
    // whose links all have fresh ranges). Returns whether its lifecycle changed.
    bool afterUpdate(MapState &map, SogBank &sogs, uint32_t node, const Trace &trace);
    // Whether the track is warm enough to be the estimate.
    bool trackIsEstimate(const NodeState &state) const;

    const MotionCounters &counters() const { return counters_; }
    void restoreCounters(const MotionCounters &counters) { counters_ = counters; }

private:
    bool change(MapState &map, SogBank &sogs, uint32_t node, bool moving, const Trace &trace);

    MotionParams params_;
    double range_sigma_m_;
    double gate_sigma_;
    RangeLikelihood likelihood_;
    MotionCounters counters_;
};

} // namespace cdro::engine
