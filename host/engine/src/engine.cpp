#include "cdro/engine/engine.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>

namespace cdro::engine {

Engine::Engine(const EngineParams &params)
    : params_(params), likelihood_(params.likelihood), intake_(params.range), sogs_(params, likelihood_),
      placement_(params, likelihood_), refiner_(params, likelihood_), convergence_(params, likelihood_),
      global_(params, convergence_.structureCheck()), motion_(params, likelihood_),
      flights_(params.motion, params.range.sigma_m, params.sog.gate_sigma, likelihood_), frame_(params.frame)
{
}

uint32_t Engine::nodeIndex(NodeId id)
{
    const uint32_t index = intake_.node(map_, id);
    if (in_relax_queue_.size() < map_.nodes.size()) {
        in_relax_queue_.resize(map_.nodes.size(), 0);
        placement_.resize(map_.nodes.size());
    }
    return index;
}

void Engine::setHeight(NodeId id, double height_m)
{
    if (flights_.tracks(id) || flights_.anchorsSet()) {
        throw std::logic_error("node " + std::to_string(id) +
                               ": a height is known before the first range of a node "
                               "tracked in 3D, and never for such a node");
    }
    map_.nodes[nodeIndex(id)].height_m = height_m;
}

void Engine::setFixed(NodeId id, const Vector2 &position_m)
{
    if (flights_.tracks(id) || flights_.anchorsSet()) {
        throw std::logic_error("node " + std::to_string(id) +
                               ": fixed nodes are set before the first range of a node "
                               "tracked in 3D, and such a node is never fixed");
    }
    frame_.setFixed(id, position_m);
    nodeIndex(id);
}

void Engine::setMoving(NodeId id, bool moving)
{
    const uint32_t node = nodeIndex(id);
    if (motion_.report(map_, sogs_, node, moving, trace_)) {
        ++revision_;
        enqueueNeighbours(node); // they lose (or regain) an anchor
    }
    keepFrame();
}

void Engine::trackMoving3D(NodeId id)
{
    const std::string node = "node " + std::to_string(id);
    const uint32_t index = map_.findNode(id);
    for (const auto &[fixed_id, position] : frame_.fixedPositions()) {
        if (fixed_id == id) {
            throw std::logic_error(node + " is fixed: it cannot also be tracked as moving");
        }
    }
    if (index != kNoIndex && map_.nodes[index].height_m) {
        throw std::logic_error(node + " has a known height: a 3D track is for a node whose height is not known");
    }
    if (index != kNoIndex || flights_.anchorsSet()) {
        throw std::logic_error(node + ": a node is declared moving in 3D before the first range of any such node");
    }
    flights_.add(id);
}

std::vector<std::pair<NodeId, Vector3>> Engine::flightAnchors() const
{
    std::vector<std::pair<NodeId, Vector3>> anchors;
    for (const auto &[id, position] : frame_.fixedPositions()) {
        const uint32_t index = map_.findNode(id);
        if (index != kNoIndex && map_.nodes[index].height_m) {
            anchors.emplace_back(id, Vector3(position.x(), position.y(), *map_.nodes[index].height_m));
        }
    }
    return anchors;
}

FlightTracks::RestoreReport Engine::restoreFlights(const FlightTracks::Saved &saved)
{
    FlightTracks::RestoreReport report = flights_.restore(saved);
    if (saved.anchors_set) {
        // Within a millimetre: a checkpoint's map holds the heights rounded to 0.5 mm.
        const std::vector<std::pair<NodeId, Vector3>> given = flightAnchors();
        report.anchors_differ = given.size() != saved.anchors.size();
        for (size_t a = 0; a < given.size() && !report.anchors_differ; ++a) {
            report.anchors_differ = given[a].first != saved.anchors[a].first ||
                                    (given[a].second - saved.anchors[a].second).cwiseAbs().maxCoeff() > 1e-3;
        }
    }
    return report;
}

RangeVerdict Engine::addFlightRange(NodeId from, NodeId to, double range_m, double t_s)
{
    if (from == to) {
        return RangeVerdict::RejectedSelf;
    }
    if (!std::isfinite(range_m) || !(range_m > 0.0) || range_m > params_.range.max_range_m || !std::isfinite(t_s)) {
        return RangeVerdict::RejectedValue;
    }
    if (!flights_.anchorsSet()) {
        flights_.setAnchors(flightAnchors()); // none can be added from now on
    }
    ++revision_;
    const FlightRangeUse use = flights_.addRange(from, to, range_m, t_s);
    return use == FlightRangeUse::Used || use == FlightRangeUse::Reset ? RangeVerdict::Used : RangeVerdict::Stored;
}

void Engine::pinNode(NodeId id, const Vector2 &position_m, const Matrix2 &covariance_m2)
{
    const uint32_t node = nodeIndex(id);
    NodeState &state = map_.nodes[node];
    const Vector2 delta = position_m - state.position_m;
    const bool was_placed = state.placed();
    state.role = NodeRole::Pinned;
    if (!was_placed) {
        state.lifecycle = NodeLifecycle::Placed;
    }
    state.position_m = position_m;
    state.covariance_m2 = covariance_m2;
    if (was_placed) {
        sogs_.translate(map_, node, delta);
    } else {
        sogs_.ensureRings(map_, node);
    }
    ++revision_;
}

void Engine::unpinNode(NodeId id)
{
    const uint32_t node = map_.findNode(id);
    if (node != kNoIndex && map_.nodes[node].pinned()) {
        map_.nodes[node].role = NodeRole::Free;
        enqueue(node);
    }
}

RangeVerdict Engine::addRange(NodeId from, NodeId to, double range_m, double t_s)
{
    const RangeVerdict verdict = takeRange(from, to, range_m, t_s);
    keepFrame();
    return verdict;
}

void Engine::keepFrame()
{
    if (frame_.frameNodesLost(map_)) {
        frame_.ensureFrameNodes(map_, params_.placement);
    }
}

RangeVerdict Engine::takeRange(NodeId from, NodeId to, double range_m, double t_s)
{
    if (!flights_.empty() && (flights_.tracks(from) || flights_.tracks(to))) {
        return addFlightRange(from, to, range_m, t_s); // a node that never stops: its own 3D track
    }
    // 1. Intake.
    const TakenRange taken = intake_.take(map_, from, to, range_m, t_s);
    if (taken.verdict == RangeVerdict::RejectedSelf || taken.verdict == RangeVerdict::RejectedValue) {
        return taken.verdict;
    }
    nodeIndex(from); // sizes the per-node bookkeeping
    const uint32_t a = taken.a;
    const uint32_t b = taken.b;
    intake_.refreshLinkRange(map_, taken.link, params_.motion.reset);
    ++revision_; // the links are part of the outputs (last range, count)
    output_changes_.rangeTaken(a, b);
    // 2. Motion: the map is a reference only once it holds both ends.
    const NodeState &end_a = map_.nodes[a];
    const NodeState &end_b = map_.nodes[b];
    if (holds(a) && holds(b)) {
        const double residual = taken.planar_m - (end_a.position_m - end_b.position_m).norm();
        // Far from the map and from the link's own history: something moved.
        const double evidence = std::abs(taken.jump_m) < std::abs(residual) ? taken.jump_m : residual;
        for (uint32_t end : {a, b}) {
            if (motion_.watch(map_, sogs_, end, taken.link, evidence, t_s, trace_)) {
                ++revision_;
                enqueueNeighbours(end);
            }
        }
    }
    // 3. The global solve, when due.
    if (taken.new_link) {
        placement_.markPending(map_, a);
        placement_.markPending(map_, b);
    }
    global_.countRange();
    if (global_.adoptionDue()) {
        adoptGlobalSolve();
    }
    if (global_.dueAfterRange(map_, taken.new_link, intake_.counters().taken()) && !global_.pending()) {
        startGlobalSolve(false);
        if (global_.adoptionDue()) {
            adoptGlobalSolve(); // solved in this thread
        }
    }
    // 4. Placement.
    if (placement_.anyPending()) {
        runPlacement(Settling::OverRanges);
    }
    if (!map_.nodes[a].placed() || !map_.nodes[b].placed()) {
        placement_.countWaitingRange(map_, a);
        placement_.countWaitingRange(map_, b);
        if (placement_.anyPending()) {
            runPlacement(Settling::OverRanges);
        }
        ++ranges_stored_;
        relaxAfterRange();
        return RangeVerdict::Stored;
    }
    ++ranges_used_;
    // 5. The SoGs (and the tracks of moving ends).
    if (std::isfinite(t_s)) {
        motion_.track(map_, a, b, taken.planar_m, t_s);
        motion_.track(map_, b, a, taken.planar_m, t_s);
    }
    sogs_.update(map_, taken.link, a, taken.planar_m);
    sogs_.update(map_, taken.link, b, taken.planar_m);
    // 6. Both ends.
    updateNode(a, true);
    updateNode(b, true);
    // 7. Neighbours.
    relaxAfterRange();
    return RangeVerdict::Used;
}

void Engine::relaxAfterRange()
{
    const uint64_t owed = std::min<uint64_t>(settle_owed_, params_.refinement.settle_per_range);
    const uint64_t done = relax(params_.refinement.relax_per_range + owed, Settling::OverRanges);
    const uint64_t paid = done - std::min<uint64_t>(done, params_.refinement.relax_per_range);
    settle_owed_ = relax_queue_.empty() ? 0 : settle_owed_ - std::min(settle_owed_, paid);
}

void Engine::runPlacement(Settling settling)
{
    // A placed node's neighbourhood agrees with it before the next placement leans on it; on the
    // range path that settling is spread over the ranges that follow (no range pays for more
    // than `settle_per_range` of it), and the next placement waits until it is done.
    if (placing_ || (settling == Settling::OverRanges && settle_owed_ > 0)) {
        return; // re-entered from a relaxation (the outer loop sees the pending nodes), or owed
    }
    placing_ = true;
    relax(std::exchange(settle_owed_, 0), settling); // settle(): what the range path still owes
    if (!frame_.applied()) {
        frame_.apply(map_);
        ++revision_;
    }
    // One node a range on the range path: each placement leans on the one before it settled.
    const uint64_t most = settling == Settling::AtOnce ? UINT64_MAX : 1;
    const std::vector<uint32_t> placed = placement_.run(map_, frame_held_, frame_, trace_, most);
    adoptPlaced(placed);
    settle_owed_ = placed.size() * params_.refinement.settle_per_placed;
    if (settling == Settling::AtOnce) {
        relax(std::exchange(settle_owed_, 0), settling);
    }
    placing_ = false;
    if (settling == Settling::AtOnce && !placed.empty() && placement_.anyPending()) {
        runPlacement(settling); // nodes unplaced during that relaxation
    }
}

void Engine::adoptPlaced(const std::vector<uint32_t> &nodes)
{
    for (uint32_t node : nodes) {
        sogs_.ensureRings(map_, node);
        enqueue(node);
        enqueueNeighbours(node);
        ++revision_;
    }
}

void Engine::startGlobalSolve(bool settling)
{
    if (!frame_.applied()) {
        frame_.apply(map_);
    }
    global_.start(map_, intake_.counters().taken(), settling);
}

bool Engine::adoptFinishedSolve() { return global_.finished() && adoptPendingSolve(); }

bool Engine::adoptPendingSolve()
{
    if (!global_.pending()) {
        return false;
    }
    adoptGlobalSolve();
    keepFrame();
    return true;
}

void Engine::adoptGlobalSolve()
{
    const GlobalStep::Outcome outcome = global_.adopt(map_, frame_.fixedFrameNodes(), trace_);
    // The links' ranges follow the offsets the solve came with.
    for (uint32_t link = 0; link < map_.links.size(); ++link) {
        intake_.refreshLinkRange(map_, link, params_.motion.reset);
    }
    global_.markSolved(map_);
    for (const auto &[node, delta] : outcome.shifted) {
        sogs_.translate(map_, node, delta);
        if (delta.norm() > params_.refinement.relax_threshold_m) {
            // A map solved at once is a new start: eq. 16's average starts again from it.
            Convergence::restart(map_.nodes[node]);
            enqueueNeighbours(node);
        }
    }
    const double variance = params_.range.sigma_m * params_.range.sigma_m;
    for (size_t i = 0; i < outcome.placed.size(); ++i) {
        const uint32_t node = outcome.placed[i];
        placement_.place(map_, node, map_.nodes[node].position_m,
                         outcome.placed_covariance_m2[i] + variance * Matrix2::Identity());
    }
    adoptPlaced(outcome.placed);
    frame_.ensureFrameNodes(map_, params_.placement);
    ++revision_;
    if (outcome.structure.doubt.empty()) {
        assess();
    } else {
        convergence_.adoptStructure(map_, outcome.structure, outcome.structure_nodes);
    }
    // Every node updated once as a neighbour would update it: SoGs, covariances and eq. 16
    // catch up with the map solved at once.
    for (uint32_t node = 0; node < map_.nodes.size(); ++node) {
        enqueue(node);
    }
}

void Engine::updateNode(uint32_t node, bool after_range)
{
    NodeState &state = map_.nodes[node];
    if (!state.placed() || !state.free()) {
        return;
    }
    ++node_updates_;
    const bool tracked = (state.moving() || state.settling()) && params_.motion.reset;
    if (!after_range && !params_.refinement.enabled) {
        // Without refinement the merged SoG is the estimate: a neighbour update repeats the
        // paper's iteration (weights from the other nodes' ranges, transfer) before merging.
        for (uint32_t link : state.links) {
            const uint32_t other = map_.otherNode(link, node);
            if (map_.nodes[other].placed()) {
                sogs_.reweight(map_, link, other, map_.links[link].representative_m, false);
            }
        }
    }
    uint32_t ring_count = 0;
    const Gaussian2 merged = sogs_.merge(map_, node, &ring_count);
    Vector2 position = state.position_m;
    Matrix2 covariance = state.covariance_m2;
    if (tracked && motion_.afterUpdate(map_, sogs_, node, trace_)) {
        ++revision_;
        enqueueNeighbours(node);
    }
    if (motion_.trackIsEstimate(state)) {
        // A moving node's estimate is its track (the SoG resets keep the multimodal picture).
        position = state.track->position();
        covariance = state.track->positionCovariance();
    } else {
        const Refinement refined = refiner_.refine(map_, node, merged, ring_count, tracked);
        if (refined.inconsistent) {
            trace("node " + std::to_string(state.id) + " is inconsistent with its links: placed again");
            unplace(node);
            return;
        }
        position = refined.position_m;
        covariance = refined.covariance_m2;
    }
    covariance = symmetricPart(covariance);
    const Vector2 delta = position - state.position_m;
    const bool changed = delta.squaredNorm() > 0.0 || covariance != state.covariance_m2;
    state.position_m = position;
    state.covariance_m2 = covariance;
    sogs_.follow(map_, node, delta); // rings are relative to their centre: they move with it
    if (state.moving() || state.settling()) {
        Convergence::restart(state); // no convergence while it moves
        revision_ += changed ? 1U : 0U;
        output_changes_.nodeUpdated(node, changed);
        return; // the neighbours do not lean on a moving node
    }
    const NodeLifecycle before = state.lifecycle;
    const NodeDoubt doubt_before = state.doubt;
    convergence_.afterUpdate(map_, node);
    const bool bumped = changed || before != state.lifecycle || doubt_before != state.doubt;
    revision_ += bumped ? 1U : 0U;
    output_changes_.nodeUpdated(node, bumped);
    if (delta.norm() > params_.refinement.relax_threshold_m) {
        enqueueNeighbours(node);
    }
}

void Engine::unplace(uint32_t node)
{
    sogs_.dropRings(map_, node, false);
    placement_.unplace(map_, node);
    ++revision_;
    enqueueNeighbours(node);
    // A neighbour left without a placed neighbour has nothing that holds it: it waits too.
    for (uint32_t link : map_.nodes[node].links) {
        const uint32_t other = map_.otherNode(link, node);
        const NodeState &state = map_.nodes[other];
        if (!state.placed() || !state.free()) {
            continue;
        }
        bool held = false;
        for (uint32_t other_link : state.links) {
            held = held || map_.nodes[map_.otherNode(other_link, other)].placed();
        }
        if (!held) {
            unplace(other);
        }
    }
}

void Engine::enqueue(uint32_t node)
{
    const NodeState &state = map_.nodes[node];
    if (in_relax_queue_[node] == 0 && state.placed() && state.free()) {
        in_relax_queue_[node] = 1;
        relax_queue_.push_back(node);
    }
}

void Engine::enqueueNeighbours(uint32_t node)
{
    for (uint32_t link : map_.nodes[node].links) {
        enqueue(map_.otherNode(link, node));
    }
}

uint64_t Engine::relax(uint64_t budget, Settling settling)
{
    uint64_t done = 0;
    for (; done < budget && !relax_queue_.empty(); ++done) {
        const uint32_t node = relax_queue_.front();
        relax_queue_.pop_front();
        in_relax_queue_[node] = 0;
        ++relaxations_;
        updateNode(node);
        if (settling == Settling::AtOnce && placement_.anyPending()) {
            runPlacement(settling); // a node found inconsistent was unplaced: place it again
        }
    }
    return done; // on the range path a node unplaced here is placed again at the next range
}

void Engine::assess()
{
    // The key: the links, and which nodes are placed, still and fixed (splitmix64 of each index
    // with its state, summed), and the solve count: cheap next to the checks it saves.
    uint64_t key = 0x9E3779B97F4A7C15ULL * (map_.links.size() + 1) + global_.counters().solves;
    for (uint32_t node = 0; node < map_.nodes.size(); ++node) {
        const NodeState &state = map_.nodes[node];
        const uint64_t flags = (state.placed() ? 1U : 0U) | (state.anchor() ? 2U : 0U) | (state.fixed() ? 4U : 0U);
        uint64_t mixed = (static_cast<uint64_t>(node) << 3U | flags) + 0x9E3779B97F4A7C15ULL;
        mixed = (mixed ^ (mixed >> 30U)) * 0xBF58476D1CE4E5B9ULL;
        mixed = (mixed ^ (mixed >> 27U)) * 0x94D049BB133111EBULL;
        key += mixed ^ (mixed >> 31U);
    }
    if (key == assessed_key_) {
        return;
    }
    assessed_key_ = key;
    convergence_.assess(map_);
    ++revision_;
}

uint64_t Engine::settle(uint64_t max_updates)
{
    const uint64_t before = relaxations_;
    if (global_.pending()) {
        adoptGlobalSolve();
    }
    if (global_.dueAtSettle(map_, intake_.counters().taken())) {
        startGlobalSolve(true);
        adoptGlobalSolve();
    }
    relax(std::exchange(settle_owed_, 0), Settling::AtOnce);
    if (placement_.anyPending()) {
        runPlacement(Settling::AtOnce);
    }
    relax(max_updates, Settling::AtOnce);
    assessed_key_ = 0;
    assess();
    // A quiet map is the evidence eq. 16's average waits for: nodes still catching up with a
    // recent jump start their average again where they are, and a few more updates tell whether
    // they stay there.
    // The rounds run while any node is not converged, whatever the checks doubt of it: the map
    // must not depend on the statuses, which judge it (a node doubted by a wider covariance would
    // otherwise leave the map less settled).
    bool lagging = false;
    for (NodeState &state : map_.nodes) {
        if (state.placed() && state.free() && state.anchor() && !state.converged()) {
            if (state.doubt == NodeDoubt::Unsettled || state.doubt == NodeDoubt::None) {
                Convergence::restart(state);
            }
            lagging = true;
        }
    }
    if (lagging && relax_queue_.empty()) {
        const uint32_t rounds = std::max(params_.convergence.consecutive, params_.convergence.min_updates);
        for (uint32_t round = 0; round < rounds; ++round) {
            for (uint32_t node = 0; node < map_.nodes.size(); ++node) {
                updateNode(node);
                ++relaxations_;
            }
        }
    }
    keepFrame();
    return relaxations_ - before;
}

EngineCounters Engine::counters() const
{
    EngineCounters out;
    out.intake = intake_.counters();
    out.sogs = sogs_.counters();
    out.placement = placement_.counters();
    out.refinement = refiner_.counters();
    out.solve = global_.counters();
    out.convergence = convergence_.counters();
    out.motion = motion_.counters();
    out.ranges_used = ranges_used_;
    out.ranges_stored = ranges_stored_;
    out.node_updates = node_updates_;
    out.relaxations = relaxations_;
    return out;
}

// ---- outputs --------------------------------------------------------------------------------

std::vector<NodeOutput> Engine::estimates() const
{
    const RigidTransform transform = outputTransform();
    std::vector<NodeOutput> out;
    out.reserve(map_.nodes.size());
    for (const uint32_t index : map_.nodesById()) {
        out.push_back(outputOf(index, transform));
    }
    return out;
}

std::vector<NodeOutput> Engine::estimatesAt(const std::vector<uint32_t> &positions) const
{
    const RigidTransform transform = outputTransform();
    std::vector<NodeOutput> out;
    out.reserve(positions.size());
    for (const uint32_t position : positions) {
        out.push_back(outputOf(map_.nodesById().at(position), transform));
    }
    return out;
}

std::optional<NodeOutput> Engine::estimate(NodeId id) const
{
    const uint32_t index = map_.findNode(id);
    if (index == kNoIndex) {
        return std::nullopt;
    }
    return outputOf(index, outputTransform());
}

NodeOutput Engine::outputOf(uint32_t index, const RigidTransform &transform) const
{
    const NodeState &state = map_.nodes[index];
    NodeOutput node;
    node.id = state.id;
    node.role = state.role;
    node.lifecycle = state.lifecycle;
    node.doubt = state.placed() ? state.doubt : NodeDoubt::None;
    if (node.doubt == NodeDoubt::Foldable) {
        for (uint32_t hinge : state.hinge) {
            if (hinge != kNoIndex) {
                node.hinge[node.hinge_nodes++] = map_.nodes[hinge].id;
            }
        }
        if (node.hinge_nodes == 2 && node.hinge[1] < node.hinge[0]) {
            std::swap(node.hinge[0], node.hinge[1]); // by id, as the output lists nodes
        }
    }
    node.height_known = state.height_m.has_value();
    node.height_m = state.height_m.value_or(0.0);
    node.link_count = static_cast<uint32_t>(state.links.size());
    if (state.placed()) {
        // A moving node is where its track says it is now, not at its last range.
        const bool predicted =
            state.moving() && state.track && std::isfinite(map_.last_time_s) && motion_.trackIsEstimate(state);
        node.position_m = transform.apply(predicted ? state.track->positionAt(map_.last_time_s) : state.position_m);
        const auto &single = frame_.singleFixed();
        if (single && single->first == state.id) {
            node.position_m = single->second;
            node.role = NodeRole::Fixed;
        }
        // The map's covariance (correlations across it included) where the solve has one,
        // else the local one of the refinement.
        const bool from_solve = state.solve.solved && state.free() && state.anchor() && params_.refinement.enabled;
        node.covariance_m2 = transform.applyToCovariance(from_solve ? state.solve.covariance_m2 : state.covariance_m2);
    }
    return node;
}

std::vector<LinkOutput> Engine::links() const
{
    std::vector<LinkOutput> out;
    out.reserve(map_.links.size());
    for (const uint32_t index : map_.linksById()) {
        const LinkState &state = map_.links[index];
        LinkOutput link;
        link.a = map_.nodes[state.node_a].id;
        link.b = map_.nodes[state.node_b].id;
        link.last_range_m = state.last_range_m;
        link.range_m = state.representative_m;
        link.range_count = state.range_count;
        link.inlier_probability = state.inlier_probability;
        out.push_back(link);
    }
    return out;
}

std::vector<RingOutput> Engine::ringsDescribing(NodeId id) const
{
    std::vector<RingOutput> out;
    const uint32_t node = map_.findNode(id);
    if (node == kNoIndex) {
        return out;
    }
    const RigidTransform transform = outputTransform();
    for (uint32_t link : map_.nodes[node].links) {
        const uint32_t slot = map_.ringSlot(link, map_.otherNode(link, node));
        if (slot == kNoIndex || map_.rings[slot].empty()) {
            continue;
        }
        RingOutput ring;
        ring.center = map_.rings[slot].center();
        ring.target = map_.rings[slot].target();
        ring.components = map_.rings[slot].components();
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
    if (!map_.frame_nodes) {
        return std::nullopt;
    }
    return std::array<NodeId, 3>{map_.nodes[(*map_.frame_nodes)[0]].id, map_.nodes[(*map_.frame_nodes)[1]].id,
                                 map_.nodes[(*map_.frame_nodes)[2]].id};
}

void Engine::restore(const RestoredState &restored)
{
    MapState map;
    for (const NodeState &node : restored.nodes) {
        const uint32_t index = map.addNode(node.id);
        if (index != map.nodes.size() - 1) {
            throw std::invalid_argument("node " + std::to_string(node.id) + " appears twice");
        }
        map.nodes[index] = node;
        map.nodes[index].links.clear();
    }
    for (const RestoredLink &link : restored.links) {
        const uint32_t a = map.findNode(link.a);
        const uint32_t b = map.findNode(link.b);
        if (a == kNoIndex || b == kNoIndex || a == b) {
            throw std::invalid_argument("link " + std::to_string(link.a) + "-" + std::to_string(link.b) +
                                        " names an unknown node");
        }
        const uint32_t index = map.addLink(a, b, params_.range.window);
        LinkState &state = map.links[index];
        for (double value : link.window_m) {
            state.window.push(value);
        }
        intake_.refreshLinkRange(map, index, params_.motion.reset);
        state.range_count = link.range_count;
        state.last_range_m = link.last_range_m;
        state.inlier_probability = link.inlier_probability;
        state.solved_range_m = link.solved_range_m;
    }
    for (const RingSog &ring : restored.rings) {
        const uint32_t center = map.findNode(ring.center());
        const uint32_t target = map.findNode(ring.target());
        const uint32_t link = (center == kNoIndex || target == kNoIndex) ? kNoIndex : map.findLink(center, target);
        if (link == kNoIndex) {
            throw std::invalid_argument("a SoG names nodes without a link");
        }
        map.ringSlot(link, center) = static_cast<uint32_t>(map.rings.size());
        map.rings.push_back(ring);
    }
    if (restored.frame_nodes) {
        std::array<uint32_t, 3> indices{};
        for (size_t i = 0; i < 3; ++i) {
            indices[i] = map.findNode((*restored.frame_nodes)[i]);
            if (indices[i] == kNoIndex) {
                throw std::invalid_argument("the frame names an unknown node");
            }
        }
        map.frame_nodes = indices;
    }
    map.frame_offset = restored.frame_offset;
    map_ = std::move(map);
    in_relax_queue_.assign(map_.nodes.size(), 0);
    relax_queue_.clear();
    settle_owed_ = 0;
    placement_.resize(map_.nodes.size());
    for (uint32_t node = 0; node < map_.nodes.size(); ++node) {
        placement_.markPending(map_, node);
    }
    const EngineCounters &c = restored.counters;
    intake_.restoreCounters(c.intake);
    sogs_.restoreCounters(c.sogs);
    placement_.restoreCounters(c.placement);
    refiner_.restoreCounters(c.refinement);
    global_.restoreCounters(c.solve);
    convergence_.restoreCounters(c.convergence);
    motion_.restoreCounters(c.motion);
    ranges_used_ = c.ranges_used;
    ranges_stored_ = c.ranges_stored;
    node_updates_ = c.node_updates;
    relaxations_ = c.relaxations;
    global_.restoreSchedule(restored.solve_schedule);
    frame_.restored(map_);
    if (!restored.structural_doubts.empty() && restored.structural_doubts.size() != map_.nodes.size()) {
        throw std::invalid_argument("the convergence checks name " + std::to_string(restored.structural_doubts.size()) +
                                    " nodes, the map " + std::to_string(map_.nodes.size()));
    }
    convergence_.restoreStructuralDoubts(restored.structural_doubts);
    assessed_key_ = restored.assessed_key;
    ++revision_;
}

} // namespace cdro::engine
