#include "cdro/engine/convergence.hpp"

#include <algorithm>
#include <cmath>
#include <optional>

#include "cdro/engine/global_solve.hpp"
#include "cdro/engine/placement.hpp"
#include "cdro/engine/second_place.hpp"

namespace cdro::engine {

namespace {
constexpr double kConvergedRegionChiSquare = 5.991; // the 95 % point of chi-square, 2 degrees of freedom
// A node's second place with its neighbours following it (second_place.hpp) is looked for from
// every distinct candidate that costs less than this more than its place with them held (freed,
// they took 1.1-3.3 nats off that difference on the variants' two nodes called converged
// 1.3-1.4 m off: docs/results.md, "Variants nobody had run") ...
constexpr double kNeighbourhoodWindowNats = 8.0;
// ... and is a rival when it costs less than this more than the node's place, freed the same way:
// the gap by which the global solve calls a whole map a rival.
const double kNeighbourhoodGapNats = GlobalSolveParams{}.rival_gap_nats;
} // namespace

double regionSemiAxisM(const Matrix2 &covariance_m2)
{
    return std::sqrt(kConvergedRegionChiSquare * std::max(covariance_m2.trace() - minEigenvalue(covariance_m2), 0.0));
}

bool disputedByOtherMaps(double region_m, double rival_apart_m, double other_model_reach_m, double within_m)
{
    return region_m < within_m && std::max(rival_apart_m + region_m, other_model_reach_m) >= within_m;
}

Convergence::Convergence(const EngineParams &params, const RangeLikelihood &likelihood)
    : params_(params.convergence), check_(params, likelihood),
      solve_enabled_(params.solve.enabled && params.refinement.enabled)
{
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
    return settled(state) ? NodeDoubt::None : NodeDoubt::Unsettled;
}

bool Convergence::settled(const NodeState &state) const
{
    const NodeSolveView &solve = state.solve;
    if (solve_enabled_ && (!solve.solved || (state.position_m - solve.position_m).norm() > 0.5 * params_.reliable_m)) {
        return false;
    }
    return state.still_updates >= params_.consecutive && state.update_count >= params_.min_updates;
}

bool Convergence::holds(const MapState &map, uint32_t node) const
{
    const NodeState &state = map.nodes[node];
    if (!state.anchor()) {
        return false;
    }
    if (!state.free() || state.converged()) {
        return true;
    }
    return state.doubt == NodeDoubt::Flexible && settled(state) && state.solve.solved &&
           regionSemiAxisM(state.solve.covariance_m2) < params_.reliable_m;
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

StructureCheck::StructureCheck(const EngineParams &params, const RangeLikelihood &likelihood)
    : params_(params.convergence), placement_(params.placement), likelihood_(likelihood)
{
    solver_.range_sigma_m = params.range.sigma_m;
    solver_.max_iterations = std::max<uint32_t>(params.refinement.max_iterations, 1U);
    solver_.anchor_uncertainty_in_solve = false;
}

StructureVerdict StructureCheck::run(const MapProblem &problem, const MapEstimate &estimate,
                                     const std::vector<StructureNode> &nodes) const
{
    const uint32_t count = problem.nodeCount();
    StructureVerdict verdict;
    verdict.doubt.assign(count, NodeDoubt::None);
    verdict.hinge.assign(count, {kNoHinge, kNoHinge});
    // Foldable parts of the link graph of the placed nodes (fixed ones anchor a part).
    std::vector<uint8_t> anchored(count, 0);
    for (uint32_t node = 0; node < count; ++node) {
        anchored[node] = nodes[node].anchored ? 1 : 0;
    }
    std::vector<std::pair<uint32_t, uint32_t>> edges;
    edges.reserve(problem.links.size());
    for (const MapLink &link : problem.links) {
        edges.emplace_back(link.a, link.b);
    }
    const Foldable folds = findFoldable(count, edges, estimate.placed, anchored);
    const double reliable = params_.reliable_m;
    std::vector<uint8_t> movable; // filled when first needed
    for (uint32_t node = 0; node < count; ++node) {
        if (estimate.placed[node] == 0 || !nodes[node].free) {
            continue;
        }
        NodeDoubt doubt = NodeDoubt::None;
        if (folds.foldable[node] != 0) {
            doubt = NodeDoubt::Foldable;
            verdict.hinge[node] = folds.hinge[node];
        }
        const NodeSolveView &solve = nodes[node].solve;
        if (doubt == NodeDoubt::None && solve.solved && solve.disputed) {
            doubt = NodeDoubt::Ambiguous;
        }
        if (doubt == NodeDoubt::None) {
            // A distinct position that explains its links about as well as where it is.
            std::vector<RangeConstraint> constraints = placedConstraints(problem, estimate, node);
            for (RangeConstraint &constraint : constraints) {
                const StructureNode &other = nodes[problem.other(constraint.link, node)];
                constraint.anchor_covariance_m2 = other.anchored ? Matrix2::Zero() : other.covariance_m2;
            }
            if (constraints.size() >= 3) {
                const Vector2 &position_m = estimate.position_m[node];
                const double here = robustCost(constraints, position_m, likelihood_, solver_.range_sigma_m);
                const std::vector<PlacementCandidate> candidates =
                    placementCandidates(constraints, likelihood_, solver_, placement_);
                for (const PlacementCandidate &candidate : candidates) {
                    if ((candidate.position_m - position_m).norm() > placement_.distinct_m &&
                        candidate.cost < here + placement_.ambiguity_gap_nats / 4.0) {
                        doubt = NodeDoubt::Ambiguous;
                        break;
                    }
                }
                // The same with its free neighbours following it (second_place.hpp): a rival map of
                // the neighbourhood, judged by the gap the global solve judges rival maps by.
                std::optional<NodeNeighbourhood> neighbourhood; // built when first needed
                for (const PlacementCandidate &candidate : candidates) {
                    if (doubt != NodeDoubt::None) {
                        break;
                    }
                    if ((candidate.position_m - position_m).norm() <= placement_.distinct_m ||
                        candidate.cost >= here + kNeighbourhoodWindowNats) {
                        continue;
                    }
                    if (movable.empty()) {
                        movable.assign(count, 0);
                        for (uint32_t n = 0; n < count; ++n) {
                            movable[n] = estimate.placed[n] != 0 && nodes[n].free ? 1 : 0;
                        }
                    }
                    if (!neighbourhood) {
                        neighbourhood.emplace(problem, estimate, movable, node, likelihood_);
                    }
                    const SecondPlace second = neighbourhood->from(candidate.position_m);
                    if ((second.there_m - position_m).norm() > placement_.distinct_m &&
                        second.cost_nats < neighbourhood->costHereNats() + kNeighbourhoodGapNats) {
                        doubt = NodeDoubt::Ambiguous;
                    }
                }
            }
        }
        if (doubt == NodeDoubt::None && solve.solved) {
            const double largest_m = regionSemiAxisM(solve.covariance_m2);
            // Baarda's bound: an error in one link just too small to be noticed, all of it on the
            // weakest link. Where few links hold a part of the map (two wings joined by four, one
            // of them redundant) such errors are what walls put there: two wings' joint links read
            // 0.65 m long turned one wing 1.5 m at its far end, within the 2.0 m bound. A node
            // that one such error could move beyond the promise is not converged.
            if (!solve.main_part || !(solve.reliability_m < reliable) || !(largest_m < reliable)) {
                doubt = NodeDoubt::Flexible;
            }
        }
        verdict.doubt[node] = doubt;
    }
    peelUnheld(problem, estimate, nodes, verdict);
    return verdict;
}

void StructureCheck::peelUnheld(const MapProblem &problem, const MapEstimate &estimate,
                                const std::vector<StructureNode> &nodes, StructureVerdict &verdict) const
{
    // A node is determined only by nodes that are themselves determined: the ones the checks above
    // pass (with the fixed and pinned ones) must hold each other. Peeled until none is left to
    // peel: a free node with fewer than three links to the rest of them, or whose links to them
    // leave a direction along which an excess of `common_excess_m` (the noise at least) on those
    // links would move it 2 sigma by `reliable_m` or more (the smallest eigenvalue of sum u u^T
    // below (2 sigma / reliable_m)^2), is flexible: its links to nodes the map cannot vouch for
    // are what puts it where it is. A corridor's junction node whose converged neighbours are all
    // along the corridor, and the map around it bent by walls, would otherwise be called converged
    // however wrong that map is.
    const uint32_t count = problem.nodeCount();
    const double sigma_m = std::hypot(params_.common_excess_m, solver_.range_sigma_m);
    const double least_eigenvalue = std::pow(2.0 * sigma_m / params_.reliable_m, 2);
    std::vector<uint8_t> held(count, 0);
    for (uint32_t node = 0; node < count; ++node) {
        held[node] =
            estimate.placed[node] != 0 && (!nodes[node].free || verdict.doubt[node] == NodeDoubt::None) ? 1 : 0;
    }
    for (bool peeled = true; peeled;) {
        peeled = false;
        std::vector<uint32_t> unheld;
        for (uint32_t node = 0; node < count; ++node) {
            if (held[node] == 0 || !nodes[node].free) {
                continue;
            }
            Matrix2 directions = Matrix2::Zero(); // sum of u u^T over its links to held nodes
            uint32_t links = 0;
            for (const uint32_t neighbour : problem.neighbours[node]) {
                const Vector2 delta = estimate.position_m[neighbour] - estimate.position_m[node];
                const double distance_m = delta.norm();
                if (held[neighbour] == 0 || distance_m < 1e-9) {
                    continue;
                }
                const Vector2 u = delta / distance_m;
                directions += u * u.transpose();
                ++links;
            }
            if (links < 3 || minEigenvalue(directions) < least_eigenvalue) {
                unheld.push_back(node);
            }
        }
        for (const uint32_t node : unheld) {
            held[node] = 0;
            verdict.doubt[node] = NodeDoubt::Flexible;
            peeled = true;
        }
    }
}

void Convergence::assess(MapState &map)
{
    // The map as it stands, as a problem over every node (numbered by index) and the links between
    // still, placed nodes, at the ranges the filter uses.
    const auto count = static_cast<uint32_t>(map.nodes.size());
    MapProblem problem;
    MapEstimate estimate = MapEstimate::unplaced(count);
    std::vector<StructureNode> nodes(count);
    std::vector<uint32_t> node_of(count);
    for (uint32_t node = 0; node < count; ++node) {
        const NodeState &state = map.nodes[node];
        problem.ids.push_back(state.id);
        node_of[node] = node;
        estimate.placed[node] = state.anchor() ? 1 : 0;
        estimate.position_m[node] = state.position_m;
        nodes[node].free = state.free();
        nodes[node].anchored = state.fixed();
        nodes[node].covariance_m2 = state.covariance_m2;
        nodes[node].solve = state.solve;
    }
    for (const LinkState &link : map.links) {
        if (estimate.placed[link.node_a] != 0 && estimate.placed[link.node_b] != 0) {
            problem.links.push_back(MapLink{link.node_a, link.node_b, link.representative_m});
        }
    }
    problem.finish();
    adoptStructure(map, check_.run(problem, estimate, nodes), node_of);
}

void Convergence::adoptStructure(MapState &map, const StructureVerdict &verdict, const std::vector<uint32_t> &node_of)
{
    ++counters_.assessments;
    const auto count = static_cast<uint32_t>(map.nodes.size());
    structural_.assign(count, NodeDoubt::None);
    for (NodeState &state : map.nodes) {
        state.hinge = {kNoIndex, kNoIndex};
    }
    ConvergenceCounters &c = counters_;
    c.ambiguous_nodes = 0;
    c.foldable_nodes = 0;
    c.flexible_nodes = 0;
    for (uint32_t i = 0; i < verdict.doubt.size(); ++i) {
        const uint32_t node = node_of[i];
        NodeState &state = map.nodes[node];
        // A node that started moving, or was let go, since the verdict's map: nothing to say.
        if (!state.anchor() || !state.free()) {
            continue;
        }
        const NodeDoubt doubt = verdict.doubt[i];
        structural_[node] = doubt;
        for (size_t end = 0; end < 2; ++end) {
            const uint32_t hinge = verdict.hinge[i][end];
            state.hinge[end] = hinge == kNoHinge ? kNoIndex : node_of[hinge];
        }
        c.ambiguous_nodes += doubt == NodeDoubt::Ambiguous ? 1U : 0U;
        c.foldable_nodes += doubt == NodeDoubt::Foldable ? 1U : 0U;
        c.flexible_nodes += doubt == NodeDoubt::Flexible ? 1U : 0U;
    }
    for (uint32_t node = 0; node < count; ++node) {
        decide(map, node);
    }
}

} // namespace cdro::engine
