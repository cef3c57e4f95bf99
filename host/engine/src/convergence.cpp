#include "cdro/engine/convergence.hpp"

#include <algorithm>
#include <cmath>

#include "cdro/engine/placement.hpp"

namespace cdro::engine {

namespace {
constexpr double kReliabilityMargin = 2.5;
} // namespace

Convergence::Convergence(const EngineParams &params, const RangeLikelihood &likelihood)
    : params_(params.convergence), placement_(params.placement), likelihood_(likelihood),
      solve_enabled_(params.solve.enabled && params.refinement.enabled)
{
    solver_.range_sigma_m = params.range.sigma_m;
    solver_.max_iterations = std::max<uint32_t>(params.refinement.max_iterations, 1U);
    solver_.anchor_uncertainty_in_solve = false;
}

void Convergence::restart(NodeState &state)
{
    state.average_m = state.position_m;
    state.still_updates = 0;
}

NodeDoubt Convergence::doubtOf(const MapState &map, uint32_t node) const
{
    const NodeState &state = map.nodes[node];
    if (!state.placed() || !state.free() || state.moving() || state.settling()) {
        return NodeDoubt::None;
    }
    uint32_t anchors = 0;
    for (uint32_t link : state.links) {
        anchors += map.nodes[map.otherNode(link, node)].anchor() ? 1U : 0U;
    }
    if (anchors < 3) {
        return NodeDoubt::TooFewLinks;
    }
    if (node < structural_.size() && structural_[node] != NodeDoubt::None) {
        return structural_[node];
    }
    const NodeSolveView &solve = state.solve;
    if (solve_enabled_ && (!solve.solved || (state.position_m - solve.position_m).norm() > 0.5 * params_.reliable_m)) {
        return NodeDoubt::Unsettled;
    }
    if (state.still_updates < params_.consecutive || state.update_count < params_.min_updates) {
        return NodeDoubt::Unsettled;
    }
    return NodeDoubt::None;
}

void Convergence::decide(MapState &map, uint32_t node)
{
    NodeState &state = map.nodes[node];
    if (!state.placed() || !state.free() || state.moving() || state.settling()) {
        return;
    }
    state.doubt = doubtOf(map, node);
    state.lifecycle = state.doubt == NodeDoubt::None ? NodeLifecycle::Converged : NodeLifecycle::Placed;
}

void Convergence::afterUpdate(MapState &map, uint32_t node)
{
    // Eq. 16 with a count of still steps in a row, so that one small step is not convergence.
    NodeState &state = map.nodes[node];
    const Vector2 previous = state.average_m;
    state.average_m = params_.smoothing * state.average_m + (1.0 - params_.smoothing) * state.position_m;
    const double step = (state.average_m - previous).norm();
    state.update_count = state.update_count < UINT32_MAX ? state.update_count + 1 : state.update_count;
    state.still_updates = step < params_.threshold_m ? std::min<uint32_t>(state.still_updates + 1, 1000000U) : 0U;
    if (step > params_.unconverge_factor * params_.threshold_m) {
        state.still_updates = 0;
    }
    decide(map, node);
}

void Convergence::assess(MapState &map)
{
    ++counters_.assessments;
    const auto count = static_cast<uint32_t>(map.nodes.size());
    structural_.assign(count, NodeDoubt::None);
    // Foldable parts of the link graph of the placed, still nodes (fixed ones anchor a part).
    std::vector<uint8_t> active(count, 0);
    std::vector<uint8_t> anchored(count, 0);
    for (uint32_t node = 0; node < count; ++node) {
        active[node] = map.nodes[node].anchor() ? 1 : 0;
        anchored[node] = map.nodes[node].fixed() ? 1 : 0;
    }
    std::vector<std::pair<uint32_t, uint32_t>> edges;
    edges.reserve(map.links.size());
    for (const LinkState &link : map.links) {
        edges.emplace_back(link.node_a, link.node_b);
    }
    const Foldable folds = findFoldable(count, edges, active, anchored);
    uint64_t ambiguous = 0;
    uint64_t foldable = 0;
    uint64_t flexible = 0;
    const double reliable = params_.reliable_m;
    for (uint32_t node = 0; node < count; ++node) {
        NodeState &state = map.nodes[node];
        state.hinge = {kNoIndex, kNoIndex};
        if (!state.placed() || !state.free() || !state.anchor()) {
            continue;
        }
        NodeDoubt doubt = NodeDoubt::None;
        if (folds.foldable[node] != 0) {
            doubt = NodeDoubt::Foldable;
            state.hinge = folds.hinge[node];
        }
        const NodeSolveView &solve = state.solve;
        if (doubt == NodeDoubt::None && solve.solved && solve.disputed) {
            doubt = NodeDoubt::Ambiguous;
        }
        if (doubt == NodeDoubt::None) {
            // A distinct position that explains its links about as well as where it is.
            const std::vector<RangeConstraint> constraints = placedConstraints(map, node);
            if (constraints.size() >= 3) {
                const double here = robustCost(constraints, state.position_m, likelihood_, solver_.range_sigma_m);
                for (const PlacementCandidate &candidate :
                     placementCandidates(constraints, likelihood_, solver_, placement_)) {
                    if ((candidate.position_m - state.position_m).norm() > placement_.distinct_m &&
                        candidate.cost < here + placement_.ambiguity_gap_nats / 4.0) {
                        doubt = NodeDoubt::Ambiguous;
                        break;
                    }
                }
            }
        }
        if (doubt == NodeDoubt::None && solve.solved) {
            // The largest 2-sigma semi-axis of the map's covariance.
            const double largest_m =
                2.0 * std::sqrt(std::max(solve.covariance_m2.trace() - minEigenvalue(solve.covariance_m2), 0.0));
            // Baarda's bound is a worst case (an error just too small to be noticed, all of it on
            // the weakest link): a node is flexible when even that bound is well beyond the promise.
            if (!solve.main_part || !(solve.reliability_m < kReliabilityMargin * reliable) || !(largest_m < reliable)) {
                doubt = NodeDoubt::Flexible;
            }
        }
        structural_[node] = doubt;
        ambiguous += doubt == NodeDoubt::Ambiguous ? 1U : 0U;
        foldable += doubt == NodeDoubt::Foldable ? 1U : 0U;
        flexible += doubt == NodeDoubt::Flexible ? 1U : 0U;
    }
    counters_.ambiguous_nodes = ambiguous;
    counters_.foldable_nodes = foldable;
    counters_.flexible_nodes = flexible;
    for (uint32_t node = 0; node < count; ++node) {
        decide(map, node);
    }
}

} // namespace cdro::engine
