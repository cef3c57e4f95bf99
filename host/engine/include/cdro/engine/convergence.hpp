// convergence.hpp: step 4c of a range and the honesty checks. Eq. 16 (the paper): the average
// p <- alpha p + (1 - alpha) p_new must have stopped moving (`consecutive` still updates in a row,
// at least `min_updates` since placed). A settled node is not always a determined one, so a node
// is converged only when, besides, nothing says otherwise (NodeDoubt):
//   too few links  fewer than three placed, still neighbours;
//   ambiguous      a distinct position explains its links about as well (a mirror image across
//                  nearly collinear neighbours), its neighbours held or following it
//                  (second_place.hpp), or a rival map of the global solve places it a metre or
//                  more away;
//   foldable       its part hangs on one or two nodes (foldable.hpp) and can fold about them
//                  without changing a range;
//   flexible       outside the part of the map joined by links that others check, or one error
//                  in a link, too small to be noticed, could move it `reliable_m` or more, or its
//                  95 % region (the global solve's covariance) reaches that far, or the
//                  undoubted nodes it has links to do not determine it (fewer than three, or
//                  all along one line);
//   unsettled      the global solve has not placed it yet, or the filter has since moved it half of
//                  `reliable_m` from where the solve put it (without the solve, or without
//                  refinement, the checks that need it are left out).
// The checks that need the whole map (StructureCheck) run with the global solve, on its thread,
// on the map it found (the adopted verdict: adoptStructure()), or on the engine's map at settle()
// and where no solve runs (assess()); the per-node part after every update (afterUpdate()).
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "cdro/engine/foldable.hpp"
#include "cdro/engine/map_problem.hpp"
#include "cdro/engine/map_state.hpp"
#include "cdro/engine/params.hpp"
#include "cdro/engine/point_solver.hpp"
#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {

struct ConvergenceCounters {
    uint64_t assessments = 0;     // whole-map checks run
    uint64_t ambiguous_nodes = 0; // at the last assessment: nodes ambiguous
    uint64_t foldable_nodes = 0;  // ... foldable
    uint64_t flexible_nodes = 0;  // ... flexible
};

// m, the largest semi-axis of the 95 % region of a position's covariance (the ellipse of
// chi-square 5.991, 2 degrees of freedom: 2.45 sigma along its largest axis). "Converged"
// promises that this region lies within `reliable_m`; the 2-sigma ellipse holds the truth only
// 86.5 % of the time, so one node in seven of those it would call converged could end beyond it.
double regionSemiAxisM(const Matrix2 &covariance_m2);

// Whether a node whose own 95 % region is region_m (regionSemiAxisM) could be beyond within_m
// in a map about as good as the chosen one: a distinct rival map placing it rival_apart_m away
// (with as large a region), or the other range-offset model's map reaching other_model_reach_m
// (its distance plus that map's own region; 0 where offsets-or-none was clearly decided). A node
// whose own region is not within within_m is not judged here (it is flexible anyway).
bool disputedByOtherMaps(double region_m, double rival_apart_m, double other_model_reach_m, double within_m);

// What the structure check needs of each node of the map it looks at.
struct StructureNode {
    bool free = false;                       // neither fixed nor pinned: the only nodes checked
    bool anchored = false;                   // fixed: a part that holds one cannot fold
    Matrix2 covariance_m2 = Matrix2::Zero(); // m^2, its own estimate's, as a neighbour's in the checks
    NodeSolveView solve;                     // what the global solve says of it
};

// The whole-map doubts of one map, per node of its problem (hinges in the problem's numbers,
// kNoHinge where none).
struct StructureVerdict {
    std::vector<NodeDoubt> doubt;
    std::vector<std::array<uint32_t, 2>> hinge;
};

// The checks over the whole map: foldable parts of its link graph, a disputed node, a distinct
// position that explains a node's links about as well, a node the solve's confidence calls
// flexible. A plain value that reads nothing but its arguments: the global solve's worker runs a
// copy of it on the map it found, with the problem's ranges (corrected by the range offsets).
class StructureCheck {
public:
    StructureCheck(const EngineParams &params, const RangeLikelihood &likelihood);
    StructureVerdict run(const MapProblem &problem, const MapEstimate &estimate,
                         const std::vector<StructureNode> &nodes) const;

private:
    // Marks flexible the nodes that the undoubted nodes around them do not determine.
    void peelUnheld(const MapProblem &problem, const MapEstimate &estimate, const std::vector<StructureNode> &nodes,
                    StructureVerdict &verdict) const;

    ConvergenceParams params_;
    PlacementParams placement_;
    RangeLikelihood likelihood_;
    PointSolverParams solver_;
};

class Convergence {
public:
    Convergence(const EngineParams &params, const RangeLikelihood &likelihood);

    // Eq. 16 after an update of a free, still node, then its lifecycle (Placed / Converged).
    void afterUpdate(MapState &map, uint32_t node);
    // Restarts eq. 16 at the node's current estimate (a map adopted at once, a quiet map).
    static void restart(NodeState &state);
    // The checks over the whole map as it stands; each placed free node's doubt and lifecycle follow.
    void assess(MapState &map);
    // The same from a verdict on another copy of the map (the global solve's, whose problem node i
    // is map node node_of[i]; nodes not in it have no whole-map doubt).
    void adoptStructure(MapState &map, const StructureVerdict &verdict, const std::vector<uint32_t> &node_of);
    const StructureCheck &structureCheck() const { return check_; }
    // The node's doubt now (the whole-map part from the last assess()).
    NodeDoubt doubtOf(const MapState &map, uint32_t node) const;
    // Whether the map holds the node, so that it can be a reference for the ones that move (the
    // fallback motion detector's residuals): still, and fixed, pinned, converged, or flexible but
    // settled where the global solve puts it with its 95 % region within `reliable_m`. Such a
    // node agrees with every range where it is; what it lacks is the redundancy that would show
    // one hidden error, the promise of "converged", not what a reference needs. Not one with a
    // rival position (ambiguous, too few links, foldable), a wide region (a corridor's bent map:
    // the detector saw static nodes start there), or moving.
    bool holds(const MapState &map, uint32_t node) const;

    const ConvergenceCounters &counters() const { return counters_; }
    // The whole-map doubts of the last assessment, per node (checkpoints).
    const std::vector<NodeDoubt> &structuralDoubts() const { return structural_; }
    void restoreStructuralDoubts(std::vector<NodeDoubt> doubts) { structural_ = std::move(doubts); }
    void restoreCounters(const ConvergenceCounters &counters) { counters_ = counters; }

private:
    void decide(MapState &map, uint32_t node);
    // Eq. 16 still and, with the solve, where the global solve last put it.
    bool settled(const NodeState &state) const;

    ConvergenceParams params_;
    StructureCheck check_;
    bool solve_enabled_;                // the solve's checks apply (else eq. 16 and the local ones)
    std::vector<NodeDoubt> structural_; // per node: the whole-map doubt of the last assessment
    ConvergenceCounters counters_;
};

} // namespace cdro::engine
