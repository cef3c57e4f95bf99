// global_step.hpp: the global solve (global_solve.hpp) as a step of the pipeline: when it runs,
// the plain problem it is given, and how its map is adopted.
//
// When: once the links have grown by `link_growth` since the last run (so a logarithmic number of
// times), once more when no link has appeared for `quiet_ranges_per_link` ranges per link, and at
// settle(); only ever at these points of the range stream, so a replay gives the same estimates.
// The problem: the placed or placeable nodes that are not moving, numbered by id, their links'
// ranges, fixed and pinned nodes where they are, and the unheard pairs of nodes that have listened
// for two sweeps of the network. Adoption: the solve's best map, seen from the current frame (a
// rigid fit on the nodes both place), unless the filter's own map, refined, explains the links
// within `min_gain_nats` as well (no jump for nothing); nodes the solve places and the filter had
// not are placed; what the solve says about each node (its covariance with the correlations of
// the whole map, its reliability, whether a rival map disputes it) is kept in NodeSolveView for
// the convergence checks and the outputs.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "cdro/engine/global_solve.hpp"
#include "cdro/engine/map_problem.hpp"
#include "cdro/engine/map_state.hpp"
#include "cdro/engine/params.hpp"

namespace cdro::engine {

struct GlobalStepCounters {
    uint64_t solves = 0;            // global solves run
    uint64_t solves_adopted = 0;    // ... whose map replaced the filter's (not its refinement)
    uint64_t solve_starts = 0;      // starting maps refined, over all solves
    uint64_t solve_escapes = 0;     // single nodes moved out of a local minimum, over all solves
    uint64_t solve_placed = 0;      // nodes the solve placed that the filter had not
};

// The problem the solve sees, and which engine node each problem node is.
struct StateProblem {
    MapProblem problem;
    std::vector<uint32_t> node_of; // problem node number -> MapState node index
};

StateProblem mapProblemOf(const MapState &map, const EngineParams &params, uint64_t ranges_received);

class GlobalStep {
public:
    explicit GlobalStep(const EngineParams &params);

    // solve.enabled. Without refinement (the paper's filter: the merged SoG is the estimate) the
    // solve only places the nodes the filter could not place; it moves none.
    bool enabled() const;
    // After a range: whether the solve is due (the links grew, or the network has been quiet).
    bool dueAfterRange(const MapState &map, bool new_link);
    // At settle(): whether links appeared since the last run.
    bool dueAtSettle(const MapState &map) const;

    struct Outcome {
        std::vector<uint32_t> placed;   // nodes it placed that were not placed
        std::vector<std::pair<uint32_t, Vector2>> shifted; // placed nodes it moved, and by how much (m)
        bool adopted = false;           // the solve's map (not the filter's, refined)
    };
    using Trace = std::function<void(const std::string &)>;
    // Runs the solve and adopts its map into `map` (positions only: the caller moves the rings,
    // places the new nodes' SoGs and restarts eq. 16 for the moved ones).
    Outcome run(MapState &map, uint64_t ranges_received, uint32_t fixed_frame_nodes, const Trace &trace);

    uint64_t linksAtLastSolve() const { return links_at_last_; }
    uint64_t rangesSinceNewLink() const { return ranges_since_new_link_; }
    void restoreSchedule(uint64_t links_at_last, uint64_t ranges_since_new_link)
    {
        links_at_last_ = links_at_last;
        ranges_since_new_link_ = ranges_since_new_link;
    }
    const GlobalStepCounters &counters() const { return counters_; }
    void restoreCounters(const GlobalStepCounters &counters) { counters_ = counters; }

private:
    EngineParams params_;
    RangeLikelihood likelihood_;   // the engine's model without the floor (map_problem.hpp)
    GlobalSolveParams solve_;
    uint64_t links_at_last_ = 0;
    uint64_t ranges_since_new_link_ = 0;
    GlobalStepCounters counters_;
};

} // namespace cdro::engine
