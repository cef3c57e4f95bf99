// global_solve.hpp: the map that all the links seen so far support, whatever order they came
// in: several starts, each refined by robust Levenberg-Marquardt with graduated non-convexity
// (map_refine.hpp) and freed from local minima node by node, the cheapest kept, and the rivals
// that explain the links almost as well remembered (a node they place differently is disputed:
// the ranges do not decide it).
//
// Then each node's range offset (its radio's antenna delay) with the best map, adopted when it
// explains the links clearly better (range_offsets.hpp).
//
// The maps are compared by their cost under the NLOS model that suits each (a profile
// likelihood), plus the cost of leaving linked nodes unplaced, plus how well each explains which
// pairs heard each other (map_connectivity.hpp), over the nodes that every map placing the most
// nodes places.
//
// Starts: the map grown from each of `growth_seeds` seed triangles spread over the network
// (map_growth.hpp), MDS-MAP (map_mds.hpp), and the caller's current map if it has one. Only
// the largest connected part of the link graph is solved; a node outside it has no range that
// relates it to the map.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "cdro/engine/map_growth.hpp"
#include "cdro/engine/map_hinges.hpp"
#include "cdro/engine/map_lift.hpp"
#include "cdro/engine/map_problem.hpp"
#include "cdro/engine/map_refine.hpp"
#include "cdro/engine/map_stitch.hpp"
#include "cdro/engine/range_offsets.hpp"

namespace cdro::engine {

struct GlobalSolveParams {
    uint32_t growth_seeds = 3;    // maps grown from this many seed triangles
    bool mds_start = true;        // MDS-MAP as a start too
    bool patch_start = true;      // local maps merged (map_patches.hpp) as a start too
    bool stitch_start = true;     // the grown maps that stop short stitched (map_stitch.hpp) as a start too
    uint32_t escape_rounds = 3;   // rounds of moving single nodes to better local optima
    double escape_gap_nats = 2.0; // a node moves when the move is this much cheaper
    double rival_gap_nats = 4.0;  // a map within this of the best is a rival
    double disputed_m = 1.0;      // m, a node two rivals place this far apart is disputed
    uint32_t learn_rounds = 2;    // EM rounds learning the NLOS share and excess from the best map
    bool lift = true;             // refine every start through the lifted space (map_lift.hpp)
    bool lifted_mds_start = true; // and start from MDS-MAP in D dimensions too
    bool range_offsets = true;    // estimate each node's range offset with the best map (range_offsets.hpp)
    bool connectivity = true;     // judge the maps by which pairs heard each other too (map_connectivity.hpp)
    bool free_parts = true;       // and place each map's free parts by it (map_hinges.hpp)
    HingeParams hinges;
    bool only_current = false; // the caller's map the only start (its links were all
                               // solved from every start before: a refresh)
    uint32_t threads = 1;      // starts refined at once (the result is the same for any)
    MapLiftParams lifting;
    MapRefineParams refine;
    MapGrowthParams growth;
};

struct MapHypothesis {
    MapEstimate estimate;
    double cost = 0.0;                // nats (map_problem.hpp)
    std::string origin;               // "grown from <ids>", "MDS-MAP", "current"
    double nlos_fraction = -1.0;      // the NLOS model it was judged under (< 0: the prior)
    double nlos_mean_excess_m = -1.0; // m
    double connectivity_nats = 0.0;   // map_connectivity.hpp's cost over the nodes every fullest map places
};

struct GlobalSolveCounters {
    uint32_t starts = 0;
    uint32_t escapes = 0; // single nodes moved to a better local optimum
    uint32_t refine_iterations = 0;
    uint32_t offset_evaluations = 0; // maps refined searching the range offsets
    uint32_t free_parts_moved = 0;   // free parts turned, reflected or swung by who heard whom

    GlobalSolveCounters &operator+=(const GlobalSolveCounters &other)
    {
        starts += other.starts;
        escapes += other.escapes;
        refine_iterations += other.refine_iterations;
        offset_evaluations += other.offset_evaluations;
        free_parts_moved += other.free_parts_moved;
        return *this;
    }
};

struct GlobalSolveResult {
    MapHypothesis best;
    std::vector<MapHypothesis> rivals; // distinct maps within rival_gap_nats of the best, best first
    std::vector<uint8_t> disputed;     // per node: a rival places it disputed_m or more away
    // per node, m: the farthest a rival places it (fitted rigidly on the part); 0 without
    std::vector<double> rival_apart_m;
    std::vector<uint32_t> part;     // the nodes solved (the largest connected part)
    std::vector<MapHypothesis> all; // every start after refinement, best first (diagnostics)
    GlobalSolveCounters counters;
    double learnt_nlos_fraction = -1.0;      // the NLOS model learnt (< 0: not learnt)
    double learnt_nlos_mean_excess_m = -1.0; // m
    RangeOffsets offsets;                    // the nodes' range offsets (adopted or not); when adopted,
                                             // `best` is the map under the corrected ranges
};

// Per node, m: how far `map` places each node of `part` from where `reference` does, after the
// rigid fit (reflection allowed) of one onto the other over the part; infinite where only one
// places it, 0 outside the part.
std::vector<double> discrepancyM(const MapEstimate &map, const MapEstimate &reference,
                                 const std::vector<uint32_t> &part);

GlobalSolveResult solveGlobally(const MapProblem &problem, const RangeLikelihood &likelihood,
                                const GlobalSolveParams &params, const MapEstimate *current = nullptr);

// Sets each map's `connectivity_nats` (who heard whom, map_connectivity.hpp), priced over the
// nodes that every map placing the most nodes places; a map placing fewer is given the worst of
// those maps' costs. With fewer than two maps nothing is priced.
void priceWhoHeardWhom(const MapProblem &problem, std::vector<MapHypothesis> &hypotheses, uint32_t threads);

// The NLOS share and mean excess that best explain the residuals of `estimate` (EM, the
// positions held).
RangeLikelihoodParams learnNlosModel(const MapProblem &problem, const MapEstimate &estimate,
                                     const RangeLikelihood &likelihood);

// Moves single nodes to a distinct local optimum of their links (placement.hpp's candidates)
// when that is cheaper by gap_nats, counting the soft cost of unheard nodes; returns the moves.
uint32_t escapeNodeMinima(const MapProblem &problem, MapEstimate &estimate, const RangeLikelihood &likelihood,
                          const MapGrowthParams &growth, double gap_nats);

} // namespace cdro::engine
