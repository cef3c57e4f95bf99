#include "cdro/engine/engine.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "cdro/engine/joint_solver.hpp"
#include "cdro/engine/mds.hpp"
#include "cdro/engine/placement.hpp"
#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

const char *rangeVerdictName(RangeVerdict verdict)
{
    switch (verdict) {
    case RangeVerdict::Used: return "used";
    case RangeVerdict::Stored: return "stored";
    case RangeVerdict::RejectedSelf: return "rejected: a node ranging itself";
    case RangeVerdict::RejectedValue: return "rejected: not a plausible range";
    }
    return "unknown";
}

Engine::Engine(const EngineParams &params) : params_(params), likelihood_(params.likelihood)
{
    params_.ring.radial_sigma_m = params_.range.sigma_m;
    solver_.range_sigma_m = params_.range.sigma_m;
    solver_.max_iterations = 8;
    refine_solver_ = solver_;
    refine_solver_.max_iterations = std::max<uint32_t>(params_.refinement.max_iterations, 1U);
    refine_solver_.anchor_uncertainty_in_solve = false;
}

uint32_t Engine::nodeIndex(NodeId id)
{
    const uint32_t index = network_.addNode(id);
    if (placement_pending_.size() < network_.nodes.size()) {
        placement_pending_.resize(network_.nodes.size(), false);
        in_relax_queue_.resize(network_.nodes.size(), false);
    }
    return index;
}

void Engine::setHeight(NodeId id, double height_m)
{
    NodeState &state = network_.nodes[nodeIndex(id)];
    state.height_known = true;
    state.height_m = height_m;
}

void Engine::setFixed(NodeId id, const Vector2 &position_m)
{
    if (fixed_applied_) {
        throw std::logic_error("fixed nodes must be given before the first range");
    }
    nodeIndex(id);
    for (auto &entry : fixed_positions_) {
        if (entry.first == id) {
            entry.second = position_m;
            return;
        }
    }
    fixed_positions_.emplace_back(id, position_m);
}

void Engine::applyFixedNodes()
{
    fixed_applied_ = true;
    if (fixed_positions_.size() == 1) {
        // One known node fixes only where the map sits: it is estimated like any other and the
        // output is shifted onto its coordinates (outputTransform).
        single_fixed_ = fixed_positions_.front();
        return;
    }
    for (const auto &[id, position_m] : fixed_positions_) {
        NodeState &state = network_.nodes[network_.findNode(id)];
        state.fixed = true;
        state.placed = true;
        state.converged = true;
        state.position_m = position_m;
        state.average_m = position_m;
        state.covariance_m2.setZero();
        ++fixed_count_;
    }
    ++revision_;
}

void Engine::setMoving(NodeId id, bool moving)
{
    const uint32_t node = nodeIndex(id);
    network_.nodes[node].motion_reported = true;
    applyMotion(node, moving);
}

void Engine::applyMotion(uint32_t node, bool moving)
{
    NodeState &state = network_.nodes[node];
    if (state.moving == moving) {
        return;
    }
    state.moving = moving;
    state.motion_inferred = false;
    ++revision_;
    if (!params_.motion.reset) {
        return; // the ablation: the flag is shown, the node is handled as static
    }
    moving ? ++counters_.motion_starts : ++counters_.motion_stops;
    trace("node " + std::to_string(state.id) + (moving ? " moves" : " stopped"));
    state.converged = false;
    state.still_updates = 0;
    state.track_anchor_m = state.position_m;
    state.track_updates = 0;
    state.recent_count = 0;
    // Stopping: the track, at rest, stays the estimate until every link has a range again
    // (the links start afresh below, and a median of nothing is no range).
    state.settling = !moving && state.has_track && params_.motion.track;
    if (state.settling) {
        state.track.stop();
        state.position_m = state.track.position();
    } else {
        state.has_track = false;
    }
    for (uint32_t link : state.links) {
        // Ranges from before the change describe another place: start the links afresh.
        network_.links[link].window.clear();
        // The SoGs centred on the node describe its neighbours from where it was.
        uint32_t &slot = ringSlot(link, node);
        if (slot != kNoIndex) {
            rings_[slot] = RingSog{};
            free_rings_.push_back(slot);
            slot = kNoIndex;
        }
    }
    if (!moving && state.placed) {
        ensureRings(node); // generated again around where it stopped
    }
    // Neighbours lose (or regain) an anchor.
    enqueueNeighbours(node);
}

void Engine::refreshLinkRange(uint32_t link)
{
    LinkState &state = network_.links[link];
    const bool tracking = params_.motion.reset &&
                          (network_.nodes[state.node_a].moving || network_.nodes[state.node_b].moving);
    // A moving end makes old ranges wrong: its link's range is the newest one.
    state.representative_m = tracking ? state.window.newest() : state.window.median();
}

void Engine::pinNode(NodeId id, const Vector2 &position_m, const Matrix2 &covariance_m2)
{
    const uint32_t node = nodeIndex(id);
    NodeState &state = network_.nodes[node];
    const Vector2 delta = position_m - state.position_m;
    const bool was_placed = state.placed;
    state.pinned = true;
    state.placed = true;
    state.position_m = position_m;
    state.covariance_m2 = covariance_m2;
    if (was_placed) {
        for (uint32_t link : state.links) {
            const uint32_t slot = ringSlot(link, node);
            if (slot != kNoIndex) {
                rings_[slot].translate(delta);
            }
        }
    } else {
        ensureRings(node);
    }
    ++revision_;
}

void Engine::unpinNode(NodeId id)
{
    const uint32_t node = network_.findNode(id);
    if (node != kNoIndex && network_.nodes[node].pinned) {
        network_.nodes[node].pinned = false;
        enqueue(node);
    }
}

void Engine::updateTrack(uint32_t moving_node, uint32_t anchor_node, double range_m, double t_s)
{
    NodeState &state = network_.nodes[moving_node];
    const NodeState &anchor = network_.nodes[anchor_node];
    const MotionParams &motion = params_.motion;
    if (!motion.reset || !motion.track || !(state.moving || state.settling) || anchor.moving || !anchor.placed) {
        return;
    }
    if (!state.has_track) {
        // An inferred motion is found late: the node is already somewhere else, by metres.
        const double position_sigma = state.motion_inferred ? 2.0 : 0.3;
        state.track = MotionTrack(state.position_m, position_sigma, motion.track_speed_sigma_mps);
        state.has_track = true;
    }
    // At rest (settling) only a little jitter is allowed, not walking.
    state.track.predict(t_s, state.settling ? 0.05 : motion.track_accel_sigma_mps2);
    const Matrix2 anchor_covariance = anchor.fixed ? Matrix2::Zero() : anchor.covariance_m2;
    if (state.track.updateRange(anchor.position_m, anchor_covariance, range_m, params_.range.sigma_m, likelihood_,
                                params_.sog.gate_sigma)) {
        state.track.limitSpeed(motion.track_max_speed_mps);
        ++counters_.track_updates;
    } else {
        ++counters_.track_refused;
    }
}

void Engine::watchForMotion(uint32_t node, uint32_t link, double residual_m)
{
    // The fallback detector: a node that has no motion reports moves when several of its
    // recent ranges, on different links, read far from the map (one NLOS link reads far on
    // one link only).
    NodeState &state = network_.nodes[node];
    const MotionParams &motion = params_.motion;
    if (!motion.reset || !motion.infer_from_ranges || state.motion_reported || state.moving || state.fixed) {
        return;
    }
    const uint32_t window = std::clamp<uint32_t>(motion.inferred_window, 1U, NodeState::kRecentRanges);
    state.recent_links[state.recent_next] = link;
    // Large means beyond both the configured distance and four standard deviations of the noise.
    const double large_m = std::max(motion.inferred_residual_m, 4.0 * params_.range.sigma_m);
    state.recent_large[state.recent_next] = std::abs(residual_m) > large_m;
    state.recent_next = (state.recent_next + 1) % window;
    state.recent_count = std::min(state.recent_count + 1, window);
    uint32_t large = 0;
    std::vector<uint32_t> large_links;
    for (uint32_t i = 0; i < state.recent_count; ++i) {
        if (state.recent_large[i]) {
            ++large;
            if (std::find(large_links.begin(), large_links.end(), state.recent_links[i]) == large_links.end()) {
                large_links.push_back(state.recent_links[i]);
            }
        }
    }
    if (large >= motion.inferred_min_large && large_links.size() >= motion.inferred_min_links) {
        ++counters_.motion_inferred;
        trace("node " + std::to_string(state.id) + ": " + std::to_string(large) + " of its last " +
              std::to_string(state.recent_count) + " ranges read far from the map: taken as moving");
        applyMotion(node, true);
        state.motion_inferred = true;
    }
}

RangeVerdict Engine::addRange(NodeId from, NodeId to, double range_m, double t_s)
{
    ++counters_.ranges_received;
    if (std::isfinite(t_s)) {
        last_time_s_ = std::max(last_time_s_, t_s);
    }
    if (from == to) {
        ++counters_.rejected_self;
        return RangeVerdict::RejectedSelf;
    }
    if (!std::isfinite(range_m) || range_m <= 0.0 || range_m > params_.range.max_range_m) {
        ++counters_.rejected_value;
        return RangeVerdict::RejectedValue;
    }
    const uint32_t a = nodeIndex(from);
    const uint32_t b = nodeIndex(to);
    double planar_m = range_m;
    const NodeState &state_a = network_.nodes[a];
    const NodeState &state_b = network_.nodes[b];
    if (state_a.height_known && state_b.height_known) {
        bool clamped = false;
        planar_m = projectRange(range_m, state_a.height_m - state_b.height_m, &clamped);
        counters_.projection_clamped += clamped ? 1U : 0U;
    }
    const size_t links_before = network_.links.size();
    const uint32_t link = network_.addLink(a, b, params_.range.window);
    LinkState &state = network_.links[link];
    // How far this range is from the link's own recent ranges (a static NLOS link reads long
    // but consistently; a node that moves reads differently from before).
    const double jump_m = state.window.size() > 0 ? planar_m - state.window.median() : 0.0;
    state.window.push(planar_m);
    refreshLinkRange(link);
    state.last_range_m = range_m;
    ++state.range_count;
    ++revision_; // the links are part of the outputs (last range, count)
    // The map is only a reference for motion once both ends have converged on it.
    const NodeState &end_a = network_.nodes[a];
    const NodeState &end_b = network_.nodes[b];
    if (end_a.placed && end_b.placed && (end_a.converged || end_a.pinned || end_a.fixed) &&
        (end_b.converged || end_b.pinned || end_b.fixed) && !end_a.moving && !end_b.moving) {
        const double residual = planar_m - (end_a.position_m - end_b.position_m).norm();
        // Far from the map and from the link's own history: something moved.
        const double evidence = std::abs(jump_m) < std::abs(residual) ? jump_m : residual;
        watchForMotion(a, link, evidence);
        watchForMotion(b, link, evidence);
    }
    const ReinitializationParams &again = params_.reinitialization;
    if (network_.links.size() != links_before) {
        ranges_since_new_link_ = 0;
        markPlacementPending(a);
        markPlacementPending(b);
        if (again.enabled && network_.links.size() >= again.min_links &&
            static_cast<double>(network_.links.size()) >= again.link_growth * static_cast<double>(reinit_link_count_)) {
            reinitialize();
        }
    } else if (again.enabled && network_.links.size() != reinit_link_count_ &&
               network_.links.size() >= again.min_links &&
               static_cast<double>(++ranges_since_new_link_) >=
                   again.quiet_ranges_per_link * static_cast<double>(network_.links.size())) {
        // The network seems complete: initialize once more on every link it has.
        reinitialize();
    }
    if (any_placement_pending_) {
        runPlacement();
    }
    if (!network_.nodes[a].placed || !network_.nodes[b].placed) {
        for (uint32_t end : {a, b}) {
            NodeState &waiting = network_.nodes[end];
            if (!waiting.placed) {
                ++waiting.ambiguous_ranges;
                // Patience runs out: look at it again even if nothing else changed.
                if (waiting.ambiguous_ranges == params_.placement.patience_ranges) {
                    markPlacementPending(end);
                }
            }
        }
        if (any_placement_pending_) {
            runPlacement();
        }
        ++counters_.ranges_stored;
        relax(params_.refinement.relax_per_range);
        return RangeVerdict::Stored;
    }
    ++counters_.ranges_used;
    if (std::isfinite(t_s)) {
        updateTrack(a, b, planar_m, t_s);
        updateTrack(b, a, planar_m, t_s);
    }
    updateRing(link, a, planar_m);
    updateRing(link, b, planar_m);
    updateNode(a, true);
    updateNode(b, true);
    relax(params_.refinement.relax_per_range);
    return RangeVerdict::Used;
}

void Engine::markPlacementPending(uint32_t node)
{
    if (!network_.nodes[node].placed) {
        placement_pending_[node] = true;
        any_placement_pending_ = true;
    }
}

// ---- placement ------------------------------------------------------------------------------

bool Engine::placeFrame()
{
    if (frame_held_) {
        return false;
    }
    std::vector<bool> eligible(network_.nodes.size(), true);
    std::optional<std::array<uint32_t, 3>> preferred;
    const FrameParams &frame = params_.frame;
    if (frame.origin != 0 && frame.x_axis != 0 && frame.positive_y != 0) {
        preferred = std::array<uint32_t, 3>{network_.findNode(frame.origin), network_.findNode(frame.x_axis),
                                            network_.findNode(frame.positive_y)};
    }
    const std::optional<FrameTriangle> triangle = chooseFrameTriangle(network_, params_.placement, eligible, preferred);
    if (!triangle) {
        return false;
    }
    const double variance = params_.range.sigma_m * params_.range.sigma_m;
    const Matrix2 covariance = variance * Matrix2::Identity();
    frame_nodes_ = std::array<uint32_t, 3>{triangle->origin, triangle->x_axis, triangle->positive_y};
    placeNode(triangle->origin, triangle->origin_m, covariance);
    placeNode(triangle->x_axis, triangle->x_axis_m, covariance);
    placeNode(triangle->positive_y, triangle->positive_y_m, covariance);
    return true;
}

void Engine::runPlacement()
{
    if (placing_) {
        return; // re-entered from the relaxation below: the outer loop sees the pending nodes
    }
    placing_ = true;
    any_placement_pending_ = false;
    if (!fixed_applied_) {
        applyFixedNodes();
    }
    const bool anything_placed = std::any_of(network_.nodes.begin(), network_.nodes.end(),
                                             [](const NodeState &node) { return node.placed; });
    // With fewer than two fixed nodes the frame comes from a triangle of ranges.
    if (!anything_placed && !placeFrame()) {
        // Nothing to start from yet: every node stays pending for the next link.
        for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
            if (!network_.nodes[node].links.empty()) {
                placement_pending_[node] = true;
                any_placement_pending_ = true;
            }
        }
        placing_ = false;
        return;
    }
    const uint64_t placed_before = counters_.placements;
    std::vector<uint32_t> ambiguous;
    for (;;) {
        // Decisive placements first, repeated while they make progress.
        bool progress = true;
        while (progress) {
            progress = false;
            ambiguous.clear();
            for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
                NodeState &state = network_.nodes[node];
                if (state.placed || !placement_pending_[node]) {
                    continue;
                }
                const std::vector<RangeConstraint> constraints = placedConstraints(network_, node);
                if (constraints.size() < 2) {
                    placement_pending_[node] = false; // waits for a placed neighbour or a link
                    continue;
                }
                if (state.placements >= params_.refinement.max_placements) {
                    placement_pending_[node] = false;
                    continue;
                }
                const std::vector<PlacementCandidate> candidates =
                    placementCandidates(constraints, likelihood_, solver_, params_.placement);
                const PlacementChoice choice =
                    choosePlacement(candidates, constraints.size(), params_.placement, nullptr);
                if (choice.decision == PlacementDecision::Placed) {
                    placement_pending_[node] = false;
                    placeNode(node, choice.chosen.position_m, choice.chosen.covariance_m2);
                    progress = true;
                } else if (constraints.size() >= 3 && !candidates.empty() &&
                           state.ambiguous_ranges >= params_.placement.patience_ranges) {
                    // Noisy ranges may never make the choice clear: after enough of them, the
                    // best explanation is taken (the SoGs and the refinement can still move it).
                    trace("node " + std::to_string(state.id) + " stayed ambiguous for " +
                          std::to_string(state.ambiguous_ranges) + " ranges: placed at its best candidate");
                    placement_pending_[node] = false;
                    placeNode(node, candidates.front().position_m, candidates.front().covariance_m2);
                    ++counters_.placements_forced;
                    progress = true;
                } else {
                    ++counters_.placement_ambiguous;
                    ambiguous.push_back(node);
                }
            }
        }
        if (!ambiguous.empty() && fixed_count_ == 2) {
            // Two fixed nodes fix the frame up to the mirror image through them: the first node
            // placed from them alone takes the side to the left of the first towards the second.
            size_t placed = 0;
            for (const NodeState &node : network_.nodes) {
                placed += node.placed ? 1U : 0U;
            }
            if (placed == 2 && placeByHandedness(ambiguous)) {
                continue;
            }
        }
        if (ambiguous.empty() || !params_.placement.mds_tie_break) {
            break;
        }
        // Stalled on ambiguous nodes: let the coarse global layout decide one, then go on.
        // MDS runs again only when the network has grown since it last could not help.
        if (network_.links.size() == mds_link_count_ && network_.nodes.size() == mds_node_count_) {
            break;
        }
        std::vector<uint32_t> members;
        double layout_error_m = 0.0;
        const std::optional<std::vector<Vector2>> layout = alignedMdsLayout(&members, &layout_error_m);
        bool decided = false;
        if (layout) {
            // Of the nodes the layout can decide, the most clearly decided one goes first; then
            // the ranges take over again.
            PlacementChoice best;
            uint32_t best_node = kNoIndex;
            for (uint32_t node : ambiguous) {
                const auto member = std::find(members.begin(), members.end(), node);
                if (member == members.end()) {
                    continue;
                }
                PlacementHint hint;
                hint.position_m = (*layout)[static_cast<size_t>(member - members.begin())];
                hint.error_m = layout_error_m;
                const std::vector<RangeConstraint> constraints = placedConstraints(network_, node);
                const std::vector<PlacementCandidate> candidates =
                    placementCandidates(constraints, likelihood_, solver_, params_.placement);
                const PlacementChoice choice = choosePlacement(candidates, constraints.size(), params_.placement, &hint);
                if (choice.decision == PlacementDecision::Placed && choice.confidence > best.confidence) {
                    best = choice;
                    best_node = node;
                }
            }
            if (best_node != kNoIndex) {
                trace("tie break: node " + std::to_string(network_.nodes[best_node].id) + " placed at (" +
                      std::to_string(best.chosen.position_m.x()) + ", " + std::to_string(best.chosen.position_m.y()) +
                      ") by the MDS layout (error " + std::to_string(layout_error_m) + " m, confidence " +
                      std::to_string(best.confidence) + ")");
                placement_pending_[best_node] = false;
                placeNode(best_node, best.chosen.position_m, best.chosen.covariance_m2);
                ++counters_.placements_by_tie_break;
                decided = true;
            }
        }
        if (!decided) {
            mds_link_count_ = network_.links.size();
            mds_node_count_ = network_.nodes.size();
            break;
        }
    }
    // Nodes still ambiguous are looked at again when their neighbourhood changes.
    for (uint32_t node : ambiguous) {
        if (!network_.nodes[node].placed) {
            placement_pending_[node] = false;
        }
    }
    const uint64_t newly_placed = counters_.placements - placed_before;
    if (newly_placed > 0) {
        // Let the new part of the map and its surroundings agree before the next range.
        relax(newly_placed * params_.refinement.settle_per_placed);
    }
    placing_ = false;
    if (any_placement_pending_) {
        runPlacement(); // nodes unplaced during that relaxation
    }
}

bool Engine::placeByHandedness(const std::vector<uint32_t> &candidates_nodes)
{
    std::vector<Vector2> fixed;
    for (const NodeState &node : network_.nodes) {
        if (node.fixed) {
            fixed.push_back(node.position_m);
        }
    }
    if (fixed.size() != 2) {
        return false;
    }
    const Vector2 axis = fixed[1] - fixed[0];
    for (uint32_t node : candidates_nodes) {
        const std::vector<RangeConstraint> constraints = placedConstraints(network_, node);
        if (constraints.size() < 2) {
            continue;
        }
        for (const PlacementCandidate &candidate :
             placementCandidates(constraints, likelihood_, solver_, params_.placement)) {
            const Vector2 offset = candidate.position_m - fixed[0];
            if (axis.x() * offset.y() - axis.y() * offset.x() > 0.0) {
                trace("node " + std::to_string(network_.nodes[node].id) +
                      " placed on the left of the two fixed nodes (the mirror image fits as well)");
                placement_pending_[node] = false;
                placeNode(node, candidate.position_m, candidate.covariance_m2);
                return true;
            }
        }
    }
    return false;
}

std::optional<std::vector<Vector2>> Engine::alignedMdsLayout(std::vector<uint32_t> *members, double *error_m)
{
    // The connected component of the link graph that holds the placed nodes.
    members->clear();
    std::vector<bool> seen(network_.nodes.size(), false);
    std::deque<uint32_t> frontier;
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        if (network_.nodes[node].placed && !seen[node]) {
            seen[node] = true;
            frontier.push_back(node);
        }
    }
    while (!frontier.empty()) {
        const uint32_t node = frontier.front();
        frontier.pop_front();
        members->push_back(node);
        for (uint32_t link : network_.nodes[node].links) {
            const uint32_t other = network_.otherNode(link, node);
            if (!seen[other]) {
                seen[other] = true;
                frontier.push_back(other);
            }
        }
    }
    std::sort(members->begin(), members->end());
    ++counters_.mds_layouts;
    std::optional<std::vector<Vector2>> layout = mdsLayout(network_, *members);
    if (!layout) {
        return std::nullopt;
    }
    std::vector<Vector2> source;
    std::vector<Vector2> target;
    for (size_t i = 0; i < members->size(); ++i) {
        const NodeState &state = network_.nodes[(*members)[i]];
        if (state.placed) {
            source.push_back((*layout)[i]);
            target.push_back(state.position_m);
        }
    }
    if (source.size() < 3) {
        return std::nullopt;
    }
    const RigidTransform transform = fitRigid(source, target, true);
    *error_m = transform.rms_error_m;
    for (Vector2 &point : *layout) {
        point = transform.apply(point);
    }
    return layout;
}

void Engine::placeNode(uint32_t node, const Vector2 &position_m, const Matrix2 &covariance_m2)
{
    NodeState &state = network_.nodes[node];
    state.placed = true;
    state.position_m = position_m;
    // Never start more certain than one range could make it.
    const double variance = params_.range.sigma_m * params_.range.sigma_m;
    state.covariance_m2 = covariance_m2.allFinite() ? covariance_m2 : Matrix2::Identity();
    if (minEigenvalue(state.covariance_m2) < variance) {
        state.covariance_m2 += variance * Matrix2::Identity();
    }
    state.average_m = position_m;
    state.still_updates = 0;
    state.update_count = 0;
    state.converged = false;
    ++state.placements;
    state.ambiguous_ranges = 0;
    ++counters_.placements;
    ++revision_;
    ensureRings(node);
    for (uint32_t link : state.links) {
        const uint32_t other = network_.otherNode(link, node);
        markPlacementPending(other);
        if (network_.nodes[other].placed) {
            enqueue(other);
        }
    }
    enqueue(node);
}

void Engine::unplaceNode(uint32_t node)
{
    NodeState &state = network_.nodes[node];
    state.placed = false;
    state.converged = false;
    for (uint32_t link : state.links) {
        LinkState &link_state = network_.links[link];
        for (uint32_t *slot : {&link_state.ring_from_a, &link_state.ring_from_b}) {
            if (*slot != kNoIndex) {
                rings_[*slot] = RingSog{};
                free_rings_.push_back(*slot);
                *slot = kNoIndex;
            }
        }
    }
    ++revision_;
    markPlacementPending(node);
}

uint32_t &Engine::ringSlot(uint32_t link, uint32_t center_node)
{
    LinkState &state = network_.links[link];
    return state.node_a == center_node ? state.ring_from_a : state.ring_from_b;
}

void Engine::ensureRings(uint32_t node)
{
    for (uint32_t link : network_.nodes[node].links) {
        const uint32_t other = network_.otherNode(link, node);
        if (!network_.nodes[other].placed) {
            continue;
        }
        for (const auto &[center, target] : {std::pair{node, other}, std::pair{other, node}}) {
            // No ring describes a fixed node: its position is known.
            if (network_.nodes[target].fixed) {
                continue;
            }
            uint32_t &slot = ringSlot(link, center);
            if (slot != kNoIndex) {
                continue;
            }
            RingSog ring = RingSog::generate(network_.nodes[center].id, network_.nodes[target].id,
                                             network_.nodes[center].position_m,
                                             network_.links[link].representative_m, params_.ring);
            if (!free_rings_.empty()) {
                slot = free_rings_.back();
                free_rings_.pop_back();
                rings_[slot] = std::move(ring);
            } else {
                slot = static_cast<uint32_t>(rings_.size());
                rings_.push_back(std::move(ring));
            }
            // Algorithm 1: a new SoG is weighted by the other nodes' ranges at once (a ring of
            // equal weights would merge into its own centre).
            reweightRing(link, center, network_.links[link].representative_m, true);
        }
    }
}

// ---- the SoG update -------------------------------------------------------------------------

void Engine::updateRing(uint32_t link, uint32_t center_node, double range_m)
{
    const uint32_t target_node = network_.otherNode(link, center_node);
    const NodeState &center = network_.nodes[center_node];
    const NodeState &target = network_.nodes[target_node];
    if (target.fixed || target.pinned) {
        return;
    }
    const bool tracking = params_.motion.reset;
    if (tracking && center.moving) {
        return; // a moving node describes nobody; its SoGs come back when it stops
    }
    if (tracking && target.moving) {
        // Paper Fig. 4(a): the new range resets the SoG around the ranging neighbour; the other
        // neighbours' latest ranges weight it (4(b)).
        uint32_t &slot = ringSlot(link, center_node);
        RingSog ring = RingSog::generate(center.id, target.id, center.position_m, network_.links[link].representative_m,
                                         params_.ring);
        if (slot == kNoIndex) {
            if (!free_rings_.empty()) {
                slot = free_rings_.back();
                free_rings_.pop_back();
            } else {
                slot = static_cast<uint32_t>(rings_.size());
                rings_.emplace_back();
            }
        }
        rings_[slot] = std::move(ring);
        ++counters_.motion_resets;
        reweightRing(link, center_node, range_m, true);
        return;
    }
    if (ringSlot(link, center_node) == kNoIndex) {
        ensureRings(center_node);
    }
    const uint32_t slot = ringSlot(link, center_node);
    if (slot == kNoIndex) {
        return;
    }
    RingSog &ring = rings_[slot];
    const Matrix2 center_covariance = center.fixed ? Matrix2::Zero() : center.covariance_m2;
    const bool full = ring.updateCount() % std::max<uint32_t>(params_.sog.full_update_every, 1U) == 0;
    ring.countUpdate();
    const RangeUpdateResult update =
        ring.updateWithRange(center.position_m, center_covariance, range_m, params_.range.sigma_m,
                             params_.sog.gate_sigma, params_.sog.process_noise_m2, full);
    counters_.ekf_component_updates += update.updated;
    counters_.ekf_gated += update.gated;
    reweightRing(link, center_node, range_m, full);
}

void Engine::reweightRing(uint32_t link, uint32_t center_node, double own_range_m, bool full)
{
    const uint32_t target_node = network_.otherNode(link, center_node);
    const uint32_t slot = ringSlot(link, center_node);
    if (slot == kNoIndex) {
        return;
    }
    RingSog &ring = rings_[slot];
    const NodeState &center = network_.nodes[center_node];
    const NodeState &target = network_.nodes[target_node];
    std::vector<RangeWitness> &witnesses = scratch_witnesses_;
    witnesses.clear();
    if (params_.sog.cooperative) {
        // Eq. 8-11: every other node m that ranged to the target says how far the target is
        // from m; the components that agree gain weight.
        for (uint32_t other_link : target.links) {
            const uint32_t other = network_.otherNode(other_link, target_node);
            if (other == center_node || !network_.nodes[other].placed || network_.nodes[other].moving) {
                continue;
            }
            const NodeState &witness = network_.nodes[other];
            witnesses.push_back(RangeWitness{witness.position_m, witness.fixed ? Matrix2::Zero() : witness.covariance_m2,
                                             network_.links[other_link].representative_m});
        }
    } else {
        // The ablation: the ring's own range only (no other node's opinion).
        witnesses.push_back(RangeWitness{center.position_m, center.fixed ? Matrix2::Zero() : center.covariance_m2,
                                         own_range_m});
    }
    if (witnesses.empty()) {
        return;
    }
    const WeightUpdateResult weights =
        ring.updateWeights(witnesses, likelihood_, params_.range.sigma_m, full, params_.sog.collapse_reset);
    counters_.weight_terms += witnesses.size();
    counters_.weight_terms_downweighted += weights.downweighted;
    if (weights.collapsed) {
        ++counters_.weight_collapses;
    }
    if (params_.sog.weight_transfer) {
        ring.transferWeights(params_.sog.transfer_sigma_m);
        ++counters_.weight_transfers;
    }
}

Gaussian2 Engine::mergeRings(uint32_t node, uint32_t *ring_count) const
{
    // Eq. 12-14: moment matching of every SoG that describes the node; each ring has total
    // weight 1, so each neighbour counts equally.
    Vector2 first = Vector2::Zero();
    Matrix2 second = Matrix2::Zero();
    double total = 0.0;
    *ring_count = 0;
    const NodeState &state = network_.nodes[node];
    for (uint32_t link : state.links) {
        const uint32_t other = network_.otherNode(link, node);
        const LinkState &link_state = network_.links[link];
        const uint32_t slot = link_state.node_a == other ? link_state.ring_from_a : link_state.ring_from_b;
        if (slot == kNoIndex || rings_[slot].empty() || network_.nodes[other].moving) {
            continue;
        }
        rings_[slot].accumulateMoments(&first, &second, &total);
        ++*ring_count;
    }
    Gaussian2 merged;
    if (total <= 0.0) {
        return merged;
    }
    merged.mean_m = first / total;
    merged.covariance_m2 = second / total - merged.mean_m * merged.mean_m.transpose();
    return merged;
}

void Engine::updateNode(uint32_t node, bool after_range)
{
    NodeState &state = network_.nodes[node];
    if (!state.placed || state.fixed || state.pinned) {
        return;
    }
    ++counters_.node_updates;
    const bool tracked = state.moving && params_.motion.reset;
    if (!after_range && !params_.refinement.enabled) {
        // Without refinement the merged SoG is the estimate: a neighbour update repeats the
        // paper's iteration (weights from the other nodes' ranges, transfer) before merging.
        for (uint32_t link : state.links) {
            const uint32_t other = network_.otherNode(link, node);
            if (network_.nodes[other].placed) {
                reweightRing(link, other, network_.links[link].representative_m, false);
            }
        }
    }
    uint32_t ring_count = 0;
    const Gaussian2 merged = mergeRings(node, &ring_count);
    Vector2 position = state.position_m;
    Matrix2 covariance = state.covariance_m2;
    bool replace = false;
    if (state.settling) {
        bool fresh = true;
        for (uint32_t link : state.links) {
            const NodeState &other = network_.nodes[network_.otherNode(link, node)];
            fresh = fresh && (!other.placed || other.moving || network_.links[link].window.size() > 0);
        }
        if (fresh) {
            state.settling = false;
            state.has_track = false;
        }
    }
    if ((tracked || state.settling) && state.has_track && state.track.updates() >= params_.motion.track_warmup) {
        // A moving node's estimate is its track (the SoG resets keep the multimodal picture).
        position = state.track.position();
        covariance = state.track.positionCovariance();
    } else if (params_.refinement.enabled) {
        const std::vector<RangeConstraint> constraints = placedConstraints(network_, node);
        if (constraints.size() >= 2) {
            std::vector<double> inliers;
            PointSolution solution = solvePoint(constraints, state.position_m, likelihood_, refine_solver_, &inliers);
            ++counters_.refinements;
            // The SoG may hold a better hypothesis than the current basin (a flip): try it.
            if (ring_count > 0 && (merged.mean_m - state.position_m).norm() > params_.refinement.hypothesis_switch_m) {
                std::vector<double> alternative_inliers;
                const PointSolution alternative =
                    solvePoint(constraints, merged.mean_m, likelihood_, refine_solver_, &alternative_inliers);
                if (alternative.well_posed &&
                    alternative.cost + params_.refinement.switch_gap_nats < solution.cost) {
                    trace("node " + std::to_string(state.id) + ": its SoGs explain the links better " +
                          std::to_string((alternative.position_m - solution.position_m).norm()) + " m away: moved there");
                    solution = alternative;
                    inliers = alternative_inliers;
                    ++counters_.hypothesis_switches;
                }
            }
            if (solution.well_posed) {
                position = solution.position_m;
                covariance = solution.covariance_m2;
            } else if (ring_count >= 2) {
                position = merged.mean_m;
                covariance = merged.covariance_m2;
            }
            counters_.refinement_links_downweighted += solution.downweighted;
            uint32_t inconsistent = 0;
            const double inconsistent_m =
                std::max(params_.refinement.inconsistent_residual_m, 4.0 * params_.range.sigma_m);
            for (size_t i = 0; i < constraints.size(); ++i) {
                network_.links[constraints[i].link].inlier_probability = inliers[i];
                const double residual = constraints[i].range_m - (position - constraints[i].anchor_m).norm();
                if (std::abs(residual) > inconsistent_m) {
                    ++inconsistent;
                }
            }
            replace = !tracked && inconsistent >= 2 &&
                      static_cast<double>(inconsistent) >
                          params_.refinement.inconsistent_fraction * static_cast<double>(constraints.size()) &&
                      state.placements < params_.refinement.max_placements;
        } else if (ring_count >= 2) {
            position = merged.mean_m;
            covariance = merged.covariance_m2;
        }
    } else if (ring_count >= 2) {
        // One ring says only how far the node is from one neighbour, not where: its moments
        // are the ring's centre, and following them would drag the node onto its neighbour.
        position = merged.mean_m;
        covariance = merged.covariance_m2;
    }
    if (replace) {
        trace("node " + std::to_string(state.id) + " is inconsistent with its links: placed again");
        ++counters_.replacements;
        unplaceNode(node);
        enqueueNeighbours(node);
        return;
    }
    const Vector2 delta = position - state.position_m;
    const bool changed = delta.squaredNorm() > 0.0 || covariance != state.covariance_m2;
    state.position_m = position;
    state.covariance_m2 = covariance;
    // Rings are relative to their centre: they move with it.
    if (delta.squaredNorm() > 0.0 && ringsFollow()) {
        for (uint32_t link : state.links) {
            const uint32_t slot = ringSlot(link, node);
            if (slot != kNoIndex) {
                rings_[slot].translate(delta);
            }
        }
    }
    if (tracked || state.settling) {
        // No convergence while it moves; an inferred motion ends when the track stands still.
        state.converged = false;
        state.still_updates = 0;
        state.average_m = state.position_m;
        if (state.motion_inferred) {
            // Stopped: the track's speed stayed low for a while (or, without a track, the
            // estimate stayed within inferred_still_m).
            const bool slow = state.has_track ? state.track.velocity().norm() < params_.motion.inferred_still_speed_mps
                                              : (state.position_m - state.track_anchor_m).norm() <
                                                    params_.motion.inferred_still_m;
            state.track_updates = slow ? state.track_updates + 1 : 0;
            if (!slow) {
                state.track_anchor_m = state.position_m;
            }
            if (state.track_updates >= params_.motion.inferred_still_updates) {
                applyMotion(node, false);
            }
        }
        if (changed) {
            ++revision_;
        }
        return; // the neighbours do not lean on a moving node
    }
    updateConvergence(state);
    if (changed) {
        ++revision_;
    }
    if (delta.norm() > params_.refinement.relax_threshold_m) {
        enqueueNeighbours(node);
    }
}

void Engine::updateConvergence(NodeState &state)
{
    // Eq. 16 with a count of still steps in a row, so that one small step is not convergence.
    const ConvergenceParams &convergence = params_.convergence;
    const Vector2 previous = state.average_m;
    state.average_m = convergence.smoothing * state.average_m + (1.0 - convergence.smoothing) * state.position_m;
    const double step = (state.average_m - previous).norm();
    state.update_count = state.update_count < UINT32_MAX ? state.update_count + 1 : state.update_count;
    if (step < convergence.threshold_m) {
        state.still_updates = std::min<uint32_t>(state.still_updates + 1, 1000000U);
    } else {
        state.still_updates = 0;
    }
    const bool was = state.converged;
    if (state.still_updates >= convergence.consecutive && state.update_count >= convergence.min_updates &&
        !state.ambiguous) {
        state.converged = true;
    }
    if (step > convergence.unconverge_factor * convergence.threshold_m) {
        state.converged = false;
    }
    if (was != state.converged) {
        ++revision_;
    }
}

// ---- relaxation -----------------------------------------------------------------------------

void Engine::enqueue(uint32_t node)
{
    if (!in_relax_queue_[node] && network_.nodes[node].placed && !network_.nodes[node].fixed &&
        !network_.nodes[node].pinned) {
        in_relax_queue_[node] = true;
        relax_queue_.push_back(node);
    }
}

void Engine::enqueueNeighbours(uint32_t node)
{
    for (uint32_t link : network_.nodes[node].links) {
        enqueue(network_.otherNode(link, node));
    }
}

void Engine::relax(uint64_t budget)
{
    for (uint64_t done = 0; done < budget && !relax_queue_.empty(); ++done) {
        const uint32_t node = relax_queue_.front();
        relax_queue_.pop_front();
        in_relax_queue_[node] = false;
        ++counters_.relaxations;
        updateNode(node);
        if (any_placement_pending_) {
            runPlacement(); // a node found inconsistent was unplaced: place it again
        }
    }
}

uint64_t Engine::settle(uint64_t max_updates)
{
    const uint64_t before = counters_.relaxations;
    if (params_.reinitialization.enabled && network_.links.size() != reinit_link_count_ &&
        network_.links.size() >= params_.reinitialization.min_links) {
        reinitialize();
    }
    if (any_placement_pending_) {
        runPlacement();
    }
    relax(max_updates);
    checkAmbiguity();
    // A quiet map is the evidence eq. 16's average waits for: nodes that are still catching up
    // with a recent jump start their average again where they are, and a few more updates
    // tell whether they stay there.
    bool lagging = false;
    for (NodeState &state : network_.nodes) {
        if (state.placed && !state.fixed && !state.pinned && !state.moving && !state.converged && !state.ambiguous) {
            state.average_m = state.position_m;
            state.still_updates = 0;
            lagging = true;
        }
    }
    if (lagging && relax_queue_.empty()) {
        updateAllNodes(std::max(params_.convergence.consecutive, params_.convergence.min_updates));
    }
    return counters_.relaxations - before;
}

// ---- initialization again -------------------------------------------------------------------

double Engine::mapCost() const
{
    const double unexplained = -std::log(std::max(params_.likelihood.gross_density_per_m, 1e-12));
    const double variance = params_.range.sigma_m * params_.range.sigma_m;
    double cost = 0.0;
    for (const LinkState &link : network_.links) {
        const NodeState &a = network_.nodes[link.node_a];
        const NodeState &b = network_.nodes[link.node_b];
        if (!a.placed || !b.placed) {
            cost += unexplained;
            continue;
        }
        const double residual = link.representative_m - (a.position_m - b.position_m).norm();
        cost -= likelihood_.logDensity(residual, variance);
    }
    return cost;
}

std::unique_ptr<Engine> Engine::unplacedCopy() const
{
    auto fresh = std::make_unique<Engine>(params_);
    fresh->network_ = network_;
    for (NodeState &node : fresh->network_.nodes) {
        if (!node.fixed) {
            node.placed = false;
            node.converged = false;
            node.still_updates = 0;
            node.update_count = 0;
            node.placements = 0;
        }
    }
    for (LinkState &link : fresh->network_.links) {
        link.ring_from_a = kNoIndex;
        link.ring_from_b = kNoIndex;
        link.inlier_probability = 1.0;
    }
    fresh->fixed_positions_ = fixed_positions_;
    fresh->fixed_applied_ = fixed_applied_;
    fresh->fixed_count_ = fixed_count_;
    fresh->single_fixed_ = single_fixed_;
    fresh->reinit_link_count_ = reinit_link_count_;
    fresh->placement_pending_.assign(network_.nodes.size(), false);
    fresh->in_relax_queue_.assign(network_.nodes.size(), false);
    return fresh;
}

bool Engine::placeFromMds()
{
    // The largest connected component, laid out by MDS-MAP; nodes with a single link stay out
    // (one range cannot place anything).
    std::vector<uint32_t> best;
    std::vector<bool> seen(network_.nodes.size(), false);
    for (uint32_t start = 0; start < network_.nodes.size(); ++start) {
        if (seen[start] || network_.nodes[start].links.empty()) {
            continue;
        }
        std::vector<uint32_t> component;
        std::deque<uint32_t> frontier{start};
        seen[start] = true;
        while (!frontier.empty()) {
            const uint32_t node = frontier.front();
            frontier.pop_front();
            component.push_back(node);
            for (uint32_t link : network_.nodes[node].links) {
                const uint32_t other = network_.otherNode(link, node);
                if (!seen[other]) {
                    seen[other] = true;
                    frontier.push_back(other);
                }
            }
        }
        if (component.size() > best.size()) {
            best = std::move(component);
        }
    }
    std::sort(best.begin(), best.end());
    const std::optional<std::vector<Vector2>> layout = mdsLayout(network_, best);
    if (!layout) {
        return false;
    }
    ++counters_.mds_layouts;
    for (size_t i = 0; i < best.size(); ++i) {
        if (network_.nodes[best[i]].links.size() < 2) {
            continue;
        }
        // Metres of uncertainty: the layout is coarse.
        placeNode(best[i], (*layout)[i], 4.0 * Matrix2::Identity());
    }
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        markPlacementPending(node);
    }
    return true;
}

void Engine::sweep(uint32_t sweeps, bool anneal)
{
    // All nodes at once (joint_solver.hpp), with graduated non-convexity when annealing, then
    // the usual node updates so that SoGs, covariances and convergence follow.
    JointSolveParams joint;
    joint.range_sigma_m = params_.range.sigma_m;
    if (!anneal) {
        joint.sigma_scales = {1.0};
    }
    joint.iterations_per_stage = std::max<uint32_t>(sweeps / static_cast<uint32_t>(joint.sigma_scales.size()), 2U);
    std::vector<Vector2> before(network_.nodes.size());
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        before[node] = network_.nodes[node].position_m;
    }
    solveJointly(network_, likelihood_, joint);
    ++counters_.joint_solves;
    // Rings follow their centres; then every node is updated once as a neighbour would be.
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        NodeState &state = network_.nodes[node];
        const Vector2 delta = state.position_m - before[node];
        // A map solved at once is a new starting point: eq. 16's average starts again from it
        // (else it would lag behind the jump for many updates, and convergence with it).
        if (delta.squaredNorm() > 0.0) {
            state.average_m = state.position_m;
            state.still_updates = 0;
        }
        if (delta.squaredNorm() > 0.0 && ringsFollow()) {
            for (uint32_t link : network_.nodes[node].links) {
                const uint32_t slot = ringSlot(link, node);
                if (slot != kNoIndex) {
                    rings_[slot].translate(delta);
                }
            }
        }
    }
}

void Engine::updateAllNodes(uint32_t rounds)
{
    // Every node updated as a neighbour would update it, rounds times each: SoGs, covariances
    // and convergence catch up with a map that was solved at once.
    for (uint32_t round = 0; round < rounds; ++round) {
        for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
            updateNode(node);
            ++counters_.relaxations;
        }
    }
}

uint32_t Engine::escapeLocalMinima()
{
    // Robust refinement only walks downhill: a node can sit on the wrong side of a line of
    // neighbours (a mirror image) with one link written off as NLOS. Look at every local
    // optimum of each node against its neighbours and move it where the links say it is.
    uint32_t moved = 0;
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        NodeState &state = network_.nodes[node];
        if (!state.placed || state.fixed) {
            continue;
        }
        const std::vector<RangeConstraint> constraints = placedConstraints(network_, node);
        if (constraints.size() < 3) {
            continue;
        }
        const std::vector<PlacementCandidate> candidates =
            placementCandidates(constraints, likelihood_, refine_solver_, params_.placement);
        if (candidates.empty()) {
            continue;
        }
        const double here = robustCost(constraints, state.position_m, likelihood_, refine_solver_.range_sigma_m);
        const PlacementCandidate &best = candidates.front();
        if ((best.position_m - state.position_m).norm() > params_.placement.distinct_m &&
            best.cost + params_.refinement.switch_gap_nats < here) {
            const Vector2 delta = best.position_m - state.position_m;
            state.position_m = best.position_m;
            state.average_m = best.position_m;
            state.still_updates = 0;
            state.converged = false;
            for (uint32_t link : state.links) {
                const uint32_t slot = ringSlot(link, node);
                if (slot != kNoIndex) {
                    rings_[slot].translate(delta);
                }
            }
            enqueueNeighbours(node);
            enqueue(node);
            ++counters_.hypothesis_switches;
            ++revision_;
            ++moved;
        }
    }
    return moved;
}

void Engine::ensureFrameNodes()
{
    // The output frame needs three placed nodes that ranged to each other (a map adopted from
    // MDS-MAP has no frame triangle of its own): pick them the way the first triangle is picked.
    if (fixed_count_ >= 2) {
        return;
    }
    if (frame_nodes_ && std::all_of(frame_nodes_->begin(), frame_nodes_->end(),
                                    [&](uint32_t n) { return network_.nodes[n].placed; })) {
        return;
    }
    std::vector<bool> eligible(network_.nodes.size(), false);
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        eligible[node] = network_.nodes[node].placed && !network_.nodes[node].moving;
    }
    const std::optional<FrameTriangle> triangle = chooseFrameTriangle(network_, params_.placement, eligible, std::nullopt);
    if (triangle) {
        frame_nodes_ = std::array<uint32_t, 3>{triangle->origin, triangle->x_axis, triangle->positive_y};
    }
}

uint32_t Engine::checkAmbiguity()
{
    // A node is ambiguous when a distinct position explains its links about as well as where it
    // is: nothing the ranges say decides between them, so it cannot be called converged (the
    // honest answer is "add a link").
    uint32_t count = 0;
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        NodeState &state = network_.nodes[node];
        if (!state.placed || state.fixed || state.pinned || state.moving) {
            state.ambiguous = false;
            continue;
        }
        const std::vector<RangeConstraint> constraints = placedConstraints(network_, node);
        bool ambiguous = constraints.size() < 3;
        if (!ambiguous) {
            const double here = robustCost(constraints, state.position_m, likelihood_, refine_solver_.range_sigma_m);
            for (const PlacementCandidate &candidate :
                 placementCandidates(constraints, likelihood_, refine_solver_, params_.placement)) {
                if ((candidate.position_m - state.position_m).norm() > params_.placement.distinct_m &&
                    candidate.cost < here + params_.placement.ambiguity_gap_nats / 4.0) {
                    ambiguous = true;
                    break;
                }
            }
        }
        if (ambiguous != state.ambiguous) {
            ++revision_;
        }
        state.ambiguous = ambiguous;
        if (ambiguous) {
            state.converged = false;
            ++count;
        }
    }
    counters_.ambiguous_nodes = count;
    return count;
}

bool Engine::reinitialize()
{
    reinit_link_count_ = network_.links.size();
    ++counters_.reinitializations;
    const uint32_t sweeps = params_.reinitialization.sweeps;
    // Candidates: the paper's multilateration on all links, MDS-MAP, and the current map, each
    // refined with graduated non-convexity; against them, the current map refined as it is.
    std::vector<std::unique_ptr<Engine>> candidates;
    std::vector<const char *> names;
    {
        std::unique_ptr<Engine> multilateration = unplacedCopy();
        for (uint32_t node = 0; node < multilateration->network_.nodes.size(); ++node) {
            multilateration->markPlacementPending(node);
        }
        multilateration->runPlacement();
        candidates.push_back(std::move(multilateration));
        names.push_back("multilateration");
    }
    if (fixed_count_ < 2) {
        std::unique_ptr<Engine> mds = unplacedCopy();
        if (mds->placeFromMds()) {
            candidates.push_back(std::move(mds));
            names.push_back("MDS-MAP");
        }
    }
    {
        auto annealed = std::make_unique<Engine>(*this);
        annealed->trace_ = nullptr;
        candidates.push_back(std::move(annealed));
        names.push_back("the current map, annealed");
    }
    for (auto &candidate : candidates) {
        candidate->sweep(sweeps, true);
        if (candidate->any_placement_pending_) {
            candidate->runPlacement();
        }
        if (candidate->escapeLocalMinima() > 0) {
            candidate->sweep(sweeps / 2 + 1, false);
        }
    }
    sweep(sweeps, false);
    size_t best = 0;
    for (size_t i = 1; i < candidates.size(); ++i) {
        if (candidates[i]->mapCost() < candidates[best]->mapCost()) {
            best = i;
        }
    }
    Engine &fresh = *candidates[best];
    const double current_cost = mapCost();
    const double fresh_cost = fresh.mapCost();
    const char *name = names[best];
    trace("initialization again on " + std::to_string(network_.links.size()) + " links: best " + name + ", cost " +
          std::to_string(fresh_cost) + " against " + std::to_string(current_cost) + " nats now");
    const uint32_t rounds = std::max<uint32_t>(params_.convergence.min_updates, 1U);
    if (!(fresh_cost + params_.reinitialization.min_gain_nats < current_cost)) {
        checkAmbiguity();
        updateAllNodes(rounds);
        return false;
    }
    // Adopt it, seen from the current frame so that the outputs do not jump.
    std::vector<Vector2> source;
    std::vector<Vector2> target;
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        if (network_.nodes[node].placed && fresh.network_.nodes[node].placed) {
            source.push_back(fresh.network_.nodes[node].position_m);
            target.push_back(network_.nodes[node].position_m);
        }
    }
    RigidTransform transform;
    if (fixed_count_ < 2 && source.size() >= 2) {
        transform = fitRigid(source, target, true);
    }
    for (NodeState &node : fresh.network_.nodes) {
        if (node.placed && !node.fixed) {
            node.position_m = transform.apply(node.position_m);
            node.average_m = transform.apply(node.average_m);
            node.covariance_m2 = transform.applyToCovariance(node.covariance_m2);
        }
    }
    for (RingSog &ring : fresh.rings_) {
        ring.applyRigid(transform.rotation, transform.translation_m);
    }
    // Keep the current frame's nodes where they are all placed in the new map.
    const bool keep_frame = frame_nodes_ && std::all_of(frame_nodes_->begin(), frame_nodes_->end(), [&](uint32_t n) {
                                return fresh.network_.nodes[n].placed;
                            });
    if (!keep_frame) {
        frame_nodes_ = fresh.frame_nodes_;
    }
    network_ = std::move(fresh.network_);
    rings_ = std::move(fresh.rings_);
    free_rings_ = std::move(fresh.free_rings_);
    placement_pending_ = std::move(fresh.placement_pending_);
    any_placement_pending_ = fresh.any_placement_pending_;
    relax_queue_ = std::move(fresh.relax_queue_);
    in_relax_queue_ = std::move(fresh.in_relax_queue_);
    mds_link_count_ = fresh.mds_link_count_;
    mds_node_count_ = fresh.mds_node_count_;
    ensureFrameNodes();
    ++counters_.reinitializations_adopted;
    ++revision_;
    checkAmbiguity();
    updateAllNodes(rounds);
    return true;
}

// ---- outputs --------------------------------------------------------------------------------

RigidTransform Engine::outputTransform() const
{
    RigidTransform transform;
    if (fixed_count_ >= 2) {
        return transform;
    }
    std::optional<std::array<uint32_t, 3>> frame;
    const FrameParams &named = params_.frame;
    if (named.origin != 0 && named.x_axis != 0 && named.positive_y != 0) {
        const std::array<uint32_t, 3> ids{network_.findNode(named.origin), network_.findNode(named.x_axis),
                                          network_.findNode(named.positive_y)};
        if (std::all_of(ids.begin(), ids.end(), [&](uint32_t n) { return n != kNoIndex && network_.nodes[n].placed; })) {
            frame = ids;
        }
    } else if (frame_nodes_ &&
               std::all_of(frame_nodes_->begin(), frame_nodes_->end(), [&](uint32_t n) { return network_.nodes[n].placed; })) {
        frame = frame_nodes_;
    }
    if (frame) {
        const Vector2 origin = network_.nodes[(*frame)[0]].position_m;
        const Vector2 axis = network_.nodes[(*frame)[1]].position_m - origin;
        if (axis.norm() > kSingularDistanceM) {
            const Vector2 unit_x = axis.normalized();
            Matrix2 rotation;
            rotation << unit_x.x(), unit_x.y(), -unit_x.y(), unit_x.x();
            const Vector2 third = rotation * (network_.nodes[(*frame)[2]].position_m - origin);
            if (third.y() < 0.0) {
                rotation.row(1) *= -1.0;
                transform.reflected = true;
            }
            transform.rotation = rotation;
            transform.translation_m = -rotation * origin;
        }
    }
    if (single_fixed_) {
        const uint32_t node = network_.findNode(single_fixed_->first);
        if (node != kNoIndex && network_.nodes[node].placed) {
            // The fixed node's output is its known coordinates.
            transform.translation_m += single_fixed_->second - transform.apply(network_.nodes[node].position_m);
        }
    }
    return transform;
}

const Foldable &Engine::foldableParts() const
{
    // The key: the links, and which nodes are placed, still and fixed (splitmix64 of each index
    // with its state, summed): cheap next to the O(V (V + E)) search it saves.
    uint64_t key = 0x9E3779B97F4A7C15ULL * (network_.links.size() + 1);
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        const NodeState &state = network_.nodes[node];
        const uint64_t flags = (state.placed ? 1U : 0U) | (state.moving ? 2U : 0U) | (state.fixed ? 4U : 0U);
        uint64_t mixed = (static_cast<uint64_t>(node) << 3U | flags) + 0x9E3779B97F4A7C15ULL;
        mixed = (mixed ^ (mixed >> 30U)) * 0xBF58476D1CE4E5B9ULL;
        mixed = (mixed ^ (mixed >> 27U)) * 0x94D049BB133111EBULL;
        key += mixed ^ (mixed >> 31U);
    }
    if (foldable_valid_ && key == foldable_key_) {
        return foldable_;
    }
    const size_t count = network_.nodes.size();
    std::vector<uint8_t> active(count, 0);
    std::vector<uint8_t> anchored(count, 0);
    for (uint32_t node = 0; node < count; ++node) {
        const NodeState &state = network_.nodes[node];
        // A moving node's ranges hold nothing in place while it moves.
        active[node] = state.placed && !state.moving ? 1 : 0;
        anchored[node] = state.fixed ? 1 : 0;
    }
    std::vector<std::pair<uint32_t, uint32_t>> edges;
    edges.reserve(network_.links.size());
    for (const LinkState &link : network_.links) {
        edges.emplace_back(link.node_a, link.node_b);
    }
    foldable_ = findFoldable(static_cast<uint32_t>(count), edges, active, anchored);
    foldable_key_ = key;
    foldable_valid_ = true;
    return foldable_;
}

uint32_t Engine::foldableCount() const { return foldableParts().count; }

std::vector<NodeOutput> Engine::estimates() const
{
    const Foldable &folds = foldableParts();
    const RigidTransform transform = outputTransform();
    std::vector<NodeOutput> out;
    out.reserve(network_.nodes.size());
    for (const NodeState &state : network_.nodes) {
        NodeOutput node;
        node.id = state.id;
        node.placed = state.placed;
        node.converged = state.placed && state.converged;
        node.moving = state.moving;
        node.fixed = state.fixed;
        node.ambiguous = state.placed && state.ambiguous;
        const uint32_t index = static_cast<uint32_t>(out.size());
        if (state.placed && index < folds.foldable.size() && folds.foldable[index] != 0) {
            node.foldable = true;
            node.converged = false;
            for (uint32_t hinge : folds.hinge[index]) {
                if (hinge != kNoHinge) {
                    node.hinge[node.hinge_nodes++] = network_.nodes[hinge].id;
                }
            }
            if (node.hinge_nodes == 2 && node.hinge[1] < node.hinge[0]) {
                std::swap(node.hinge[0], node.hinge[1]); // by id, as the output lists nodes
            }
        }
        node.height_known = state.height_known;
        node.height_m = state.height_m;
        node.link_count = static_cast<uint32_t>(state.links.size());
        if (state.placed) {
            // A moving node is where its track says it is now, not at its last range.
            const bool predicted = state.moving && state.has_track && std::isfinite(last_time_s_) &&
                                   state.track.updates() >= params_.motion.track_warmup;
            node.position_m = transform.apply(predicted ? state.track.positionAt(last_time_s_) : state.position_m);
            if (single_fixed_ && single_fixed_->first == state.id) {
                node.position_m = single_fixed_->second;
                node.fixed = true;
            }
            node.covariance_m2 = transform.applyToCovariance(state.covariance_m2);
        }
        out.push_back(node);
    }
    std::sort(out.begin(), out.end(), [](const NodeOutput &x, const NodeOutput &y) { return x.id < y.id; });
    return out;
}

std::optional<NodeOutput> Engine::estimate(NodeId id) const
{
    for (const NodeOutput &node : estimates()) {
        if (node.id == id) {
            return node;
        }
    }
    return std::nullopt;
}

std::vector<LinkOutput> Engine::links() const
{
    std::vector<LinkOutput> out;
    out.reserve(network_.links.size());
    for (const LinkState &state : network_.links) {
        LinkOutput link;
        link.a = network_.nodes[state.node_a].id;
        link.b = network_.nodes[state.node_b].id;
        link.last_range_m = state.last_range_m;
        link.range_m = state.representative_m;
        link.range_count = state.range_count;
        link.inlier_probability = state.inlier_probability;
        out.push_back(link);
    }
    std::sort(out.begin(), out.end(), [](const LinkOutput &x, const LinkOutput &y) {
        return x.a != y.a ? x.a < y.a : x.b < y.b;
    });
    return out;
}

std::vector<RingOutput> Engine::ringsDescribing(NodeId id) const
{
    std::vector<RingOutput> out;
    const uint32_t node = network_.findNode(id);
    if (node == kNoIndex) {
        return out;
    }
    const RigidTransform transform = outputTransform();
    for (uint32_t link : network_.nodes[node].links) {
        const uint32_t other = network_.otherNode(link, node);
        const LinkState &state = network_.links[link];
        const uint32_t slot = state.node_a == other ? state.ring_from_a : state.ring_from_b;
        if (slot == kNoIndex || rings_[slot].empty()) {
            continue;
        }
        RingOutput ring;
        ring.center = rings_[slot].center();
        ring.target = rings_[slot].target();
        ring.components = rings_[slot].components();
        for (SogComponentState &component : ring.components) {
            component.mean_m = transform.apply(component.mean_m);
            component.covariance_m2 = transform.applyToCovariance(component.covariance_m2);
        }
        out.push_back(std::move(ring));
    }
    return out;
}

std::optional<std::array<NodeId, 3>> Engine::frameNodes() const
{
    if (!frame_nodes_) {
        return std::nullopt;
    }
    return std::array<NodeId, 3>{network_.nodes[(*frame_nodes_)[0]].id, network_.nodes[(*frame_nodes_)[1]].id,
                                 network_.nodes[(*frame_nodes_)[2]].id};
}

void Engine::restore(const RestoredState &restored)
{
    Network network;
    for (const NodeState &node : restored.nodes) {
        const uint32_t index = network.addNode(node.id);
        if (index != network.nodes.size() - 1) {
            throw std::invalid_argument("node " + std::to_string(node.id) + " appears twice");
        }
        network.nodes[index] = node;
        network.nodes[index].links.clear();
    }
    for (const RestoredLink &link : restored.links) {
        const uint32_t a = network.findNode(link.a);
        const uint32_t b = network.findNode(link.b);
        if (a == kNoIndex || b == kNoIndex || a == b) {
            throw std::invalid_argument("link " + std::to_string(link.a) + "-" + std::to_string(link.b) +
                                        " names an unknown node");
        }
        const uint32_t index = network.addLink(a, b, params_.range.window);
        LinkState &state = network.links[index];
        for (double value : link.window_m) {
            state.window.push(value);
        }
        state.representative_m = state.window.median();
        state.range_count = link.range_count;
        state.last_range_m = link.last_range_m;
        state.inlier_probability = link.inlier_probability;
    }
    rings_.clear();
    free_rings_.clear();
    for (const RingSog &ring : restored.rings) {
        const uint32_t center = network.findNode(ring.center());
        const uint32_t target = network.findNode(ring.target());
        const uint32_t link = (center == kNoIndex || target == kNoIndex) ? kNoIndex : network.findLink(center, target);
        if (link == kNoIndex) {
            throw std::invalid_argument("a SoG names nodes without a link");
        }
        LinkState &state = network.links[link];
        uint32_t &slot = state.node_a == center ? state.ring_from_a : state.ring_from_b;
        slot = static_cast<uint32_t>(rings_.size());
        rings_.push_back(ring);
    }
    network_ = std::move(network);
    placement_pending_.assign(network_.nodes.size(), false);
    in_relax_queue_.assign(network_.nodes.size(), false);
    relax_queue_.clear();
    fixed_count_ = 0;
    for (uint32_t node = 0; node < network_.nodes.size(); ++node) {
        fixed_count_ += network_.nodes[node].fixed ? 1U : 0U;
        markPlacementPending(node);
    }
    frame_nodes_.reset();
    if (restored.frame_nodes) {
        std::array<uint32_t, 3> indices{};
        for (size_t i = 0; i < 3; ++i) {
            indices[i] = network_.findNode((*restored.frame_nodes)[i]);
            if (indices[i] == kNoIndex) {
                throw std::invalid_argument("the frame names an unknown node");
            }
        }
        frame_nodes_ = indices;
    }
    counters_ = restored.counters;
    reinit_link_count_ = restored.reinit_link_count;
    ranges_since_new_link_ = restored.ranges_since_new_link;
    fixed_applied_ = true;
    if (fixed_positions_.size() == 1) {
        single_fixed_ = fixed_positions_.front();
    }
    mds_link_count_ = 0;
    mds_node_count_ = 0;
    ++revision_;
}

} // namespace cdro::engine
