#include "cdro/hostd/engine_adapter.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "cdro/fixed.h"
#include "cdro/wire.h"

namespace cdro::hostd {

using service::CheckpointError;

namespace {

// ---- little-endian byte blocks for the extension ----------------------------------------

class ByteWriter {
public:
    void u8(uint8_t v) { bytes_.push_back(v); }
    void u16(uint16_t v) { put(v, 2); }
    void u32(uint32_t v) { put(v, 4); }
    void u64(uint64_t v) { put(v, 8); }
    std::vector<uint8_t> take() { return std::move(bytes_); }

private:
    void put(uint64_t v, size_t size)
    {
        uint8_t buffer[8];
        cdro_put_u64(buffer, v);
        bytes_.insert(bytes_.end(), buffer, buffer + size);
    }
    std::vector<uint8_t> bytes_;
};

class ByteReader {
public:
    explicit ByteReader(const std::vector<uint8_t> &bytes, const char *block = "engine") : bytes_(bytes), block_(block)
    {
    }
    uint8_t u8() { return static_cast<uint8_t>(get(1)); }
    uint16_t u16() { return static_cast<uint16_t>(get(2)); }
    uint32_t u32() { return static_cast<uint32_t>(get(4)); }
    uint64_t u64() { return get(8); }
    bool done() const { return position_ == bytes_.size(); }

private:
    uint64_t get(size_t size)
    {
        if (position_ + size > bytes_.size()) {
            throw CheckpointError(std::string("the ") + block_ + " block of the checkpoint is cut short");
        }
        uint8_t buffer[8] = {0, 0, 0, 0, 0, 0, 0, 0};
        std::memcpy(buffer, bytes_.data() + position_, size);
        position_ += size;
        return cdro_get_u64(buffer);
    }
    const std::vector<uint8_t> &bytes_;
    const char *block_;
    size_t position_ = 0;
};

// 2: roles, lifecycles and doubts as enums; the motion memory, the solve's view of each node and
// the solve schedule; the counters of every step.
constexpr uint8_t kEngineBlockVersion = 2;

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

// Doubles through the block: their bits, exactly.
uint64_t bitsOf(double value)
{
    uint64_t bits = 0;
    std::memcpy(&bits, &value, sizeof bits);
    return bits;
}

double doubleOf(uint64_t bits)
{
    double value = 0.0;
    std::memcpy(&value, &bits, sizeof value);
    return value;
}

template <typename Enum> Enum enumOf(uint8_t value, uint8_t last, const char *what)
{
    if (value > last) {
        throw CheckpointError(std::string("the checkpoint's engine block has an unknown ") + what + " " +
                              std::to_string(value));
    }
    return static_cast<Enum>(value);
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

EngineAdapter::EngineAdapter(engine::Engine &engine, engine::MovementStage *movement)
    : engine_(engine), movement_(movement)
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

void EngineAdapter::onOdometry(const service::OdometryMessage &message)
{
    if (movement_ != nullptr) {
        movement_->addOdometry(message.t_s, engine::OdometryStep{message.distance_m, message.dheading_rad});
    }
}

void EngineAdapter::fill(service::MapState &map) const
{
    map.nodes.clear();
    const std::vector<engine::NodeOutput> estimates =
        movement_ != nullptr ? movement_->estimates() : engine_.estimates();
    for (const engine::NodeOutput &node : estimates) {
        if (node.link_count == 0 && !node.fixed()) {
            continue;
        }
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
        map.nodes.push_back(out);
    }
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
    map.robot.reset();
    if (movement_ != nullptr) {
        const std::optional<engine::RobotOutput> robot = movement_->robot();
        if (robot && robot->localized) {
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
            map.robot = pose;
        }
    }
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
    return snapshot;
}

void EngineAdapter::restore(const service::SogSnapshot &snapshot)
{
    restoreFrom(engine_, snapshot);
    if (movement_ != nullptr) {
        restoreMovement(*movement_, snapshot);
    }
}

namespace {

// 1: the stage's whole state (movement.hpp MovementStage::Saved), doubles as their bits.
constexpr uint8_t kMovementBlockVersion = 1;

void putVector(ByteWriter &block, const Eigen::VectorXd &values)
{
    block.u32(static_cast<uint32_t>(values.size()));
    for (Eigen::Index i = 0; i < values.size(); ++i) {
        block.u64(bitsOf(values(i)));
    }
}

Eigen::VectorXd vectorOf(ByteReader &block, uint32_t limit)
{
    const uint32_t size = block.u32();
    if (size > limit) {
        throw CheckpointError("the checkpoint's movement block holds a vector of " + std::to_string(size) + " values");
    }
    Eigen::VectorXd values(size);
    for (uint32_t i = 0; i < size; ++i) {
        values(i) = doubleOf(block.u64());
    }
    return values;
}

void putMatrix2(ByteWriter &block, const engine::Matrix2 &m)
{
    block.u64(bitsOf(m(0, 0)));
    block.u64(bitsOf(m(0, 1)));
    block.u64(bitsOf(m(1, 0)));
    block.u64(bitsOf(m(1, 1)));
}

engine::Matrix2 matrix2Of(ByteReader &block)
{
    engine::Matrix2 m;
    m(0, 0) = doubleOf(block.u64());
    m(0, 1) = doubleOf(block.u64());
    m(1, 0) = doubleOf(block.u64());
    m(1, 1) = doubleOf(block.u64());
    return m;
}

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

} // namespace

std::vector<uint8_t> movementBlockOf(const engine::MovementStage &movement)
{
    engine::MovementStage::Saved saved = movement.saved();
    ByteWriter block;
    block.u8(kMovementBlockVersion);
    block.u16(movement.params().robot_id);
    block.u8(static_cast<uint8_t>((saved.started ? 1U : 0U) | (saved.own_frame ? 2U : 0U) |
                                  (saved.waiting_for_fix ? 4U : 0U) | (saved.have_time ? 8U : 0U) |
                                  (saved.adaptive_sigma_m ? 16U : 0U)));
    block.u64(bitsOf(saved.moved_m));
    block.u64(bitsOf(saved.last_t_s));
    block.u64(bitsOf(saved.dead_reckoning.x_m));
    block.u64(bitsOf(saved.dead_reckoning.y_m));
    block.u64(bitsOf(saved.dead_reckoning.heading_rad));
    block.u64(bitsOf(saved.adaptive_sigma_m.value_or(0.0)));
    block.u32(static_cast<uint32_t>(saved.hypotheses.size()));
    for (const engine::MovementStage::Hypothesis &hypothesis : saved.hypotheses) {
        const engine::RobotFilter &filter = hypothesis.filter;
        block.u64(bitsOf(hypothesis.log_weight));
        block.u8(static_cast<uint8_t>((filter.mirrored() ? 1U : 0U) | (filter.scaleFixed() ? 2U : 0U) |
                                      (filter.offsetFixed() ? 4U : 0U)));
        const std::vector<engine::NodeId> nodes = filter.nodes();
        block.u32(static_cast<uint32_t>(nodes.size()));
        for (engine::NodeId id : nodes) {
            block.u16(id);
        }
        putVector(block, filter.state());
        const Eigen::MatrixXd &covariance = filter.covariance();
        for (Eigen::Index i = 0; i < covariance.rows(); ++i) {
            for (Eigen::Index j = 0; j < covariance.cols(); ++j) {
                block.u64(bitsOf(covariance(i, j)));
            }
        }
    }
    block.u32(static_cast<uint32_t>(saved.beacons.size()));
    for (const auto &[id, sog] : saved.beacons) {
        block.u16(id);
        block.u32(sog.ranges);
        block.u64(bitsOf(sog.first_robot_m.x()));
        block.u64(bitsOf(sog.first_robot_m.y()));
        block.u64(bitsOf(sog.baseline_m));
        block.u32(static_cast<uint32_t>(sog.components.size()));
        for (const engine::MovementStage::BeaconComponent &component : sog.components) {
            block.u64(bitsOf(component.mean_m.x()));
            block.u64(bitsOf(component.mean_m.y()));
            putMatrix2(block, component.covariance_m2);
            block.u64(bitsOf(component.weight));
        }
    }
    block.u32(static_cast<uint32_t>(saved.moving.size()));
    for (const auto &[id, moving] : saved.moving) {
        block.u16(id);
        block.u8(moving ? 1 : 0);
    }
    block.u32(static_cast<uint32_t>(saved.links.size()));
    for (const auto &[ends, watch] : saved.links) {
        block.u16(ends.first);
        block.u16(ends.second);
        block.u32(static_cast<uint32_t>(watch.next));
        block.u8(watch.excluded ? 1 : 0);
        putVector(block, vectorFrom(watch.innovations_m));
    }
    putVector(block, vectorFrom(saved.innovations_m));
    putVector(block, vectorFrom(saved.prior_variances_m2));
    block.u32(static_cast<uint32_t>(saved.innovation_next));
    block.u64(saved.revision);
    const std::vector<uint64_t *> fields = movementCounterFields(saved.counters);
    block.u8(static_cast<uint8_t>(fields.size()));
    for (uint64_t *field : fields) {
        block.u64(*field);
    }
    return block.take();
}

void restoreMovement(engine::MovementStage &movement, const service::SogSnapshot &snapshot)
{
    const service::SogSnapshot::Extension *extension = snapshot.findExtension(kMovementExtensionTag);
    if (extension == nullptr) {
        return; // written without a robot: the stage starts afresh, as on a first start
    }
    // Far more than any stage holds (the EKF takes at most 120 nodes); a bigger count is damage.
    constexpr uint32_t kLimit = 1U << 20U;
    ByteReader block(extension->bytes, "movement");
    if (block.u8() != kMovementBlockVersion) {
        throw CheckpointError("the checkpoint's movement block is of another version");
    }
    const engine::NodeId robot = block.u16();
    if (robot != movement.params().robot_id) {
        throw CheckpointError("the checkpoint's movement stage is robot " + std::to_string(robot) +
                              ", the configuration's " + std::to_string(movement.params().robot_id));
    }
    engine::MovementStage::Saved saved;
    const uint8_t flags = block.u8();
    saved.started = (flags & 1U) != 0;
    saved.own_frame = (flags & 2U) != 0;
    saved.waiting_for_fix = (flags & 4U) != 0;
    saved.have_time = (flags & 8U) != 0;
    saved.moved_m = doubleOf(block.u64());
    saved.last_t_s = doubleOf(block.u64());
    saved.dead_reckoning.x_m = doubleOf(block.u64());
    saved.dead_reckoning.y_m = doubleOf(block.u64());
    saved.dead_reckoning.heading_rad = doubleOf(block.u64());
    const double adaptive_sigma_m = doubleOf(block.u64());
    if ((flags & 16U) != 0) {
        saved.adaptive_sigma_m = adaptive_sigma_m;
    }
    const uint32_t hypotheses = block.u32();
    if (hypotheses > kLimit) {
        throw CheckpointError("the checkpoint's movement block names " + std::to_string(hypotheses) + " hypotheses");
    }
    for (uint32_t h = 0; h < hypotheses; ++h) {
        const double log_weight = doubleOf(block.u64());
        const uint8_t filter_flags = block.u8();
        const uint32_t node_count = block.u32();
        if (node_count > engine::RobotFilter::kMaxNodes) {
            throw CheckpointError("the checkpoint's movement block has an EKF of " + std::to_string(node_count) +
                                  " nodes");
        }
        std::vector<engine::NodeId> nodes;
        for (uint32_t i = 0; i < node_count; ++i) {
            nodes.push_back(block.u16());
        }
        const Eigen::VectorXd state = vectorOf(block, kLimit);
        Eigen::MatrixXd covariance(state.size(), state.size());
        for (Eigen::Index i = 0; i < covariance.rows(); ++i) {
            for (Eigen::Index j = 0; j < covariance.cols(); ++j) {
                covariance(i, j) = doubleOf(block.u64());
            }
        }
        try {
            saved.hypotheses.push_back(engine::MovementStage::Hypothesis{
                engine::RobotFilter::restored(state, covariance, nodes, (filter_flags & 1U) != 0,
                                              (filter_flags & 2U) != 0, (filter_flags & 4U) != 0),
                log_weight});
        } catch (const std::invalid_argument &error) {
            throw CheckpointError(std::string("the checkpoint's movement block: ") + error.what());
        }
    }
    const uint32_t beacons = block.u32();
    for (uint32_t b = 0; b < beacons && b < kLimit; ++b) {
        const engine::NodeId id = block.u16();
        engine::MovementStage::BeaconSog sog;
        sog.ranges = block.u32();
        sog.first_robot_m.x() = doubleOf(block.u64());
        sog.first_robot_m.y() = doubleOf(block.u64());
        sog.baseline_m = doubleOf(block.u64());
        const uint32_t components = block.u32();
        if (components > kLimit) {
            throw CheckpointError("the checkpoint's movement block has a beacon of " + std::to_string(components) +
                                  " components");
        }
        for (uint32_t k = 0; k < components; ++k) {
            engine::MovementStage::BeaconComponent component;
            component.mean_m.x() = doubleOf(block.u64());
            component.mean_m.y() = doubleOf(block.u64());
            component.covariance_m2 = matrix2Of(block);
            component.weight = doubleOf(block.u64());
            sog.components.push_back(component);
        }
        saved.beacons[id] = std::move(sog);
    }
    const uint32_t moving = block.u32();
    for (uint32_t i = 0; i < moving && i < kLimit; ++i) {
        const engine::NodeId id = block.u16();
        saved.moving[id] = block.u8() != 0;
    }
    const uint32_t links = block.u32();
    for (uint32_t i = 0; i < links && i < kLimit; ++i) {
        const engine::NodeId a = block.u16();
        const engine::NodeId b = block.u16();
        engine::MovementStage::LinkWatch watch;
        watch.next = block.u32();
        watch.excluded = block.u8() != 0;
        watch.innovations_m = doublesOf(vectorOf(block, kLimit));
        if (watch.next > watch.innovations_m.size()) {
            throw CheckpointError("the checkpoint's movement block has a link watch past its end");
        }
        saved.links[{a, b}] = std::move(watch);
    }
    saved.innovations_m = doublesOf(vectorOf(block, kLimit));
    saved.prior_variances_m2 = doublesOf(vectorOf(block, kLimit));
    saved.innovation_next = block.u32();
    if (saved.prior_variances_m2.size() != saved.innovations_m.size() ||
        saved.innovation_next > saved.innovations_m.size()) {
        throw CheckpointError("the checkpoint's movement block has innovations that do not fit together");
    }
    saved.revision = block.u64();
    std::vector<uint64_t *> fields = movementCounterFields(saved.counters);
    const uint8_t stored = block.u8();
    for (uint8_t i = 0; i < stored; ++i) {
        const uint64_t value = block.u64();
        if (i < fields.size()) {
            *fields[i] = value;
        }
    }
    if (!block.done()) {
        throw CheckpointError("the checkpoint's movement block has bytes after its end");
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
    ByteWriter block;
    block.u8(kEngineBlockVersion);
    const auto frame = engine.frameNodes();
    block.u8(frame ? 1 : 0);
    for (size_t i = 0; i < 3; ++i) {
        block.u16(frame ? (*frame)[i] : 0);
    }
    block.u32(static_cast<uint32_t>(network.nodes.size()));
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
        block.u16(node.id);
        block.u32(node.still_updates);
        block.u32(node.placements);
        block.u32(node.update_count);
        // The exact state (the common layout above is rounded to millimetres and flags).
        block.u8(static_cast<uint8_t>(node.role));
        block.u8(static_cast<uint8_t>(node.lifecycle));
        block.u8(static_cast<uint8_t>(node.doubt));
        const auto &structural = engine.structuralDoubts();
        const size_t index = static_cast<size_t>(&node - network.nodes.data());
        block.u8(static_cast<uint8_t>(index < structural.size() ? structural[index] : engine::NodeDoubt::None));
        for (uint32_t hinge : node.hinge) {
            block.u16(hinge == engine::kNoIndex ? 0 : network.nodes[hinge].id);
        }
        block.u64(bitsOf(node.position_m.x()));
        block.u64(bitsOf(node.position_m.y()));
        block.u64(bitsOf(node.covariance_m2(0, 0)));
        block.u64(bitsOf(node.covariance_m2(0, 1)));
        block.u64(bitsOf(node.covariance_m2(1, 1)));
        block.u64(bitsOf(node.average_m.x()));
        block.u64(bitsOf(node.average_m.y()));
        block.u32(node.waiting_ranges);
        block.u64(node.first_range);
        block.u8(static_cast<uint8_t>((node.motion.reports ? 1U : 0U) | (node.motion.reported_moving ? 2U : 0U) |
                                      (node.motion.inferred ? 4U : 0U)));
        const engine::NodeSolveView &solve = node.solve;
        block.u8(
            static_cast<uint8_t>((solve.solved ? 1U : 0U) | (solve.disputed ? 2U : 0U) | (solve.main_part ? 4U : 0U)));
        block.u64(bitsOf(solve.position_m.x()));
        block.u64(bitsOf(solve.position_m.y()));
        block.u64(bitsOf(solve.covariance_m2(0, 0)));
        block.u64(bitsOf(solve.covariance_m2(0, 1)));
        block.u64(bitsOf(solve.covariance_m2(1, 1)));
        block.u64(bitsOf(solve.reliability_m));
        block.u64(bitsOf(node.range_offset_m));
    }
    block.u32(static_cast<uint32_t>(network.links.size()));
    for (const engine::LinkState &link : network.links) {
        block.u16(network.nodes[link.node_a].id);
        block.u16(network.nodes[link.node_b].id);
        block.u32(link.range_count);
        block.u32(mmOfRange(link.last_range_m));
        block.u16(cdro_fixed_q16_from(link.inlier_probability));
        block.u64(bitsOf(link.solved_range_m));
        const std::vector<double> window = link.window.values();
        block.u8(static_cast<uint8_t>(window.size()));
        for (double value : window) {
            block.u32(mmOfRange(value));
        }
    }
    uint32_t rings = 0;
    for (const engine::RingSog &ring : network.rings) {
        rings += ring.empty() ? 0U : 1U;
    }
    block.u32(rings);
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
        block.u32(ring.updateCount());
    }
    const engine::SolveSchedule &schedule = engine.solveSchedule();
    block.u64(schedule.links_at_last);
    block.u64(schedule.ranges_at_last);
    block.u64(schedule.ranges_since_new_link);
    block.u64(schedule.ranges_at_check);
    block.u64(schedule.links_at_full);
    block.u64(schedule.nodes_at_full);
    block.u64(schedule.ranges_at_full);
    block.u64(engine.assessedKey());
    engine::EngineCounters counters = engine.counters();
    const std::vector<uint64_t *> fields = counterFields(counters);
    block.u8(static_cast<uint8_t>(fields.size()));
    for (uint64_t *field : fields) {
        block.u64(*field);
    }
    snapshot.extensions.push_back({kEngineExtensionTag, block.take()});
    return snapshot;
}

void restoreFrom(engine::Engine &engine, const service::SogSnapshot &snapshot)
{
    const service::SogSnapshot::Extension *extension = snapshot.findExtension(kEngineExtensionTag);
    if (extension == nullptr) {
        throw CheckpointError("the checkpoint has no engine block (tag 0x0001): not written by cdro-hostd");
    }
    ByteReader block(extension->bytes);
    if (block.u8() != kEngineBlockVersion) {
        throw CheckpointError("the checkpoint's engine block is of another version");
    }
    engine::Engine::RestoredState state;
    const bool has_frame = block.u8() != 0;
    std::array<engine::NodeId, 3> frame{};
    for (size_t i = 0; i < 3; ++i) {
        frame[i] = block.u16();
    }
    if (has_frame) {
        state.frame_nodes = frame;
    }
    const uint32_t node_count = block.u32();
    if (node_count != snapshot.nodes.size()) {
        throw CheckpointError("the checkpoint's engine block names " + std::to_string(node_count) + " nodes, the map " +
                              std::to_string(snapshot.nodes.size()));
    }
    std::vector<std::array<engine::NodeId, 2>> hinges;
    for (const cdro_sog_node_t &in : snapshot.nodes) {
        engine::NodeState node;
        node.id = in.id;
        if (block.u16() != in.id) {
            throw CheckpointError("the checkpoint's engine block lists the nodes in another order");
        }
        node.still_updates = block.u32();
        node.placements = block.u32();
        node.update_count = block.u32();
        node.role = enumOf<engine::NodeRole>(block.u8(), static_cast<uint8_t>(engine::NodeRole::Pinned), "role");
        node.lifecycle =
            enumOf<engine::NodeLifecycle>(block.u8(), static_cast<uint8_t>(engine::NodeLifecycle::Settling),
                                          "lifecycle");
        node.doubt = enumOf<engine::NodeDoubt>(block.u8(), static_cast<uint8_t>(engine::NodeDoubt::Unsettled), "doubt");
        state.structural_doubts.push_back(
            enumOf<engine::NodeDoubt>(block.u8(), static_cast<uint8_t>(engine::NodeDoubt::Unsettled), "doubt"));
        std::array<engine::NodeId, 2> hinge_ids{};
        hinge_ids[0] = block.u16();
        hinge_ids[1] = block.u16();
        hinges.push_back(hinge_ids);
        if ((in.flags & CDRO_SOG_NODE_HEIGHT_KNOWN) != 0) {
            node.height_m = cdro_fixed_mm_to_m(in.z_mm);
        }
        node.position_m.x() = doubleOf(block.u64());
        node.position_m.y() = doubleOf(block.u64());
        node.covariance_m2(0, 0) = doubleOf(block.u64());
        node.covariance_m2(0, 1) = node.covariance_m2(1, 0) = doubleOf(block.u64());
        node.covariance_m2(1, 1) = doubleOf(block.u64());
        node.average_m.x() = doubleOf(block.u64());
        node.average_m.y() = doubleOf(block.u64());
        node.waiting_ranges = block.u32();
        node.first_range = block.u64();
        const uint8_t motion = block.u8();
        node.motion.reports = (motion & 1U) != 0;
        node.motion.reported_moving = (motion & 2U) != 0;
        node.motion.inferred = (motion & 4U) != 0;
        const uint8_t solve = block.u8();
        node.solve.solved = (solve & 1U) != 0;
        node.solve.disputed = (solve & 2U) != 0;
        node.solve.main_part = (solve & 4U) != 0;
        node.solve.position_m.x() = doubleOf(block.u64());
        node.solve.position_m.y() = doubleOf(block.u64());
        node.solve.covariance_m2(0, 0) = doubleOf(block.u64());
        node.solve.covariance_m2(0, 1) = node.solve.covariance_m2(1, 0) = doubleOf(block.u64());
        node.solve.covariance_m2(1, 1) = doubleOf(block.u64());
        node.solve.reliability_m = doubleOf(block.u64());
        node.range_offset_m = doubleOf(block.u64());
        state.nodes.push_back(node);
    }
    // Hinges name nodes by id; the engine keeps indices (the nodes' order is the block's).
    for (size_t i = 0; i < state.nodes.size(); ++i) {
        for (size_t k = 0; k < 2; ++k) {
            state.nodes[i].hinge[k] = engine::kNoIndex;
            for (size_t j = 0; j < state.nodes.size() && hinges[i][k] != 0; ++j) {
                if (state.nodes[j].id == hinges[i][k]) {
                    state.nodes[i].hinge[k] = static_cast<uint32_t>(j);
                }
            }
        }
    }
    const uint32_t link_count = block.u32();
    for (uint32_t i = 0; i < link_count; ++i) {
        engine::Engine::RestoredLink link;
        link.a = block.u16();
        link.b = block.u16();
        link.range_count = block.u32();
        link.last_range_m = block.u32() / 1000.0;
        link.inlier_probability = cdro_fixed_q16_to(block.u16());
        link.solved_range_m = doubleOf(block.u64());
        const uint8_t size = block.u8();
        for (uint8_t k = 0; k < size; ++k) {
            link.window_m.push_back(block.u32() / 1000.0);
        }
        state.links.push_back(std::move(link));
    }
    const uint32_t ring_count = block.u32();
    if (ring_count != snapshot.pairs.size()) {
        throw CheckpointError("the checkpoint's engine block names " + std::to_string(ring_count) + " SoGs, the map " +
                              std::to_string(snapshot.pairs.size()));
    }
    for (const service::SogSnapshot::Pair &pair : snapshot.pairs) {
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
        ring.setUpdateCount(block.u32());
        state.rings.push_back(std::move(ring));
    }
    state.solve_schedule.links_at_last = block.u64();
    state.solve_schedule.ranges_at_last = block.u64();
    state.solve_schedule.ranges_since_new_link = block.u64();
    state.solve_schedule.ranges_at_check = block.u64();
    state.solve_schedule.links_at_full = block.u64();
    state.solve_schedule.nodes_at_full = block.u64();
    state.solve_schedule.ranges_at_full = block.u64();
    state.assessed_key = block.u64();
    std::vector<uint64_t *> fields = counterFields(state.counters);
    const uint8_t stored = block.u8();
    for (uint8_t i = 0; i < stored; ++i) {
        const uint64_t value = block.u64();
        if (i < fields.size()) {
            *fields[i] = value;
        }
    }
    if (!block.done()) {
        throw CheckpointError("the checkpoint's engine block has bytes after its end");
    }
    try {
        engine.restore(state);
    } catch (const std::invalid_argument &error) {
        throw CheckpointError(std::string("the checkpoint does not describe a consistent map: ") + error.what());
    }
}

} // namespace cdro::hostd
