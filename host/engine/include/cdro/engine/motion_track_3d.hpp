// motion_track_3d.hpp: nodes that never stop, tracked in 3D (docs/engine.md,
// "Nodes that never stop: 3D tracks").
//
// A node declared moving from the start whose height is not known (a tag on a drone, a person)
// is not part of the static map: its ranges go to one joint EKF over every such node, state
// (x, y, z, vx, vy, vz) per node (m, m/s, in the fixed nodes' frame), cross-covariances kept:
//   - ranges to static anchors are 3D ranges to the fixed nodes of known height (x, y from
//     Engine::setFixed, z from Engine::setHeight); a range to any other static node is not used
//     (counted: no_anchor);
//   - a range between two tracked nodes updates both (one scalar update of the joint state: both
//     ends move with the correlation it creates), once both have started; before, it waits;
//   - motion: each velocity component an Ornstein-Uhlenbeck process (stationary sigma
//     MotionParams::flight_speed_sigma_mps, correlation time flight_speed_tau_s; exact
//     discretisation): a node that never stops, whose speed stays bounded, and whose position is a
//     random walk over long gaps (a constant-velocity model's dt^3 growth made the first Python
//     EKFs on MiLUV worse than the room centre: docs/results.md);
//   - each range is one scalar update (Joseph form) with range.sigma_m plus the range's curvature
//     under the state's spread (the Gaussian second-order filter's |P_perp|_F^2 / 2 d^2): a state
//     metres off is not made confident by one range linearised at the wrong point;
//   - outliers: the engine's one-sided NLOS likelihood (range_likelihood.hpp) widens a range's
//     noise by 1 / P(line of sight) (as the 2D track, motion_track.hpp); a range beyond
//     sog.gate_sigma with P(line of sight) < 1 % is refused; after kResetAfterRefused refused in a
//     row the node's covariance is the starting one again (its correlations dropped) and the range
//     is used: a track that is off cannot lock itself out;
//   - the room: the nodes fly in the fixed anchors' horizontal bounding box grown by kRoomMarginM,
//     between MotionParams::flight_floor_z_m and the anchors' mean height. Anchors on walls and
//     ceilings are nearly coplanar, and the mirror image of a node through their plane fits its
//     ranges about as well: a state above their mean height is mirrored through it (z, vz and
//     their covariance), then, per axis, the state's Gaussian is truncated to the room (the
//     truncated mean and variance, the rest of the state moved with it through the covariance);
//   - one body (optional, addBody): two tracked nodes carried by one rigid body at a known
//     separation (a drone's two tags, its lever arms known): after each prediction, once both have
//     started, the pseudo-measurement p_a - p_b = 0 with covariance (separation^2 / 3) I (the
//     spread of a vector of that length in a uniform direction), so that each node's ranges move
//     the other. Applied at every prediction, its noise is scaled up by flight_speed_tau_s / dt
//     (when dt is shorter): what it teaches per second does not grow with the ranging rate (at
//     full weight every 0.1 s it pulled the two nodes onto one point). Its mean difference is 0,
//     not the turned lever arm (the yaw is not estimated): a bias of up to half the separation;
//     the nodes' 95 % regions hold a little less often with it (MiLUV: docs/results.md);
//   - start: at a node's first range to an anchor, from the room as a prior (its centre, sigma
//     half its size per axis, velocity 0 with the stationary sigma). Its estimate is reported
//     (FlightStatus::Tracking) once it has heard kMinAnchors distinct anchors.
// This is the Python baseline (c-ref) (tools/cdro_tools/evaluation/tracking_baselines.py) in the
// engine, with the engine's NLOS likelihood in place of its Huber weights. Deterministic: no
// clock, no randomness; nodes are kept in the order they were declared. The whole state can be
// taken out (saved()) and put back (restore()): a restored copy continues bit for bit as the
// original would (checkpoints: cdro-hostd's flight block, checkpoint_layout.def).
#pragma once

#include <cstdint>
#include <stdexcept>
#include <optional>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "cdro/engine/params.hpp"
#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

// Where a tracked node is in its life.
enum class FlightStatus : uint8_t {
    Waiting,  // declared, no range to an anchor yet
    Starting, // tracked, fewer than kMinAnchors distinct anchors heard: not reported yet
    Tracking, // reported
};

// What became of one range of a tracked node.
enum class FlightRangeUse : uint8_t {
    Used,     // taken (maybe down-weighted as NLOS-looking)
    Refused,  // beyond the gate, looking NLOS: not used
    Reset,    // the last of kResetAfterRefused refused in a row: the node's covariance reset, the range used
    Waiting,  // tag to tag with an end not started yet: not used
    NoAnchor, // the other end is static but not a fixed node of known height: not used
};

struct FlightEstimate {
    NodeId id = 0;
    FlightStatus status = FlightStatus::Waiting;
    Vector3 position_m = Vector3::Zero();    // m
    Vector3 velocity_mps = Vector3::Zero();  // m/s
    Matrix3 covariance_m2 = Matrix3::Zero(); // m^2, of the position
    uint32_t anchors_heard = 0;              // distinct anchors it has ranged
};

struct FlightCounters {
    uint64_t anchor_ranges = 0; // ranges to anchors taken (Used or Reset)
    uint64_t tag_ranges = 0;    // ranges between tracked nodes taken
    uint64_t down_weighted = 0; // ... of those taken, with P(line of sight) < 0.5
    uint64_t refused = 0;
    uint64_t resets = 0;
    uint64_t waiting = 0;
    uint64_t no_anchor = 0;
    uint64_t mirrored = 0;     // states brought below the anchors' mean height
    uint64_t truncated = 0;    // updates after which the room changed the state
    uint64_t body_updates = 0; // one-body pseudo-measurements applied
};

// What the NLOS likelihood did to the ranges of one link kind: the ranges to one anchor, or all
// the ranges between tracked nodes (anchor = 0). A range counts once, when it is decided.
struct FlightNlosCount {
    NodeId anchor = 0;          // the anchor's id; 0: the ranges between tracked nodes
    uint64_t taken = 0;         // Used or Reset
    uint64_t down_weighted = 0; // ... of those taken, with P(line of sight) < 0.5 (noise widened)
    uint64_t refused = 0;       // beyond the gate, looking NLOS: not used
};

class FlightTracks {
public:
    static constexpr uint32_t kMinAnchors = 4;        // distinct anchors before a node is reported (a 3D fix's need)
    static constexpr uint32_t kResetAfterRefused = 4; // refused anchor ranges in a row that reset a node
    static constexpr double kRoomMarginM = 1.0;       // m, the room: the anchors' box grown by this
    static constexpr double kTruncationSigmas = 6.0;  // a room bound farther than this is not applied

    FlightTracks(const MotionParams &motion, double range_sigma_m, double gate_sigma,
                 const RangeLikelihood &likelihood);

    // A node tracked in 3D from now on (before its first range; twice is once).
    void add(NodeId id);
    bool tracks(NodeId id) const { return find(id) != kNone; }
    bool empty() const { return ids_.empty(); }
    std::vector<NodeId> nodes() const { return ids_; }
    // Two tracked nodes on one rigid body, separation_m (m, > 0) apart; throws
    // std::invalid_argument for a node not tracked, one already on a body, or a bad separation.
    void addBody(NodeId a, NodeId b, double separation_m);

    // The static anchors (id, 3D position, m), once, before the first range; the room follows.
    void setAnchors(const std::vector<std::pair<NodeId, Vector3>> &anchors);
    bool anchorsSet() const { return anchors_set_ == AnchorsState::Set; }

    // One range (m) at t_s (s, finite) between a and b; at least one of them is tracked.
    FlightRangeUse addRange(NodeId a, NodeId b, double range_m, double t_s);

    std::optional<FlightEstimate> estimate(NodeId id) const;
    const FlightCounters &counters() const { return counters_; }
    // Per anchor (in setAnchors' order), then the ranges between tracked nodes: the NLOS model's
    // verdicts (docs/engine.md, "Nodes that never stop"). Ranges not decided (Waiting, NoAnchor)
    // are not in it.
    const std::vector<FlightNlosCount> &nlosCounts() const { return nlos_; }

    // The whole state, for checkpoints: what the declarations (add, addBody) and the ranges made.
    // The room is not in it: setAnchors() derives it from the anchors and the motion parameters.
    struct SavedNode {
        NodeId id = 0;
        FlightStatus status = FlightStatus::Waiting;
        std::vector<NodeId> heard; // distinct anchors, in the order heard
        uint32_t refused_in_a_row = 0;
    };
    struct SavedBody {
        NodeId a = 0;
        NodeId b = 0;
        double separation_m = 0.0; // m
    };
    struct Saved {
        std::vector<SavedNode> nodes; // in the order declared
        std::vector<SavedBody> bodies;
        bool anchors_set = false;
        std::vector<std::pair<NodeId, Vector3>> anchors; // m
        std::vector<FlightNlosCount> nlos;               // as nlosCounts(): one per anchor, then tag to tag
        Eigen::VectorXd state;                           // 6 per node: x, y, z (m), vx, vy, vz (m/s)
        Eigen::MatrixXd covariance;                      // of state
        std::optional<double> t_s;                       // s, the filter's time
        FlightCounters counters;
    };
    // What restore() could not take as it was: saved nodes not declared here (dropped), declared
    // nodes not in the saved state (they start afresh, as on a first start), whether the saved
    // bodies differ from the declared ones (the declared ones are kept), and (Engine::
    // restoreFlights) whether the saved anchors differ from the fixed nodes of known height
    // given now (the saved ones are kept: the state is in their frame).
    struct RestoreReport {
        std::vector<NodeId> dropped;
        std::vector<NodeId> restarted;
        bool bodies_differ = false;
        bool anchors_differ = false;
    };
    Saved saved() const;
    // Replaces the state with `saved` for the nodes declared here (add) that it holds; declared
    // nodes it does not hold start afresh. Throws std::invalid_argument (naming what is wrong)
    // for a state that does not fit together (sizes, a status, an anchor heard that is none);
    // nothing is changed then.
    RestoreReport restore(const Saved &saved);

private:
    static constexpr uint32_t kNone = 0xFFFFFFFFU;
    enum class AnchorsState : uint8_t { Unset, Set };
    struct Node {
        NodeId id = 0;
        FlightStatus status = FlightStatus::Waiting;
        std::vector<NodeId> heard; // distinct anchors, in the order heard
        uint32_t refused_in_a_row = 0;
    };

    uint32_t find(NodeId id) const;
    const Vector3 *anchor(NodeId id) const;
    void predict(double t_s);
    void start(uint32_t node);
    // One scalar update; end_b is kNone for an anchor at anchor_m. force: not gated.
    FlightRangeUse update(uint32_t end_a, uint32_t end_b, const Vector3 &anchor_m, double range_m, bool force);
    void keepInside(uint32_t node);
    void applyBodies(double dt_s);
    struct Body {
        uint32_t a = 0;
        uint32_t b = 0;
        double separation_m = 0.0; // m
    };
    std::vector<Body> bodies_;

    MotionParams motion_;
    double range_sigma_m_;
    double gate_sigma_;
    RangeLikelihood likelihood_;
    std::vector<NodeId> ids_;
    std::vector<Node> nodes_;
    std::vector<std::pair<NodeId, Vector3>> anchors_;
    AnchorsState anchors_set_ = AnchorsState::Unset;
    Vector3 room_lo_m_ = Vector3::Zero();
    Vector3 room_hi_m_ = Vector3::Zero();
    double plane_z_m_ = 0.0; // m, the anchors' mean height
    Eigen::VectorXd state_;  // 6 per node: x, y, z (m), vx, vy, vz (m/s)
    Eigen::MatrixXd covariance_;
    std::optional<double> t_s_; // s, the filter's time
    FlightCounters counters_;
    std::vector<FlightNlosCount> nlos_; // one per anchor, then the tag-to-tag entry
    void countNlos(size_t entry, FlightRangeUse use, uint64_t down_weighted_before);
};

} // namespace cdro::engine
