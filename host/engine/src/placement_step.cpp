#include "cdro/engine/placement_step.hpp"

#include <algorithm>
#include <optional>

#include "cdro/engine/placement.hpp"

namespace cdro::engine {

PlacementStep::PlacementStep(const EngineParams &params, const RangeLikelihood &likelihood)
    : params_(params), likelihood_(likelihood)
{
    solver_.range_sigma_m = params.range.sigma_m;
    solver_.max_iterations = 8;
}

void PlacementStep::markPending(const MapState &map, uint32_t node)
{
    if (pending_.size() < map.nodes.size()) {
        pending_.resize(map.nodes.size(), 0);
    }
    if (!map.nodes[node].placed()) {
        pending_[node] = 1;
        any_pending_ = true;
    }
}

void PlacementStep::countWaitingRange(MapState &map, uint32_t node)
{
    NodeState &state = map.nodes[node];
    if (state.placed()) {
        return;
    }
    ++state.waiting_ranges;
    // Patience runs out: look at it again even if nothing else changed.
    if (state.waiting_ranges == params_.placement.patience_ranges) {
        markPending(map, node);
    }
}

void PlacementStep::place(MapState &map, uint32_t node, const Vector2 &position_m, const Matrix2 &covariance_m2)
{
    NodeState &state = map.nodes[node];
    if (state.lifecycle == NodeLifecycle::Unplaced) {
        state.lifecycle = state.motion.reported_moving ? NodeLifecycle::Moving : NodeLifecycle::Placed;
    }
    state.position_m = position_m;
    // Never start more certain than one range could make it.
    const double variance = params_.range.sigma_m * params_.range.sigma_m;
    state.covariance_m2 = covariance_m2.allFinite() ? symmetricPart(covariance_m2) : Matrix2::Identity();
    if (minEigenvalue(state.covariance_m2) < variance) {
        state.covariance_m2 += variance * Matrix2::Identity();
    }
    state.average_m = position_m;
    state.still_updates = 0;
    state.update_count = 0;
    state.doubt = NodeDoubt::Unsettled;
    ++state.placements;
    state.waiting_ranges = 0;
    ++counters_.placements;
    if (node < pending_.size()) {
        pending_[node] = 0;
    }
    for (uint32_t link : state.links) {
        markPending(map, map.otherNode(link, node));
    }
}

void PlacementStep::unplace(MapState &map, uint32_t node)
{
    map.nodes[node].lifecycle = NodeLifecycle::Unplaced;
    map.nodes[node].doubt = NodeDoubt::None;
    ++counters_.replacements;
    markPending(map, node);
}

bool PlacementStep::placeFrame(MapState &map, const OutputFrame &frame)
{
    std::optional<std::array<uint32_t, 3>> preferred;
    const FrameParams &named = params_.frame;
    if (named.origin != 0 && named.x_axis != 0 && named.positive_y != 0) {
        preferred = std::array<uint32_t, 3>{map.findNode(named.origin), map.findNode(named.x_axis),
                                            map.findNode(named.positive_y)};
    }
    const std::optional<FrameTriangle> triangle =
        chooseFrameTriangle(map, params_.placement, frame.eligible(map, false), preferred);
    if (!triangle) {
        return false;
    }
    const double variance = params_.range.sigma_m * params_.range.sigma_m;
    const Matrix2 covariance = variance * Matrix2::Identity();
    map.frame_nodes = std::array<uint32_t, 3>{triangle->origin, triangle->x_axis, triangle->positive_y};
    place(map, triangle->origin, triangle->origin_m, covariance);
    place(map, triangle->x_axis, triangle->x_axis_m, covariance);
    place(map, triangle->positive_y, triangle->positive_y_m, covariance);
    return true;
}

bool PlacementStep::placeByHandedness(MapState &map, const std::vector<uint32_t> &nodes,
                                      const std::function<void(const std::string &)> &trace)
{
    std::vector<Vector2> fixed;
    for (const NodeState &node : map.nodes) {
        if (node.fixed()) {
            fixed.push_back(node.position_m);
        }
    }
    if (fixed.size() != 2) {
        return false;
    }
    const Vector2 axis = fixed[1] - fixed[0];
    for (uint32_t node : nodes) {
        const std::vector<RangeConstraint> constraints = placedConstraints(map, node);
        if (constraints.size() < 2) {
            continue;
        }
        for (const PlacementCandidate &candidate :
             placementCandidates(constraints, likelihood_, solver_, params_.placement)) {
            const Vector2 offset = candidate.position_m - fixed[0];
            if (axis.x() * offset.y() - axis.y() * offset.x() > 0.0) {
                if (trace) {
                    trace("node " + std::to_string(map.nodes[node].id) +
                          " placed on the left of the two fixed nodes (the mirror image fits as well)");
                }
                place(map, node, candidate.position_m, candidate.covariance_m2);
                return true;
            }
        }
    }
    return false;
}

std::vector<uint32_t> PlacementStep::run(MapState &map, bool frame_held, const OutputFrame &frame,
                                         const std::function<void(const std::string &)> &trace, uint64_t most)
{
    std::vector<uint32_t> placed_now;
    any_pending_ = false;
    if (pending_.size() < map.nodes.size()) {
        pending_.resize(map.nodes.size(), 0);
    }
    const uint64_t before = counters_.placements;
    std::vector<uint8_t> was_placed(map.nodes.size(), 0);
    for (uint32_t node = 0; node < map.nodes.size(); ++node) {
        was_placed[node] = map.nodes[node].placed() ? 1 : 0;
    }
    if (map.placedCount() == 0) {
        // With fewer than two fixed nodes the frame comes from a triangle of ranges.
        if (frame_held || !placeFrame(map, frame)) {
            // Nothing to start from yet: every linked node stays pending for the next link.
            for (uint32_t node = 0; node < map.nodes.size(); ++node) {
                if (!map.nodes[node].links.empty()) {
                    pending_[node] = 1;
                    any_pending_ = true;
                }
            }
            return placed_now;
        }
    }
    const uint64_t first = counters_.placements; // the frame's three placed above count as one
    auto full = [&] { return counters_.placements - first >= std::max<uint64_t>(most, 1); };
    std::vector<uint32_t> ambiguous;
    for (;;) {
        // Decisive placements first, repeated while they make progress.
        bool progress = true;
        while (progress && !full()) {
            progress = false;
            ambiguous.clear();
            for (uint32_t node = 0; node < map.nodes.size(); ++node) {
                NodeState &state = map.nodes[node];
                if (full()) {
                    any_pending_ = true; // the rest waits for the next run
                    break;
                }
                if (state.placed() || pending_[node] == 0) {
                    continue;
                }
                const std::vector<RangeConstraint> constraints = placedConstraints(map, node);
                if (constraints.size() < 2 || state.placements >= params_.refinement.max_placements) {
                    pending_[node] = 0; // waits for a placed neighbour or a link
                    continue;
                }
                const std::vector<PlacementCandidate> candidates =
                    placementCandidates(constraints, likelihood_, solver_, params_.placement);
                const PlacementChoice choice = choosePlacement(candidates, constraints.size(), params_.placement);
                if (choice.decision == PlacementDecision::Placed) {
                    place(map, node, choice.chosen.position_m, choice.chosen.covariance_m2);
                    progress = true;
                } else if (constraints.size() >= 3 && !candidates.empty() &&
                           state.waiting_ranges >= params_.placement.patience_ranges) {
                    // Noisy ranges may never make the choice clear: after enough of them, the
                    // best explanation is taken (the SoGs, the refinement and the global solve can
                    // still move it).
                    if (trace) {
                        trace("node " + std::to_string(state.id) + " stayed ambiguous for " +
                              std::to_string(state.waiting_ranges) + " ranges: placed at its best candidate");
                    }
                    place(map, node, candidates.front().position_m, candidates.front().covariance_m2);
                    ++counters_.placements_forced;
                    progress = true;
                } else {
                    ++counters_.placement_ambiguous;
                    ambiguous.push_back(node);
                }
            }
        }
        if (!full() && !ambiguous.empty() && frame.fixedFrameNodes() == 2 && map.placedCount() == 2 &&
            placeByHandedness(map, ambiguous, trace)) {
            continue;
        }
        break;
    }
    // Nodes still ambiguous are looked at again when their neighbourhood changes.
    for (uint32_t node : ambiguous) {
        pending_[node] = 0;
    }
    if (counters_.placements != before) {
        for (uint32_t node = 0; node < map.nodes.size(); ++node) {
            if (was_placed[node] == 0 && map.nodes[node].placed()) {
                placed_now.push_back(node);
            }
        }
    }
    return placed_now;
}

} // namespace cdro::engine
