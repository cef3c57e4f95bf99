#include "cdro/hostd/engine_adapter.hpp"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "cdro/fixed.h"
#include "cdro/hostd/checkpoint_blocks.hpp"
#include "cdro/service/log.hpp"

namespace cdro::hostd {

using service::CheckpointError;

namespace {

// The table's ranges of the enums (checkpoint_layout.def) are the engine's: a new value is a new
// block version.
static_assert(static_cast<unsigned>(engine::NodeRole::Pinned) == CDRO_CHECKPOINT_LAST_ROLE);
static_assert(static_cast<unsigned>(engine::NodeLifecycle::Settling) == CDRO_CHECKPOINT_LAST_LIFECYCLE);
static_assert(static_cast<unsigned>(engine::NodeDoubt::Unsettled) == CDRO_CHECKPOINT_LAST_DOUBT);
static_assert(static_cast<unsigned>(engine::FlightStatus::Tracking) == CDRO_CHECKPOINT_LAST_FLIGHT_STATUS);

uint32_t mmOfRange(double metres)
{
    const double mm = std::round(std::max(metres, 0.0) * 1000.0);
    return mm >= 4294967295.0 ? 0xFFFFFFFFU : static_cast<uint32_t>(mm);
}

uint16_t saturate16(uint64_t value) { return value > 0xFFFFU ? 0xFFFFU : static_cast<uint16_t>(value); }

// The counters, in one fixed order (append only).
std::vector<uint64_t *> counterFields(engine::EngineCounters &c)
{
    return {&c.intake.ranges_received,
            &c.ranges_used,
            &c.ranges_stored,
            &c.intake.rejected_self,
            &c.intake.rejected_value,
            &c.intake.projection_clamped,
            &c.sogs.ekf_component_updates,
            &c.sogs.ekf_gated,
            &c.sogs.weight_terms,
            &c.sogs.weight_terms_downweighted,
            &c.sogs.weight_collapses,
            &c.sogs.weight_transfers,
            &c.sogs.motion_resets,
            &c.placement.placements,
            &c.placement.placement_ambiguous,
            &c.placement.placements_forced,
            &c.placement.replacements,
            &c.refinement.refinements,
            &c.refinement.links_downweighted,
            &c.refinement.hypothesis_switches,
            &c.node_updates,
            &c.relaxations,
            &c.solve.solves,
            &c.solve.solves_adopted,
            &c.solve.solve_starts,
            &c.solve.solve_escapes,
            &c.solve.solve_placed,
            &c.convergence.assessments,
            &c.convergence.ambiguous_nodes,
            &c.convergence.foldable_nodes,
            &c.convergence.flexible_nodes,
            &c.motion.motion_starts,
            &c.motion.motion_stops,
            &c.motion.motion_inferred,
            &c.motion.track_updates,
            &c.motion.track_refused,
            &c.solve.solve_refreshes,
            &c.solve.offsets_adopted,
            &c.sogs.weight_updates_deferred};
}

engine::Matrix2 covarianceOf(const cdro_fixed_covariance_t &fixed)
{
    double xx = 0.0;
    double xy = 0.0;
    double yy = 0.0;
    cdro_fixed_covariance_to(fixed, &xx, &xy, &yy);
    engine::Matrix2 covariance;
    covariance << xx, xy, xy, yy;
    return covariance;
}

} // namespace

EngineAdapter::EngineAdapter(engine::Engine &engine, engine::MovementStage *movement, std::vector<uint16_t> moving)
    : engine_(engine), movement_(movement), moving_(std::move(moving))
{
}

namespace {
// Event time in seconds (the frames' host receive time, replayed as recorded).
double seconds(int64_t unix_us) { return static_cast<double>(unix_us) * 1e-6; }
} // namespace

void EngineAdapter::onRange(const cdro_range_t &range, const service::FrameContext &context)
{
    last_event_unix_us_ = context.host_unix_us;
    const double range_m = static_cast<double>(range.distance_mm) / 1000.0;
    const double t_s = seconds(context.host_unix_us);
    const engine::RangeVerdict verdict = movement_ != nullptr
                                             ? movement_->addRange(range.from_id, range.to_id, range_m, t_s)
                                             : engine_.addRange(range.from_id, range.to_id, range_m, t_s);
    if (verdict == engine::RangeVerdict::RejectedSelf || verdict == engine::RangeVerdict::RejectedValue) {
        ++ranges_refused_;
    }
}

void EngineAdapter::onMotion(const cdro_motion_t &motion, const service::FrameContext &context)
{
    last_event_unix_us_ = context.host_unix_us;
    if (movement_ != nullptr) {
        movement_->setMoving(motion.node_id, motion.moving != 0, seconds(context.host_unix_us));
    } else {
        engine_.setMoving(motion.node_id, motion.moving != 0);
    }
}

namespace {

// Host event: a global solve adopted; then u64, the engine's ranges taken when it started (which
// solve it was: a replay that has another one pending has parted from the live run).
constexpr uint8_t kSolveAdopted = 'S';
constexpr size_t kSolveAdoptedBytes = 9;

} // namespace

std::vector<uint8_t> EngineAdapter::hostEventAfterFrame(const service::FrameContext &)
{
    const uint64_t ranges = engine_.solveSchedule().ranges_at_last; // the pending solve's start
    if (!engine_.adoptFinishedSolve()) {
        return {};
    }
    std::vector<uint8_t> event(kSolveAdoptedBytes, 0);
    event[0] = kSolveAdopted;
    for (size_t i = 0; i < 8; ++i) {
        event[1 + i] = static_cast<uint8_t>(ranges >> (8U * i));
    }
    return event;
}

void EngineAdapter::onHostEvent(const uint8_t *data, size_t len, const service::FrameContext &context)
{
    last_event_unix_us_ = context.host_unix_us;
    if (len != kSolveAdoptedBytes || data[0] != kSolveAdopted) {
        ++host_events_mismatched_;
        service::log()->warn("replay: a host event this cdro-hostd does not know ({} bytes, first 0x{:02x}) skipped",
                             len, len > 0 ? data[0] : 0);
        return;
    }
    uint64_t live_ranges = 0;
    for (size_t i = 0; i < 8; ++i) {
        live_ranges |= static_cast<uint64_t>(data[1 + i]) << (8U * i);
    }
    const uint64_t ranges = engine_.solveSchedule().ranges_at_last; // the pending solve's start
    if (!engine_.adoptPendingSolve()) {
        ++host_events_mismatched_;
        service::log()->warn("replay: the live run adopted here the global solve it started after {} ranges, but "
                             "none is pending (another engine or other settings than the live run's, or a lost "
                             "record); the map will differ from the live one",
                             live_ranges);
        return;
    }
    if (ranges != live_ranges) {
        ++host_events_mismatched_;
        service::log()->warn("replay: the live run adopted here the global solve it started after {} ranges; this "
                             "replay's started after {} (another engine or settings, or a lost record); the map will "
                             "differ from the live one",
                             live_ranges, ranges);
    }
}

void EngineAdapter::onOdometry(const service::OdometryMessage &message)
{
    if (movement_ != nullptr) {
        movement_->addOdometry(message.t_s, engine::OdometryStep{message.distance_m, message.dheading_rad});
    }
}

namespace {

service::NodeEstimate estimateOf(const engine::NodeOutput &node)
{
    service::NodeEstimate out;
    out.id = node.id;
    out.placed = node.placed();
    out.converged = node.converged();
    out.moving = node.moving();
    out.foldable = node.doubt == engine::NodeDoubt::Foldable;
    out.status = engine::nodeLifecycleName(node.lifecycle);
    out.reason = engine::nodeDoubtName(node.doubt);
    for (uint8_t k = 0; k < node.hinge_nodes; ++k) {
        out.hinge.push_back(node.hinge[k]);
    }
    if (node.height_known) {
        out.z_m = node.height_m;
    }
    if (node.placed()) {
        out.x_m = node.position_m.x();
        out.y_m = node.position_m.y();
        out.var_x_m2 = node.covariance_m2(0, 0);
        out.cov_xy_m2 = node.covariance_m2(0, 1);
        out.var_y_m2 = node.covariance_m2(1, 1);
    }
    return out;
}

// Every field estimateOf reads, bit for bit (a NaN compares unequal: converted again, harmless).
bool sameOutput(const engine::NodeOutput &a, const engine::NodeOutput &b)
{
    return a.id == b.id && a.role == b.role && a.lifecycle == b.lifecycle && a.doubt == b.doubt &&
           a.hinge_nodes == b.hinge_nodes && a.hinge == b.hinge && a.height_known == b.height_known &&
           a.height_m == b.height_m && a.link_count == b.link_count && a.position_m == b.position_m &&
           a.covariance_m2 == b.covariance_m2;
}

} // namespace

std::vector<engine::NodeOutput> EngineAdapter::shownNodes(std::vector<uint32_t> *shown_index) const
{
    std::vector<engine::NodeOutput> all = movement_ != nullptr ? movement_->estimates() : engine_.estimates();
    std::vector<engine::NodeOutput> shown;
    shown.reserve(all.size());
    if (shown_index != nullptr) {
        shown_index->assign(all.size(), kNotShown);
    }
    for (size_t position = 0; position < all.size(); ++position) {
        // A node known only by name (a height, or a range refused) is not on the map until it has a link.
        if (all[position].link_count == 0 && !all[position].fixed()) {
            continue;
        }
        if (shown_index != nullptr) {
            (*shown_index)[position] = static_cast<uint32_t>(shown.size());
        }
        shown.push_back(all[position]);
    }
    return shown;
}

void EngineAdapter::fillNodes(std::vector<service::NodeEstimate> &nodes,
                              const std::vector<engine::NodeOutput> &shown) const
{
    nodes.clear();
    nodes.reserve(shown.size() + moving_.size());
    for (const engine::NodeOutput &node : shown) {
        nodes.push_back(estimateOf(node));
    }
    // The nodes tracked in 3D are not in the static map: their tracks, once started (before
    // FlightTracks::kMinAnchors anchors are heard, not placed).
    for (const uint16_t id : moving_) {
        const std::optional<engine::FlightEstimate> track = engine_.flightEstimate(id);
        if (!track || track->status == engine::FlightStatus::Waiting) {
            continue;
        }
        service::NodeEstimate out;
        out.id = id;
        out.moving = true;
        out.status = "moving";
        if (track->status == engine::FlightStatus::Tracking) {
            const engine::Vector3 &p = track->position_m;
            const engine::Matrix3 &c = track->covariance_m2;
            out.placed = true;
            out.x_m = p.x();
            out.y_m = p.y();
            out.z_m = p.z();
            out.var_x_m2 = c(0, 0);
            out.cov_xy_m2 = c(0, 1);
            out.var_y_m2 = c(1, 1);
            out.var_z_m2 = c(2, 2);
            out.cov_xz_m2 = c(0, 2);
            out.cov_yz_m2 = c(1, 2);
        } else {
            out.status = "unplaced";
        }
        nodes.push_back(out);
    }
    if (!moving_.empty()) {
        std::sort(nodes.begin(), nodes.end(),
                  [](const service::NodeEstimate &a, const service::NodeEstimate &b) { return a.id < b.id; });
    }
}

void EngineAdapter::fillRobot(std::optional<service::RobotPose> &robot_pose) const
{
    robot_pose.reset();
    if (movement_ == nullptr) {
        return;
    }
    const std::optional<engine::RobotOutput> robot = movement_->robot();
    if (!robot || !robot->localized) {
        return;
    }
    service::RobotPose pose;
    pose.id = robot->id;
    pose.x_m = robot->pose.x_m;
    pose.y_m = robot->pose.y_m;
    pose.heading_rad = robot->pose.heading_rad;
    pose.var_x_m2 = robot->covariance(0, 0);
    pose.cov_xy_m2 = robot->covariance(0, 1);
    pose.var_y_m2 = robot->covariance(1, 1);
    pose.frame = engine::robotFrameName(robot->frame);
    pose.var_heading_rad2 = robot->covariance(2, 2);
    pose.cov_x_heading_m_rad = robot->covariance(0, 2);
    pose.cov_y_heading_m_rad = robot->covariance(1, 2);
    pose.heading_hypotheses = robot->hypotheses;
    pose.range_scale = robot->range_scale;
    pose.range_scale_sigma = robot->range_scale_sigma;
    pose.range_offset_m = robot->range_offset_m;
    pose.range_offset_sigma_m = robot->range_offset_sigma_m;
    robot_pose = pose;
}

void EngineAdapter::fill(service::MapState &map) const
{
    fillNodes(map.nodes, shownNodes(nullptr));
    map.links.clear();
    for (const engine::LinkOutput &link : engine_.links()) {
        service::LinkEstimate out;
        out.a = link.a;
        out.b = link.b;
        out.last_range_m = link.last_range_m;
        out.range_count = link.range_count;
        out.range_median_m = link.range_m;
        out.inlier_probability = link.inlier_probability;
        map.links.push_back(out);
    }
    fillRobot(map.robot);
}

void EngineAdapter::updateEstimates(service::MapState &map, std::vector<size_t> &changed)
{
    fillRobot(map.robot);
    changed.clear();
    // The static map alone (no robot's stage, no 3D tracks): the engine names the nodes whose
    // outputs may have changed (output_changes.hpp), and only those are converted.
    const bool named = movement_ == nullptr && moving_.empty();
    if (named) {
        const engine::OutputChanges changes = engine_.takeOutputChanges();
        if (!changes.all && updateNamed(map, changes.positions, changed)) {
            ++updates_of_named_nodes_;
            return;
        }
    }
    // Every node converted and compared with what `map` held (after the rarer events, and always
    // with a robot's stage or 3D tracks: small maps).
    std::vector<engine::NodeOutput> shown = shownNodes(named ? &shown_index_ : nullptr);
    std::vector<service::NodeEstimate> nodes;
    fillNodes(nodes, shown);
    changed = service::changedNodes(map.nodes, nodes);
    map.nodes = std::move(nodes);
    last_shown_ = std::move(shown);
}

bool EngineAdapter::updateNamed(service::MapState &map, const std::vector<uint32_t> &positions,
                                std::vector<size_t> &changed)
{
    if (map.nodes.size() != last_shown_.size()) {
        return false;
    }
    for (const uint32_t position : positions) {
        if (position >= shown_index_.size() || shown_index_[position] == kNotShown) {
            return false; // a node shown for the first time: the whole comparison
        }
    }
    const std::vector<engine::NodeOutput> outputs = engine_.estimatesAt(positions);
    for (size_t k = 0; k < positions.size(); ++k) {
        const uint32_t i = shown_index_[positions[k]];
        if (!sameOutput(outputs[k], last_shown_[i])) {
            map.nodes[i] = estimateOf(outputs[k]);
            last_shown_[i] = outputs[k];
            changed.push_back(i);
        }
    }
    return true;
}

std::optional<service::NodeComponents> EngineAdapter::components(uint16_t id) const
{
    if (!engine_.estimate(id)) {
        return std::nullopt;
    }
    service::NodeComponents out;
    out.id = id;
    for (const engine::RingOutput &ring : engine_.ringsDescribing(id)) {
        for (const engine::SogComponentState &component : ring.components) {
            service::SogComponent c;
            c.center_id = ring.center;
            c.x_m = component.mean_m.x();
            c.y_m = component.mean_m.y();
            c.var_x_m2 = component.covariance_m2(0, 0);
            c.cov_xy_m2 = component.covariance_m2(0, 1);
            c.var_y_m2 = component.covariance_m2(1, 1);
            c.weight = component.weight;
            out.components.push_back(c);
        }
    }
    return out;
}

service::SogSnapshot EngineAdapter::snapshot()
{
    service::SogSnapshot snapshot = snapshotOf(engine_, last_event_unix_us_);
    if (movement_ != nullptr) {
        snapshot.extensions.push_back({kMovementExtensionTag, movementBlockOf(*movement_)});
    }
    if (!moving_.empty()) {
        snapshot.extensions.push_back({kFlightExtensionTag, flightBlockOf(engine_)});
    }
    return snapshot;
}

void EngineAdapter::restore(const service::SogSnapshot &snapshot)
{
    restoreFrom(engine_, snapshot);
    for (const std::string &warning : restoreFlight(engine_, moving_, snapshot)) {
        service::log()->warn("resume: {}", warning);
    }
    if (movement_ != nullptr) {
        restoreMovement(*movement_, snapshot);
    }
}

std::vector<uint16_t> EngineAdapter::restoredNodes() const
{
    std::vector<uint16_t> out;
    for (const uint16_t id : moving_) {
        const std::optional<engine::FlightEstimate> track = engine_.flightEstimate(id);
        if (track && track->status != engine::FlightStatus::Waiting) {
            out.push_back(id);
        }
    }
    return out;
}

namespace {

std::vector<double> doublesOf(const Eigen::VectorXd &values) { return {values.data(), values.data() + values.size()}; }

Eigen::VectorXd vectorFrom(const std::vector<double> &values)
{
    return Eigen::Map<const Eigen::VectorXd>(values.data(), static_cast<Eigen::Index>(values.size()));
}

// The movement counters, in one fixed order (append only).
std::vector<uint64_t *> movementCounterFields(engine::MovementCounters &c)
{
    return {&c.odometry_steps, &c.robot_ranges,      &c.ekf_updates,
            &c.ekf_gated,      &c.nodes_inserted,    &c.nodes_removed,
            &c.beacon_sogs,    &c.hypotheses_pruned, &c.nlos_link_ranges_skipped};
}

uint8_t bitIf(bool condition, unsigned bit) { return condition ? static_cast<uint8_t>(bit) : uint8_t{0}; }

// The 3D tracks' counters, in one fixed order (append only).
std::vector<uint64_t *> flightCounterFields(engine::FlightCounters &c)
{
    return {&c.anchor_ranges, &c.tag_ranges, &c.down_weighted, &c.refused,   &c.resets,
            &c.waiting,       &c.no_anchor,  &c.mirrored,      &c.truncated, &c.body_updates};
}

std::string idList(const std::vector<engine::NodeId> &ids)
{
    std::string out;
    for (const engine::NodeId id : ids) {
        out += (out.empty() ? "" : ", ") + std::to_string(id);
    }
    return out;
}

} // namespace

std::vector<uint8_t> flightBlockOf(const engine::Engine &engine)
{
    engine::FlightTracks::Saved saved = engine.flightSaved();
    blocks::flight_block block;
    block.version = CDRO_CHECKPOINT_FLIGHT_VERSION;
    block.flags = static_cast<uint8_t>(bitIf(saved.anchors_set, CDRO_CHECKPOINT_FLIGHT_ANCHORS_SET) |
                                       bitIf(saved.t_s.has_value(), CDRO_CHECKPOINT_FLIGHT_HAVE_TIME));
    block.t_s = saved.t_s.value_or(0.0);
    for (const engine::FlightTracks::SavedNode &node : saved.nodes) {
        blocks::flight_node &out = block.nodes.emplace_back();
        out.id = node.id;
        out.status = static_cast<uint8_t>(node.status);
        out.refused_in_a_row = node.refused_in_a_row;
        out.heard.assign(node.heard.begin(), node.heard.end());
    }
    for (const engine::FlightTracks::SavedBody &body : saved.bodies) {
        block.bodies.push_back({body.a, body.b, body.separation_m});
    }
    for (size_t a = 0; a < saved.anchors.size(); ++a) {
        const auto &[id, position] = saved.anchors[a];
        const engine::FlightNlosCount &nlos = saved.nlos[a];
        block.anchors.push_back(
            {id, position.x(), position.y(), position.z(), nlos.taken, nlos.down_weighted, nlos.refused});
    }
    if (saved.anchors_set) {
        const engine::FlightNlosCount &tags = saved.nlos.back(); // the ranges between tracked nodes
        block.tag_taken = tags.taken;
        block.tag_down_weighted = tags.down_weighted;
        block.tag_refused = tags.refused;
    }
    block.state = doublesOf(saved.state);
    for (Eigen::Index i = 0; i < saved.covariance.rows(); ++i) {
        for (Eigen::Index j = 0; j < saved.covariance.cols(); ++j) {
            block.covariance.push_back(saved.covariance(i, j));
        }
    }
    for (const uint64_t *field : flightCounterFields(saved.counters)) {
        block.counters.push_back(*field);
    }
    return blocks::encode(block);
}

std::vector<std::string> restoreFlight(engine::Engine &engine, const std::vector<uint16_t> &moving,
                                       const service::SogSnapshot &snapshot)
{
    std::vector<std::string> warnings;
    const service::SogSnapshot::Extension *extension = snapshot.findExtension(kFlightExtensionTag);
    if (extension == nullptr) {
        if (!moving.empty()) {
            warnings.push_back("the checkpoint holds no 3D tracks (written without map.moving, or by an older "
                               "cdro-hostd): the tracks of nodes " +
                               idList(moving) + " (map.moving) restart from their next ranges");
        }
        return warnings;
    }
    const auto block = blocks::decode<blocks::flight_block>(extension->bytes, "flight", CDRO_CHECKPOINT_FLIGHT_VERSION);
    engine::FlightTracks::Saved saved;
    saved.anchors_set = (block.flags & CDRO_CHECKPOINT_FLIGHT_ANCHORS_SET) != 0;
    if ((block.flags & CDRO_CHECKPOINT_FLIGHT_HAVE_TIME) != 0) {
        saved.t_s = block.t_s;
    }
    for (const blocks::flight_node &in : block.nodes) {
        engine::FlightTracks::SavedNode node;
        node.id = in.id;
        node.status = static_cast<engine::FlightStatus>(in.status); // in range: the table's R
        node.refused_in_a_row = in.refused_in_a_row;
        node.heard.assign(in.heard.begin(), in.heard.end());
        saved.nodes.push_back(std::move(node));
    }
    for (const blocks::flight_body &in : block.bodies) {
        saved.bodies.push_back({in.a_id, in.b_id, in.separation_m});
    }
    for (const blocks::flight_anchor &in : block.anchors) {
        saved.anchors.emplace_back(in.id, engine::Vector3(in.x_m, in.y_m, in.z_m));
        saved.nlos.push_back({in.id, in.taken, in.down_weighted, in.refused});
    }
    if (saved.anchors_set) {
        saved.nlos.push_back({0, block.tag_taken, block.tag_down_weighted, block.tag_refused});
    }
    saved.state = vectorFrom(block.state);
    const auto size = static_cast<Eigen::Index>(block.state.size());
    saved.covariance.resize(size, size);
    for (Eigen::Index i = 0; i < size; ++i) {
        for (Eigen::Index j = 0; j < size; ++j) {
            saved.covariance(i, j) = block.covariance[static_cast<size_t>(i * size + j)];
        }
    }
    std::vector<uint64_t *> fields = flightCounterFields(saved.counters);
    for (size_t i = 0; i < block.counters.size() && i < fields.size(); ++i) {
        *fields[i] = block.counters[i];
    }
    engine::FlightTracks::RestoreReport report;
    try {
        report = engine.restoreFlights(saved);
    } catch (const std::invalid_argument &error) {
        throw CheckpointError(std::string("the checkpoint's flight block: ") + error.what());
    }
    if (!report.dropped.empty()) {
        warnings.push_back("the checkpoint's 3D tracks of nodes " + idList(report.dropped) +
                           " are not in map.moving: dropped");
    }
    if (!report.restarted.empty()) {
        warnings.push_back("nodes " + idList(report.restarted) +
                           " of map.moving have no 3D track in the checkpoint: their tracks restart from their "
                           "next ranges");
    }
    if (report.anchors_differ) {
        warnings.push_back("the checkpoint's anchors (the fixed nodes of known height the 3D tracks started "
                           "from) differ from the ones given now: the tracks go on from the checkpoint's");
    }
    if (report.bodies_differ) {
        warnings.push_back("the checkpoint's rigid bodies differ from the configured ones (--moving-body): the "
                           "configured ones apply");
    }
    return warnings;
}

std::vector<uint8_t> movementBlockOf(const engine::MovementStage &movement)
{
    engine::MovementStage::Saved saved = movement.saved();
    blocks::movement_block block;
    block.version = CDRO_CHECKPOINT_MOVEMENT_VERSION;
    block.robot_id = movement.params().robot_id;
    block.flags =
        static_cast<uint8_t>(bitIf(saved.started, CDRO_CHECKPOINT_MOVEMENT_STARTED) |
                             bitIf(saved.own_frame, CDRO_CHECKPOINT_MOVEMENT_OWN_FRAME) |
                             bitIf(saved.waiting_for_fix, CDRO_CHECKPOINT_MOVEMENT_WAITING_FOR_FIX) |
                             bitIf(saved.have_time, CDRO_CHECKPOINT_MOVEMENT_HAVE_TIME) |
                             bitIf(saved.adaptive_sigma_m.has_value(), CDRO_CHECKPOINT_MOVEMENT_ADAPTIVE_SIGMA));
    block.moved_m = saved.moved_m;
    block.last_t_s = saved.last_t_s;
    block.dead_reckoning_x_m = saved.dead_reckoning.x_m;
    block.dead_reckoning_y_m = saved.dead_reckoning.y_m;
    block.dead_reckoning_heading_rad = saved.dead_reckoning.heading_rad;
    block.adaptive_sigma_m = saved.adaptive_sigma_m.value_or(0.0);
    for (const engine::MovementStage::Hypothesis &hypothesis : saved.hypotheses) {
        const engine::RobotFilter &filter = hypothesis.filter;
        blocks::movement_hypothesis &out = block.hypotheses.emplace_back();
        out.log_weight = hypothesis.log_weight;
        out.filter_flags = static_cast<uint8_t>(bitIf(filter.mirrored(), CDRO_CHECKPOINT_FILTER_MIRRORED) |
                                                bitIf(filter.scaleFixed(), CDRO_CHECKPOINT_FILTER_SCALE_FIXED) |
                                                bitIf(filter.offsetFixed(), CDRO_CHECKPOINT_FILTER_OFFSET_FIXED));
        for (engine::NodeId id : filter.nodes()) {
            out.node_ids.push_back(id);
        }
        out.state = doublesOf(filter.state());
        const Eigen::MatrixXd &covariance = filter.covariance();
        for (Eigen::Index i = 0; i < covariance.rows(); ++i) {
            for (Eigen::Index j = 0; j < covariance.cols(); ++j) {
                out.covariance.push_back(covariance(i, j));
            }
        }
    }
    for (const auto &[id, sog] : saved.beacons) {
        blocks::movement_beacon &out = block.beacons.emplace_back();
        out.id = id;
        out.ranges = sog.ranges;
        out.first_robot_x_m = sog.first_robot_m.x();
        out.first_robot_y_m = sog.first_robot_m.y();
        out.baseline_m = sog.baseline_m;
        for (const engine::SogComponentState &component : sog.ring.components()) {
            blocks::movement_component &c = out.components.emplace_back();
            c.mean_x_m = component.mean_m.x();
            c.mean_y_m = component.mean_m.y();
            c.var_x_m2 = component.covariance_m2(0, 0);
            c.cov_xy_m2 = component.covariance_m2(0, 1);
            c.cov_yx_m2 = component.covariance_m2(1, 0);
            c.var_y_m2 = component.covariance_m2(1, 1);
            c.weight = component.weight;
        }
    }
    for (const auto &[id, moving] : saved.moving) {
        block.moving.push_back({id, static_cast<uint8_t>(moving ? 1 : 0)});
    }
    for (const auto &[ends, watch] : saved.links) {
        block.links.push_back({ends.first, ends.second, static_cast<uint32_t>(watch.next),
                               static_cast<uint8_t>(watch.excluded ? 1 : 0), watch.innovations_m});
    }
    block.innovations_m = saved.innovations_m;
    block.prior_variances_m2 = saved.prior_variances_m2;
    block.innovation_next = static_cast<uint32_t>(saved.innovation_next);
    block.revision = saved.revision;
    for (const uint64_t *field : movementCounterFields(saved.counters)) {
        block.counters.push_back(*field);
    }
    return blocks::encode(block);
}

void restoreMovement(engine::MovementStage &movement, const service::SogSnapshot &snapshot)
{
    const service::SogSnapshot::Extension *extension = snapshot.findExtension(kMovementExtensionTag);
    if (extension == nullptr) {
        return; // written without a robot: the stage starts afresh, as on a first start
    }
    const auto block =
        blocks::decode<blocks::movement_block>(extension->bytes, "movement", CDRO_CHECKPOINT_MOVEMENT_VERSION);
    if (block.robot_id != movement.params().robot_id) {
        throw CheckpointError("the checkpoint's movement stage is robot " + std::to_string(block.robot_id) +
                              ", the configuration's " + std::to_string(movement.params().robot_id));
    }
    engine::MovementStage::Saved saved;
    saved.started = (block.flags & CDRO_CHECKPOINT_MOVEMENT_STARTED) != 0;
    saved.own_frame = (block.flags & CDRO_CHECKPOINT_MOVEMENT_OWN_FRAME) != 0;
    saved.waiting_for_fix = (block.flags & CDRO_CHECKPOINT_MOVEMENT_WAITING_FOR_FIX) != 0;
    saved.have_time = (block.flags & CDRO_CHECKPOINT_MOVEMENT_HAVE_TIME) != 0;
    saved.moved_m = block.moved_m;
    saved.last_t_s = block.last_t_s;
    saved.dead_reckoning.x_m = block.dead_reckoning_x_m;
    saved.dead_reckoning.y_m = block.dead_reckoning_y_m;
    saved.dead_reckoning.heading_rad = block.dead_reckoning_heading_rad;
    if ((block.flags & CDRO_CHECKPOINT_MOVEMENT_ADAPTIVE_SIGMA) != 0) {
        saved.adaptive_sigma_m = block.adaptive_sigma_m;
    }
    for (const blocks::movement_hypothesis &in : block.hypotheses) {
        if (in.node_ids.size() > engine::RobotFilter::kMaxNodes) {
            throw CheckpointError("the checkpoint's movement block has an EKF of " +
                                  std::to_string(in.node_ids.size()) + " nodes");
        }
        const std::vector<engine::NodeId> nodes(in.node_ids.begin(), in.node_ids.end());
        const Eigen::VectorXd state = vectorFrom(in.state);
        Eigen::MatrixXd covariance(state.size(), state.size());
        for (Eigen::Index i = 0; i < covariance.rows(); ++i) {
            for (Eigen::Index j = 0; j < covariance.cols(); ++j) {
                covariance(i, j) = in.covariance[static_cast<size_t>(i * covariance.cols() + j)];
            }
        }
        try {
            saved.hypotheses.push_back(engine::MovementStage::Hypothesis{
                engine::RobotFilter::restored(state, covariance, nodes,
                                              (in.filter_flags & CDRO_CHECKPOINT_FILTER_MIRRORED) != 0,
                                              (in.filter_flags & CDRO_CHECKPOINT_FILTER_SCALE_FIXED) != 0,
                                              (in.filter_flags & CDRO_CHECKPOINT_FILTER_OFFSET_FIXED) != 0),
                in.log_weight});
        } catch (const std::invalid_argument &error) {
            throw CheckpointError(std::string("the checkpoint's movement block: ") + error.what());
        }
    }
    for (const blocks::movement_beacon &in : block.beacons) {
        engine::MovementStage::BeaconSog sog;
        sog.ranges = in.ranges;
        sog.first_robot_m = engine::Vector2(in.first_robot_x_m, in.first_robot_y_m);
        sog.baseline_m = in.baseline_m;
        std::vector<engine::SogComponentState> components;
        for (const blocks::movement_component &c : in.components) {
            engine::SogComponentState &component = components.emplace_back();
            component.mean_m = engine::Vector2(c.mean_x_m, c.mean_y_m);
            component.covariance_m2(0, 0) = c.var_x_m2;
            component.covariance_m2(0, 1) = c.cov_xy_m2;
            component.covariance_m2(1, 0) = c.cov_yx_m2;
            component.covariance_m2(1, 1) = c.var_y_m2;
            component.weight = c.weight;
        }
        sog.ring.setIdentity(block.robot_id, in.id);
        sog.ring.setAbsoluteComponents(std::move(components));
        saved.beacons[in.id] = std::move(sog);
    }
    for (const blocks::movement_moving &in : block.moving) {
        saved.moving[in.id] = in.moving != 0;
    }
    for (const blocks::movement_link &in : block.links) {
        engine::MovementStage::LinkWatch watch;
        watch.next = in.next;
        watch.excluded = in.excluded != 0;
        watch.innovations_m = in.innovations_m;
        if (watch.next > watch.innovations_m.size()) {
            throw CheckpointError("the checkpoint's movement block has a link watch past its end");
        }
        saved.links[{in.a_id, in.b_id}] = std::move(watch);
    }
    saved.innovations_m = block.innovations_m;
    saved.prior_variances_m2 = block.prior_variances_m2;
    saved.innovation_next = block.innovation_next;
    if (saved.prior_variances_m2.size() != saved.innovations_m.size() ||
        saved.innovation_next > saved.innovations_m.size()) {
        throw CheckpointError("the checkpoint's movement block has innovations that do not fit together");
    }
    saved.revision = block.revision;
    std::vector<uint64_t *> fields = movementCounterFields(saved.counters);
    for (size_t i = 0; i < block.counters.size() && i < fields.size(); ++i) {
        *fields[i] = block.counters[i];
    }
    movement.restore(saved);
}

service::SogSnapshot snapshotOf(const engine::Engine &engine, int64_t created_unix_us)
{
    const engine::MapState &network = engine.map();
    service::SogSnapshot snapshot;
    snapshot.header.created_unix_us = created_unix_us;
    snapshot.header.ranges_processed =
        static_cast<uint32_t>(std::min<uint64_t>(engine.counters().intake.ranges_received, 0xFFFFFFFFULL));
    blocks::engine_block block;
    block.version = CDRO_CHECKPOINT_ENGINE_VERSION;
    if (const auto frame = engine.frameNodes()) {
        block.has_frame = 1;
        block.frame_origin_id = (*frame)[0];
        block.frame_axis_id = (*frame)[1];
        block.frame_side_id = (*frame)[2];
    }
    for (const engine::NodeState &node : network.nodes) {
        cdro_sog_node_t out{};
        out.id = node.id;
        out.flags = static_cast<uint8_t>(
            (node.placed() ? CDRO_SOG_NODE_PLACED : 0) | (node.converged() ? CDRO_SOG_NODE_CONVERGED : 0) |
            (node.moving() ? CDRO_SOG_NODE_MOVING : 0) | (node.fixed() ? CDRO_SOG_NODE_FIXED : 0) |
            (node.height_m ? CDRO_SOG_NODE_HEIGHT_KNOWN : 0));
        out.x_mm = cdro_fixed_mm_from_m(node.position_m.x());
        out.y_mm = cdro_fixed_mm_from_m(node.position_m.y());
        out.z_mm = cdro_fixed_mm_from_m(node.height_m.value_or(0.0));
        const cdro_fixed_covariance_t covariance =
            cdro_fixed_covariance_from(node.covariance_m2(0, 0), node.covariance_m2(0, 1), node.covariance_m2(1, 1));
        out.std_x_um = covariance.std_x_um;
        out.std_y_um = covariance.std_y_um;
        out.correlation_q15 = covariance.correlation_q15;
        out.average_x_mm = cdro_fixed_mm_from_m(node.average_m.x());
        out.average_y_mm = cdro_fixed_mm_from_m(node.average_m.y());
        out.merge_count = saturate16(node.update_count);
        snapshot.nodes.push_back(out);
        // The exact state (the common layout above is rounded to millimetres and flags).
        blocks::engine_node &exact = block.nodes.emplace_back();
        exact.id = node.id;
        exact.still_updates = node.still_updates;
        exact.placements = node.placements;
        exact.update_count = node.update_count;
        exact.role = static_cast<uint8_t>(node.role);
        exact.lifecycle = static_cast<uint8_t>(node.lifecycle);
        exact.doubt = static_cast<uint8_t>(node.doubt);
        const auto &structural = engine.structuralDoubts();
        const size_t index = static_cast<size_t>(&node - network.nodes.data());
        exact.structural_doubt =
            static_cast<uint8_t>(index < structural.size() ? structural[index] : engine::NodeDoubt::None);
        exact.hinge_a_id = node.hinge[0] == engine::kNoIndex ? 0 : network.nodes[node.hinge[0]].id;
        exact.hinge_b_id = node.hinge[1] == engine::kNoIndex ? 0 : network.nodes[node.hinge[1]].id;
        exact.x_m = node.position_m.x();
        exact.y_m = node.position_m.y();
        exact.var_x_m2 = node.covariance_m2(0, 0);
        exact.cov_xy_m2 = node.covariance_m2(0, 1);
        exact.var_y_m2 = node.covariance_m2(1, 1);
        exact.average_x_m = node.average_m.x();
        exact.average_y_m = node.average_m.y();
        exact.waiting_ranges = node.waiting_ranges;
        exact.first_range = node.first_range;
        exact.motion_flags =
            static_cast<uint8_t>(bitIf(node.motion.reports, CDRO_CHECKPOINT_MOTION_REPORTS) |
                                 bitIf(node.motion.reported_moving, CDRO_CHECKPOINT_MOTION_REPORTED_MOVING) |
                                 bitIf(node.motion.inferred, CDRO_CHECKPOINT_MOTION_INFERRED));
        const engine::NodeSolveView &solve = node.solve;
        exact.solve_flags = static_cast<uint8_t>(bitIf(solve.solved, CDRO_CHECKPOINT_SOLVE_SOLVED) |
                                                 bitIf(solve.disputed, CDRO_CHECKPOINT_SOLVE_DISPUTED) |
                                                 bitIf(solve.main_part, CDRO_CHECKPOINT_SOLVE_MAIN_PART));
        exact.solve_x_m = solve.position_m.x();
        exact.solve_y_m = solve.position_m.y();
        exact.solve_var_x_m2 = solve.covariance_m2(0, 0);
        exact.solve_cov_xy_m2 = solve.covariance_m2(0, 1);
        exact.solve_var_y_m2 = solve.covariance_m2(1, 1);
        exact.solve_reliability_m = solve.reliability_m;
        exact.range_offset_m = node.range_offset_m;
    }
    for (const engine::LinkState &link : network.links) {
        blocks::engine_link &out = block.links.emplace_back();
        out.a_id = network.nodes[link.node_a].id;
        out.b_id = network.nodes[link.node_b].id;
        out.range_count = link.range_count;
        out.last_range_mm = mmOfRange(link.last_range_m);
        out.inlier_probability_q16 = cdro_fixed_q16_from(link.inlier_probability);
        out.solved_range_m = link.solved_range_m;
        for (double value : link.window.values()) {
            out.window_mm.push_back(mmOfRange(value));
        }
    }
    for (const engine::RingSog &ring : network.rings) {
        if (ring.empty()) {
            continue;
        }
        service::SogSnapshot::Pair pair;
        pair.pair.center_id = ring.center();
        pair.pair.target_id = ring.target();
        const uint32_t center = network.findNode(ring.center());
        const uint32_t target = network.findNode(ring.target());
        const uint32_t link = network.findLink(center, target);
        pair.pair.last_range_mm = mmOfRange(network.links[link].representative_m);
        pair.pair.range_count = saturate16(network.links[link].range_count);
        for (const engine::SogComponentState &component : ring.components()) {
            cdro_sog_component_t out{};
            out.x_mm = cdro_fixed_mm_from_m(component.mean_m.x());
            out.y_mm = cdro_fixed_mm_from_m(component.mean_m.y());
            const cdro_fixed_covariance_t covariance =
                cdro_fixed_covariance_from(component.covariance_m2(0, 0), component.covariance_m2(0, 1),
                                           component.covariance_m2(1, 1));
            out.std_x_um = covariance.std_x_um;
            out.std_y_um = covariance.std_y_um;
            out.correlation_q15 = covariance.correlation_q15;
            out.weight_q16 = cdro_fixed_q16_from(component.weight);
            pair.components.push_back(out);
        }
        snapshot.pairs.push_back(std::move(pair));
        block.ring_update_counts.push_back(ring.updateCount());
    }
    const engine::SolveSchedule &schedule = engine.solveSchedule();
    block.links_at_last_solve = schedule.links_at_last;
    block.ranges_at_last_solve = schedule.ranges_at_last;
    block.ranges_since_new_link = schedule.ranges_since_new_link;
    block.ranges_at_check = schedule.ranges_at_check;
    block.links_at_full_solve = schedule.links_at_full;
    block.nodes_at_full_solve = schedule.nodes_at_full;
    block.ranges_at_full_solve = schedule.ranges_at_full;
    block.assessed_key = engine.assessedKey();
    engine::EngineCounters counters = engine.counters();
    for (const uint64_t *field : counterFields(counters)) {
        block.counters.push_back(*field);
    }
    snapshot.extensions.push_back({kEngineExtensionTag, blocks::encode(block)});
    const engine::RigidTransform &offset = network.frame_offset;
    if (offset.rotation != engine::Matrix2::Identity() || offset.translation_m != engine::Vector2::Zero()) {
        blocks::output_frame_block frame;
        frame.version = CDRO_CHECKPOINT_OUTPUT_FRAME_VERSION;
        frame.rotation_xx = offset.rotation(0, 0);
        frame.rotation_xy = offset.rotation(0, 1);
        frame.rotation_yx = offset.rotation(1, 0);
        frame.rotation_yy = offset.rotation(1, 1);
        frame.translation_x_m = offset.translation_m.x();
        frame.translation_y_m = offset.translation_m.y();
        snapshot.extensions.push_back({kOutputFrameExtensionTag, blocks::encode(frame)});
    }
    return snapshot;
}

namespace {

// The output frame's offset (none without the block: the frame triangle's own frame).
engine::RigidTransform outputFrameOffsetOf(const service::SogSnapshot &snapshot)
{
    engine::RigidTransform offset;
    const service::SogSnapshot::Extension *extension = snapshot.findExtension(kOutputFrameExtensionTag);
    if (extension == nullptr) {
        return offset;
    }
    const auto frame = blocks::decode<blocks::output_frame_block>(extension->bytes, "output frame",
                                                                  CDRO_CHECKPOINT_OUTPUT_FRAME_VERSION);
    offset.rotation << frame.rotation_xx, frame.rotation_xy, frame.rotation_yx, frame.rotation_yy;
    offset.translation_m = engine::Vector2(frame.translation_x_m, frame.translation_y_m);
    // Orthonormal to the doubles' precision, as the engine composes them; anything else is damage.
    constexpr double kOrthonormalTolerance = 1e-9;
    if (!offset.rotation.allFinite() || !offset.translation_m.allFinite() ||
        (offset.rotation.transpose() * offset.rotation - engine::Matrix2::Identity()).cwiseAbs().maxCoeff() >
            kOrthonormalTolerance) {
        throw CheckpointError("the checkpoint's output frame block holds no rotation (not orthonormal, or not finite)");
    }
    const engine::Matrix2 &rotation = offset.rotation;
    offset.reflected = rotation(0, 0) * rotation(1, 1) - rotation(0, 1) * rotation(1, 0) < 0.0;
    return offset;
}

} // namespace

void restoreFrom(engine::Engine &engine, const service::SogSnapshot &snapshot)
{
    const service::SogSnapshot::Extension *extension = snapshot.findExtension(kEngineExtensionTag);
    if (extension == nullptr) {
        throw CheckpointError("the checkpoint has no engine block (tag 0x0001): not written by cdro-hostd");
    }
    const auto block = blocks::decode<blocks::engine_block>(extension->bytes, "engine", CDRO_CHECKPOINT_ENGINE_VERSION);
    engine::Engine::RestoredState state;
    if (block.has_frame != 0) {
        state.frame_nodes =
            std::array<engine::NodeId, 3>{block.frame_origin_id, block.frame_axis_id, block.frame_side_id};
    }
    if (block.nodes.size() != snapshot.nodes.size()) {
        throw CheckpointError("the checkpoint's engine block names " + std::to_string(block.nodes.size()) +
                              " nodes, the map " + std::to_string(snapshot.nodes.size()));
    }
    for (size_t n = 0; n < block.nodes.size(); ++n) {
        const cdro_sog_node_t &in = snapshot.nodes[n];
        const blocks::engine_node &exact = block.nodes[n];
        engine::NodeState node;
        node.id = in.id;
        if (exact.id != in.id) {
            throw CheckpointError("the checkpoint's engine block lists the nodes in another order");
        }
        node.still_updates = exact.still_updates;
        node.placements = exact.placements;
        node.update_count = exact.update_count;
        node.role = static_cast<engine::NodeRole>(exact.role); // in range: the table's R
        node.lifecycle = static_cast<engine::NodeLifecycle>(exact.lifecycle);
        node.doubt = static_cast<engine::NodeDoubt>(exact.doubt);
        state.structural_doubts.push_back(static_cast<engine::NodeDoubt>(exact.structural_doubt));
        if ((in.flags & CDRO_SOG_NODE_HEIGHT_KNOWN) != 0) {
            node.height_m = cdro_fixed_mm_to_m(in.z_mm);
        }
        node.position_m = engine::Vector2(exact.x_m, exact.y_m);
        node.covariance_m2(0, 0) = exact.var_x_m2;
        node.covariance_m2(0, 1) = node.covariance_m2(1, 0) = exact.cov_xy_m2;
        node.covariance_m2(1, 1) = exact.var_y_m2;
        node.average_m = engine::Vector2(exact.average_x_m, exact.average_y_m);
        node.waiting_ranges = exact.waiting_ranges;
        node.first_range = exact.first_range;
        node.motion.reports = (exact.motion_flags & CDRO_CHECKPOINT_MOTION_REPORTS) != 0;
        node.motion.reported_moving = (exact.motion_flags & CDRO_CHECKPOINT_MOTION_REPORTED_MOVING) != 0;
        node.motion.inferred = (exact.motion_flags & CDRO_CHECKPOINT_MOTION_INFERRED) != 0;
        node.solve.solved = (exact.solve_flags & CDRO_CHECKPOINT_SOLVE_SOLVED) != 0;
        node.solve.disputed = (exact.solve_flags & CDRO_CHECKPOINT_SOLVE_DISPUTED) != 0;
        node.solve.main_part = (exact.solve_flags & CDRO_CHECKPOINT_SOLVE_MAIN_PART) != 0;
        node.solve.position_m = engine::Vector2(exact.solve_x_m, exact.solve_y_m);
        node.solve.covariance_m2(0, 0) = exact.solve_var_x_m2;
        node.solve.covariance_m2(0, 1) = node.solve.covariance_m2(1, 0) = exact.solve_cov_xy_m2;
        node.solve.covariance_m2(1, 1) = exact.solve_var_y_m2;
        node.solve.reliability_m = exact.solve_reliability_m;
        node.range_offset_m = exact.range_offset_m;
        state.nodes.push_back(node);
    }
    // Hinges name nodes by id; the engine keeps indices (the nodes' order is the block's).
    for (size_t i = 0; i < state.nodes.size(); ++i) {
        const std::array<engine::NodeId, 2> hinges{block.nodes[i].hinge_a_id, block.nodes[i].hinge_b_id};
        for (size_t k = 0; k < 2; ++k) {
            state.nodes[i].hinge[k] = engine::kNoIndex;
            for (size_t j = 0; j < state.nodes.size() && hinges[k] != 0; ++j) {
                if (state.nodes[j].id == hinges[k]) {
                    state.nodes[i].hinge[k] = static_cast<uint32_t>(j);
                }
            }
        }
    }
    for (const blocks::engine_link &in : block.links) {
        engine::Engine::RestoredLink link;
        link.a = in.a_id;
        link.b = in.b_id;
        link.range_count = in.range_count;
        link.last_range_m = in.last_range_mm / 1000.0;
        link.inlier_probability = cdro_fixed_q16_to(in.inlier_probability_q16);
        link.solved_range_m = in.solved_range_m;
        for (uint32_t mm : in.window_mm) {
            link.window_m.push_back(mm / 1000.0);
        }
        state.links.push_back(std::move(link));
    }
    if (block.ring_update_counts.size() != snapshot.pairs.size()) {
        throw CheckpointError("the checkpoint's engine block names " + std::to_string(block.ring_update_counts.size()) +
                              " SoGs, the map " + std::to_string(snapshot.pairs.size()));
    }
    for (size_t p = 0; p < snapshot.pairs.size(); ++p) {
        const service::SogSnapshot::Pair &pair = snapshot.pairs[p];
        std::vector<engine::SogComponentState> components;
        for (const cdro_sog_component_t &in : pair.components) {
            engine::SogComponentState component;
            component.mean_m = engine::Vector2(cdro_fixed_mm_to_m(in.x_mm), cdro_fixed_mm_to_m(in.y_mm));
            component.covariance_m2 = covarianceOf({in.std_x_um, in.std_y_um, in.correlation_q15});
            component.weight = cdro_fixed_q16_to(in.weight_q16);
            components.push_back(component);
        }
        engine::RingSog ring;
        ring.setIdentity(pair.pair.center_id, pair.pair.target_id);
        const size_t count = std::max<size_t>(components.size(), 1U);
        ring.setWeightFloor(std::min(engine.params().ring.weight_floor, 0.1 / static_cast<double>(count)));
        ring.setComponents(components);
        ring.setUpdateCount(block.ring_update_counts[p]);
        state.rings.push_back(std::move(ring));
    }
    state.solve_schedule.links_at_last = block.links_at_last_solve;
    state.solve_schedule.ranges_at_last = block.ranges_at_last_solve;
    state.solve_schedule.ranges_since_new_link = block.ranges_since_new_link;
    state.solve_schedule.ranges_at_check = block.ranges_at_check;
    state.solve_schedule.links_at_full = block.links_at_full_solve;
    state.solve_schedule.nodes_at_full = block.nodes_at_full_solve;
    state.solve_schedule.ranges_at_full = block.ranges_at_full_solve;
    state.assessed_key = block.assessed_key;
    state.frame_offset = outputFrameOffsetOf(snapshot);
    std::vector<uint64_t *> fields = counterFields(state.counters);
    for (size_t i = 0; i < block.counters.size() && i < fields.size(); ++i) {
        *fields[i] = block.counters[i];
    }
    try {
        engine.restore(state);
    } catch (const std::invalid_argument &error) {
        throw CheckpointError(std::string("the checkpoint does not describe a consistent map: ") + error.what());
    }
}

} // namespace cdro::hostd
