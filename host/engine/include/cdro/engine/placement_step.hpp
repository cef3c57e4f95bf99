// placement_step.hpp: step 2 of a range, placing what can be placed as ranges arrive (the
// paper's multilateration, eq. 1-4, made streaming and multi-hop: placement.hpp): the frame
// triangle first (or, with two or more fixed nodes, their frame), then every node whose placed
// neighbours decide its position, repeated while that makes progress. A node that stays
// ambiguous waits for the global solve (global_step.hpp) or for its patience to run out; with
// exactly two fixed nodes the first node placed from them alone takes the side to the left of
// the first towards the second (they fix the frame only up to that mirror image).
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "cdro/engine/map_state.hpp"
#include "cdro/engine/output_frame.hpp"
#include "cdro/engine/params.hpp"
#include "cdro/engine/point_solver.hpp"
#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {

struct PlacementCounters {
    uint64_t placements = 0;          // nodes placed (frame triangle included)
    uint64_t placement_ambiguous = 0; // evaluations that could not decide (waited)
    uint64_t placements_forced = 0;   // placed at the best candidate after patience ran out
    uint64_t replacements = 0;        // placed nodes found inconsistent, placed again
};

class PlacementStep {
public:
    PlacementStep(const EngineParams &params, const RangeLikelihood &likelihood);

    // The node is worth looking at again (a new link, a neighbour placed, patience).
    void markPending(const MapState &map, uint32_t node);
    bool anyPending() const { return any_pending_; }
    // Places what can be placed now; returns the nodes placed, in order. `frame_held`: no frame
    // triangle (the movement stage's own frame: only fixed or pinned nodes start the map); the
    // frame triangle is taken among the nodes `frame` allows. At most `most` nodes are placed
    // (the frame's three count as one); the others stay pending for the next run.
    std::vector<uint32_t> run(MapState &map, bool frame_held, const OutputFrame &frame,
                              const std::function<void(const std::string &)> &trace, uint64_t most = UINT64_MAX);
    // A node placed at position_m (also by others: the global solve).
    void place(MapState &map, uint32_t node, const Vector2 &position_m, const Matrix2 &covariance_m2);
    // A placed node found inconsistent with its links goes back to waiting.
    void unplace(MapState &map, uint32_t node);
    // Counts a range to a node that is not placed (its patience).
    void countWaitingRange(MapState &map, uint32_t node);
    void resize(size_t nodes) { pending_.resize(nodes, 0); }

    const PlacementCounters &counters() const { return counters_; }
    void restoreCounters(const PlacementCounters &counters) { counters_ = counters; }

private:
    bool placeFrame(MapState &map, const OutputFrame &frame);
    bool placeByHandedness(MapState &map, const std::vector<uint32_t> &nodes,
                           const std::function<void(const std::string &)> &trace);

    EngineParams params_;
    RangeLikelihood likelihood_;
    PointSolverParams solver_;
    std::vector<uint8_t> pending_;
    bool any_pending_ = false;
    PlacementCounters counters_;
};

} // namespace cdro::engine
