// engine_adapter.hpp: the SLAM engine behind the service's three interfaces
// (host/service: consumer.hpp, map_state.hpp, checkpoint.hpp), for cdro-hostd.
//
//   FrameConsumer       RANGE -> Engine::addRange (mm -> m), MOTION -> Engine::setMoving (or the
//                       movement stage's, with the frame's event time in s); host events: the
//                       global solve adopted between frames, live when its worker is done, on
//                       replay where the capture says (Engine::SolveAdoption::ByCaller)
//   MapSource           the engine's estimates in the output frame, its links, SoG components;
//                       the nodes tracked in 3D (map.moving) with their 3D track: z_m, var_z_m2,
//                       cov_xz_m2, cov_yz_m2 (docs/outputs.md), once they have started
//   CheckpointProvider  the engine state in common/'s fixed-point SoG layout (sog_layout.h),
//                       plus an extension block (tag kEngineExtensionTag) with what the layout
//                       does not hold: link windows, update counts, the frame, the counters;
//                       with a robot, a second block (kMovementExtensionTag): the movement
//                       stage's EKF hypotheses, beacon SoGs and link watches, exactly; both
//                       laid out by checkpoint_layout.def (cdro/hostd/checkpoint_blocks.hpp);
//                       with nodes tracked in 3D (map.moving), a third (kFlightExtensionTag):
//                       the 3D tracks' whole state, doubles exactly, so that they go on as if
//                       never stopped; once a node of the output frame's triangle moved and
//                       another took its place, a fourth (kOutputFrameExtensionTag): the offset
//                       that keeps the outputs where they were
//
// A checkpoint without the 3D tracks (written by an older cdro-hostd, or without map.moving), or
// whose tracks are of other nodes than map.moving, is resumed with a warning naming the nodes;
// those tracks restart from their next ranges.
// Resuming from a checkpoint continues from the state rounded to the layout's scales
// (positions to 0.5 mm, standard deviations to 0.5 um, weights to 7.7e-6, ranges in the link
// windows to 0.5 mm) and with an empty neighbour-update queue; docs/service.md states the
// tolerance this gives and tests/hostd checks it.
//
// Called on the service's loop thread only; never reads a clock (event time comes in the
// FrameContext), so a replay gives the same estimates bit for bit.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "cdro/checkpoint_layout.def"
#include "cdro/engine/engine.hpp"
#include "cdro/engine/movement.hpp"
#include "cdro/service/checkpoint.hpp"
#include "cdro/service/consumer.hpp"
#include "cdro/service/map_state.hpp"
#include "cdro/service/odometry.hpp"

namespace cdro::hostd {

// The tags are defined with every other in common/include/cdro/checkpoint_layout.def.
constexpr uint16_t kEngineExtensionTag = CDRO_CHECKPOINT_TAG_ENGINE;
constexpr uint16_t kMovementExtensionTag =
    CDRO_CHECKPOINT_TAG_MOVEMENT;                                    // the movement stage, when a robot is configured
constexpr uint16_t kFlightExtensionTag = CDRO_CHECKPOINT_TAG_FLIGHT; // the 3D tracks, with map.moving
// The output frame's offset, once a frame node moved (MapState::frame_offset; absent: none).
constexpr uint16_t kOutputFrameExtensionTag = CDRO_CHECKPOINT_TAG_OUTPUT_FRAME;

class EngineAdapter final : public service::FrameConsumer,
                            public service::MapSource,
                            public service::CheckpointProvider,
                            public service::OdometryConsumer {
public:
    // movement: the movement stage over the same engine when a robot is configured, else null.
    // moving: the nodes the engine tracks in 3D (Engine::trackMoving3D, done by the caller).
    explicit EngineAdapter(engine::Engine &engine, engine::MovementStage *movement = nullptr,
                           std::vector<uint16_t> moving = {});

    // OdometryConsumer: a step from the robot (UDP, MQTT, or a capture's odometry records), ending
    // at message.t_s (the frames' clock); ignored without a movement stage.
    void onOdometry(const service::OdometryMessage &message) override;

    // FrameConsumer
    void onRange(const cdro_range_t &range, const service::FrameContext &context) override;
    void onMotion(const cdro_motion_t &motion, const service::FrameContext &context) override;
    // Host events (consumer.hpp): with Engine::SolveAdoption::ByCaller, live, the global solve's
    // map is adopted after the first frame that finds its worker done, and the event says so
    // ('S' and the engine's ranges taken when that solve started, u64 little endian); a replay
    // adopts it after the same frame. An event that does not fit the replay (no solve pending, or
    // another one: another engine or settings, a lost record) is warned about and counted, and
    // skipped where it cannot be taken.
    std::vector<uint8_t> hostEventAfterFrame(const service::FrameContext &context) override;
    void onHostEvent(const uint8_t *data, size_t len, const service::FrameContext &context) override;

    // MapSource
    uint64_t revision() const override { return movement_ != nullptr ? movement_->revision() : engine_.revision(); }
    void fill(service::MapState &map) const override;
    // Converts only the nodes whose engine output changed since the last call (the outputs of a
    // frame cost what it changed, not the size of the map): of the static map, those the engine
    // names (Engine::takeOutputChanges); otherwise (a robot's stage, 3D tracks, or the engine says
    // "all") every node is converted and compared.
    void updateEstimates(service::MapState &map, std::vector<size_t> &changed) override;
    std::optional<service::NodeComponents> components(uint16_t id) const override;

    // CheckpointProvider
    service::SogSnapshot snapshot() override;
    void restore(const service::SogSnapshot &snapshot) override;
    // The nodes tracked in 3D whose tracks the checkpoint held (started ones).
    std::vector<uint16_t> restoredNodes() const override;

    uint64_t rangesRefused() const { return ranges_refused_; }
    // Host events of a replay that did not fit it (unknown, or no solve pending to adopt, or
    // another range count): the replay diverges from the live run there.
    uint64_t hostEventsMismatched() const { return host_events_mismatched_; }
    int64_t lastEventUnixUs() const { return last_event_unix_us_; }
    // Updates (updateEstimates) that converted only the nodes the engine named.
    uint64_t updatesOfNamedNodes() const { return updates_of_named_nodes_; }

private:
    // The static map's nodes the outputs show, by id; shown_index (if given): for each position of
    // the engine's estimates(), its position among them, or kNotShown.
    std::vector<engine::NodeOutput> shownNodes(std::vector<uint32_t> *shown_index) const;
    // updateEstimates with the positions the engine named; false where it cannot (then nothing changed).
    bool updateNamed(service::MapState &map, const std::vector<uint32_t> &positions, std::vector<size_t> &changed);
    void fillNodes(std::vector<service::NodeEstimate> &nodes, const std::vector<engine::NodeOutput> &shown) const;
    void fillRobot(std::optional<service::RobotPose> &robot_pose) const;

    engine::Engine &engine_;
    engine::MovementStage *movement_ = nullptr;
    std::vector<uint16_t> moving_; // tracked in 3D
    uint64_t ranges_refused_ = 0;
    uint64_t host_events_mismatched_ = 0;
    int64_t last_event_unix_us_ = 0;
    std::vector<engine::NodeOutput> last_shown_; // shownNodes() at the last updateEstimates
    static constexpr uint32_t kNotShown = UINT32_MAX;
    std::vector<uint32_t> shown_index_; // estimates() position -> position in last_shown_
    uint64_t updates_of_named_nodes_ = 0;
};

// The conversions, usable on their own (tests, tools).
service::SogSnapshot snapshotOf(const engine::Engine &engine, int64_t created_unix_us);
void restoreFrom(engine::Engine &engine, const service::SogSnapshot &snapshot); // throws CheckpointError
// The movement stage's block (tag kMovementExtensionTag): its whole state, doubles exactly. A
// checkpoint without it (written with no robot) leaves the stage as it is, a fresh start; one of
// another robot is refused (CheckpointError).
std::vector<uint8_t> movementBlockOf(const engine::MovementStage &movement);
void restoreMovement(engine::MovementStage &movement, const service::SogSnapshot &snapshot);
// The 3D tracks' block (tag kFlightExtensionTag): their whole state, doubles exactly.
std::vector<uint8_t> flightBlockOf(const engine::Engine &engine);
// Restores the tracks of the nodes of `moving` (tracked in the engine already) that the
// checkpoint holds; returns a warning for each mismatch, naming the nodes: no block (the tracks
// restart), tracks of nodes not in `moving` (dropped), nodes of `moving` without a track (they
// restart), other rigid bodies (the configured ones apply), other anchors than the fixed nodes
// of known height given now (the checkpoint's are kept). A damaged block, or one whose state
// does not fit together, is refused (CheckpointError).
std::vector<std::string> restoreFlight(engine::Engine &engine, const std::vector<uint16_t> &moving,
                                       const service::SogSnapshot &snapshot);

} // namespace cdro::hostd
