// convergence.hpp: step 4c of a range and the honesty checks. Eq. 16 (the paper): the average
// p <- alpha p + (1 - alpha) p_new must have stopped moving (`consecutive` still updates in a row,
// at least `min_updates` since placed). A settled node is not always a determined one, so a node
// is converged only when, besides, nothing says otherwise (NodeDoubt):
//   too few links  fewer than three placed, still neighbours;
//   ambiguous      a distinct position explains its links about as well (a mirror image across
//                  nearly collinear neighbours), or a rival map of the global solve places it a
//                  metre or more away;
//   foldable       its part hangs on one or two nodes (foldable.hpp) and can fold about them
//                  without changing a range;
//   flexible       outside the part of the map joined by links that others check, or one error
//                  in a link, too small to be noticed, could move it `reliable_m` or more, or its
//                  2-sigma ellipse (the global solve's covariance) reaches that far;
//   unsettled      the global solve has not placed it yet, or the filter has since moved it half of
//                  `reliable_m` from where the solve put it (without the solve, or without
//                  refinement, the checks that need it are left out).
// The checks that need the whole map run when its structure or the solve changed (assess()); the
// per-node part after every update (afterUpdate()).
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/foldable.hpp"
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

class Convergence {
public:
    Convergence(const EngineParams &params, const RangeLikelihood &likelihood);

    // Eq. 16 after an update of a free, still node, then its lifecycle (Placed / Converged).
    void afterUpdate(MapState &map, uint32_t node);
    // Restarts eq. 16 at the node's current estimate (a map adopted at once, a quiet map).
    static void restart(NodeState &state);
    // The checks over the whole map; each placed free node's doubt and lifecycle follow.
    void assess(MapState &map);
    // The node's doubt now (the whole-map part from the last assess()).
    NodeDoubt doubtOf(const MapState &map, uint32_t node) const;

    const ConvergenceCounters &counters() const { return counters_; }
    // The whole-map doubts of the last assessment, per node (checkpoints).
    const std::vector<NodeDoubt> &structuralDoubts() const { return structural_; }
    void restoreStructuralDoubts(std::vector<NodeDoubt> doubts) { structural_ = std::move(doubts); }
    void restoreCounters(const ConvergenceCounters &counters) { counters_ = counters; }

private:
    void decide(MapState &map, uint32_t node);

    ConvergenceParams params_;
    PlacementParams placement_;
    RangeLikelihood likelihood_;
    PointSolverParams solver_;
    bool solve_enabled_;                // the solve's checks apply (else eq. 16 and the local ones)
    std::vector<NodeDoubt> structural_; // per node: the whole-map doubt of the last assessment
    ConvergenceCounters counters_;
};

} // namespace cdro::engine
