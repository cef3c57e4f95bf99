// global_step.hpp: the global solve (global_solve.hpp) as a step of the pipeline: when it runs,
// the plain problem it is given, and how its map is adopted.
//
// When: once the links have grown by `link_growth` since the last run; once the ranges taken
// have grown by as much and a tenth of the links' ranges have moved by more than twice the noise
// since the solve last saw them (looked at once a sweep of the network: the medians improve for a while
// after the last link appeared; once they only flicker, in the steady state, nothing is solved
// again but once each time the ranges reach twice those of the last full solve, until one has seen
// the links' windows full: a live run never settles); once more when no link has appeared
// for `quiet_ranges_per_link` ranges per link; and at settle() when ranges arrived since. Only
// ever at these points of the range stream, so a replay gives the same estimates.
// Full or refresh: a solve on the same links and nodes as the last full solve, before the ranges
// have doubled since, starts from the
// current map alone (every start was tried on these links; only their ranges changed) and keeps
// what the full solve found disputed; settle() runs a full solve whenever ranges arrived since one.
// The problem: the placed or placeable nodes that are not moving, numbered by id, their links'
// ranges, fixed and pinned nodes where they are, and the unheard pairs of nodes that have listened
// for two sweeps of the network. Where: with `adopt_after_sweeps` > 0 (the default), on a worker
// thread, from a copy of the problem as the map stood when it was due, its map adopted that many
// sweeps of the network later (that many ranges taken per link at the start), at that range
// exactly, waiting for the worker if it is not done: the estimates depend on the range stream
// only, never on the thread's timing (the worker runs at a lower priority than the thread feeding
// the ranges, worker_priority.hpp); with 0, in the caller's thread, adopted at once. settle()'s
// solve always runs in the caller's thread.
// Adoption: the solve's best map, seen from the current frame (a
// rigid fit on the nodes both place), unless the filter's own map, refined, explains the links
// within `min_gain_nats` as well and is the same map (no jump for nothing); nodes the solve places and the filter had
// not are placed; what the solve says about each node (its covariance with the correlations of
// the whole map, its reliability, whether a rival map disputes it) is kept in NodeSolveView for
// the convergence checks and the outputs, and the convergence step's whole-map checks
// (convergence.hpp, StructureCheck) run on the chosen map with the solve, on its thread: at the
// adoption only their verdict is taken.
#pragma once

#include <cstdint>
#include <functional>
#include <future>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "cdro/engine/convergence.hpp"
#include "cdro/engine/global_solve.hpp"
#include "cdro/engine/map_problem.hpp"
#include "cdro/engine/map_state.hpp"
#include "cdro/engine/params.hpp"

namespace cdro::engine {

// Where the schedule stands (kept in checkpoints, so that a resumed engine solves when the
// uninterrupted one would).
struct SolveSchedule {
    uint64_t links_at_last = 0;  // links at the last solve
    uint64_t ranges_at_last = 0; // ranges taken at the last solve
    uint64_t ranges_since_new_link = 0;
    uint64_t ranges_at_check = 0; // ranges taken when the links were last checked for change
    uint64_t links_at_full = 0;   // the problem's links and nodes at the last full solve
    uint64_t nodes_at_full = 0;
    uint64_t ranges_at_full = 0; // ranges taken at the last full solve
    bool operator==(const SolveSchedule &other) const
    {
        return links_at_last == other.links_at_last && ranges_at_last == other.ranges_at_last &&
               ranges_since_new_link == other.ranges_since_new_link && ranges_at_check == other.ranges_at_check &&
               links_at_full == other.links_at_full && nodes_at_full == other.nodes_at_full &&
               ranges_at_full == other.ranges_at_full;
    }
};

struct GlobalStepCounters {
    uint64_t solves = 0; // global solves run (full and refreshes)
    uint64_t solve_refreshes =
        0; // ... of which refreshes: the same links as the last full solve, the current map refined
    uint64_t solves_adopted = 0;  // ... whose map replaced the filter's (not its refinement)
    uint64_t solve_starts = 0;    // starting maps refined, over all solves
    uint64_t solve_escapes = 0;   // single nodes moved out of a local minimum, over all solves
    uint64_t solve_placed = 0;    // nodes the solve placed that the filter had not
    uint64_t offsets_adopted = 0; // solves whose map came with the nodes' range offsets (range_offsets.hpp)
};

// The problem the solve sees, and which engine node each problem node is.
struct StateProblem {
    MapProblem problem;
    std::vector<uint32_t> node_of; // problem node number -> MapState node index
};

StateProblem mapProblemOf(const MapState &map, const EngineParams &params, uint64_t ranges_taken);

class GlobalStep {
public:
    // `check`: the convergence step's whole-map checks, run on each solve's map (a copy is kept).
    GlobalStep(const EngineParams &params, const StructureCheck &check);

    // solve.enabled. Without refinement (the paper's filter: the merged SoG is the estimate) the
    // solve only places the nodes the filter could not place; it moves none.
    bool enabled() const;
    // After a solve was adopted and the links' ranges follow the new offsets: the ranges it saw.
    void markSolved(MapState &map);
    // After a range: whether the solve is due (the links grew; the ranges grew by the same
    // factor and changed a share of the links' ranges; the network has been quiet; or, with no
    // new link, the nodes to solve changed: a carry settled).
    bool dueAfterRange(const MapState &map, bool new_link, uint64_t ranges_taken);
    // At settle(): whether ranges arrived since the last run.
    // The ranges behind the last full solve have doubled since (kMaturedRanges), and that solve
    // saw the links' windows not yet full.
    bool matured(uint64_t ranges_taken) const;
    bool dueAtSettle(const MapState &map, uint64_t ranges_taken) const;

    struct Outcome {
        std::vector<uint32_t> placed;                      // nodes it placed that were not placed
        std::vector<Matrix2> placed_covariance_m2;         // m^2, per node of `placed`: the solve's
                                                           // covariance without the nodes' shared
                                                           // excesses (MapCovariance), for its SoG
        std::vector<std::pair<uint32_t, Vector2>> shifted; // placed nodes it moved, and by how much (m)
        bool adopted = false;                              // the solve's map (not the filter's, refined)
        // The whole-map checks on the chosen map (empty when the solve placed too little), and
        // which map node each of its entries is.
        StructureVerdict structure;
        std::vector<uint32_t> structure_nodes;
    };
    using Trace = std::function<void(const std::string &)>;
    // Starts the solve on the map as it stands (on the worker thread, or deferred to adopt() when
    // it runs in the caller's thread). `settling`: the solve of settle(), whose map is the answer:
    // the best, without the margin; it always runs in the caller's thread.
    void start(const MapState &map, uint64_t ranges_taken, bool settling);
    // A solve started and not adopted yet.
    bool pending() const { return pending_ != nullptr; }
    // One more range taken (refused ranges do not count: they change nothing else either).
    void countRange() { adopt_in_ranges_ -= pending_ != nullptr && adopt_in_ranges_ > 0 ? 1U : 0U; }
    // Whether the pending solve's map is due now: a solve of the caller's thread at once, one of
    // the worker thread after its lag, unless the caller adopts those (setAdoptionByCaller).
    bool adoptionDue() const
    {
        return pending_ != nullptr && adopt_in_ranges_ == 0 && !(adoption_by_caller_ && pending_->background);
    }
    // Whether a solve runs on the worker thread and its map waits for the caller (never for the
    // range stream): adopted where adopt() is called, which the caller must then be able to repeat
    // (cdro-hostd records the place in its capture). Default false: after the lag.
    void setAdoptionByCaller(bool by_caller) { adoption_by_caller_ = by_caller; }
    // The pending solve ran on the worker thread and is done: adopt() would not wait.
    bool finished() const;
    // Waits for the pending solve and adopts its map into `map` (positions only: the caller moves
    // the rings, places the new nodes' SoGs and restarts eq. 16 for the moved ones).
    Outcome adopt(MapState &map, uint32_t fixed_frame_nodes, const Trace &trace);

    const SolveSchedule &schedule() const { return schedule_; }
    void restoreSchedule(const SolveSchedule &schedule) { schedule_ = schedule; }
    const GlobalStepCounters &counters() const { return counters_; }
    void restoreCounters(const GlobalStepCounters &counters) { counters_ = counters; }

private:
    // A solve under way: the problem as the map stood at its start, and its result to come
    // (shared: a copied engine adopts the same result at the same range).
    // What the solve ends with, all of it worked out on the solve's thread: the solve, the map
    // chosen from it (the filter's own, refined, or the solve's best) and that map's confidence.
    struct SolvedMap {
        GlobalSolveResult solved;
        MapHypothesis chosen;
        bool offsets = false;                  // the chosen map comes with the range offsets (the best's)
        std::vector<NodeSolveView> views;      // per problem node, in the solve's frame
        std::vector<Matrix2> shared_excess_m2; // m^2, per problem node: MapCovariance's
        StructureVerdict structure;            // the whole-map checks on the chosen map
    };
    struct PendingSolve {
        StateProblem built;
        MapEstimate current;                 // the filter's map at the start
        std::vector<uint8_t> height_unknown; // per node of the problem, at the start
        std::vector<uint8_t> was_disputed;   // per node of the problem: disputed by the last solve
        std::vector<StructureNode> nodes;    // per node of the problem, at the start (for the checks)
        bool refresh = false;                // the same links and nodes as the last full solve
        bool settling = false;
        bool background = false;              // on the worker thread (not deferred to adopt())
        bool check_structure = false;         // run the whole-map checks (refinement on)
        std::shared_future<SolvedMap> result; // last: destroyed first, waiting for the worker
    };
    // The solve, the choice, the confidence and the whole-map checks, from what the job owns and
    // copies of the settings: run on the worker thread, nothing of the engine's is read.
    static SolvedMap solveAndAssess(const PendingSolve &job, const RangeLikelihood &likelihood,
                                    const GlobalSolveParams &solve, double min_gain_nats, MapModelError model_error,
                                    const StructureCheck &check);

    EngineParams params_;
    RangeLikelihood likelihood_; // the engine's model without the floor (map_problem.hpp)
    StructureCheck check_;
    GlobalSolveParams solve_;
    SolveSchedule schedule_;
    GlobalStepCounters counters_;
    std::shared_ptr<const PendingSolve> pending_;
    uint64_t adopt_in_ranges_ = 0; // ranges to take before the pending solve's map is adopted
    bool adoption_by_caller_ = false;
};

} // namespace cdro::engine
