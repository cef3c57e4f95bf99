// movement.hpp: the movement stage (paper section II-C; docs/engine.md "Stage 2").
//
// The robot's own tag is a node with odometry. While the robot stands still it is an ordinary
// node of the initialization stage (engine.hpp). Once it moves:
//
//   * the EKF of robot_filter.hpp takes over: robot pose, range scale and offset, and the nodes
//     that have converged (seeded from their merged means and covariances); robot-node and
//     node-node ranges update it; those nodes are pinned in the initialization stage (anchors
//     at the EKF's positions), which keeps handling the nodes that have not converged yet
//     (their SoGs) and the nodes that move (Fig. 4);
//   * if the initialization stage had a map, its frame is kept: the robot's position is its
//     estimate there, and its unknown heading is a bank of hypotheses (as PX4's EKF-GSF does
//     for yaw), weighted by their range innovations until one wins;
//   * without a map (a robot ranging to beacons that never range to each other, the Plaza
//     case) the frame is the odometry's own (the robot starts at 0, 0, heading 0) and every
//     beacon is first a ring SoG around the robot (the conventional SoG RO-SLAM path, as in
//     MRPT), updated by the robot's ranges as it moves, and enters the EKF once its SoG has
//     become one concentrated mode.
//
// A node reported moving (MOTION) leaves the EKF (it is marginalised) and is tracked by the
// initialization stage; when it has stopped and converged again, it rejoins.
//
// Time: every input carries its time (s); inputs must come in time order (the offline mode
// sorts them). No clock is read.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <optional>
#include <vector>

#include "cdro/engine/engine.hpp"
#include "cdro/engine/ring_sog.hpp"
#include "cdro/engine/robot_filter.hpp"

namespace cdro::engine {

struct MovementParams {
    NodeId robot_id = 0;                   // the node carried by the robot; 0 = no robot
    RobotFilterNoise odometry;             // odometry and calibration drift noise
    double range_sigma_m = 0.0;            // m, noise of the ranges in the EKF; 0 = adaptive: from the
                                           // spread of the robot's range innovations (robust, over the
                                           // last adaptive_window of them), never below the engine's
                                           // range.sigma_m, starting from adaptive_initial_sigma_m
    double adaptive_initial_sigma_m = 1.0; // m
    uint32_t adaptive_window = 60;         // innovations
    bool estimate_scale = true;            // range scale s in the state
    double scale_sigma = 0.1;              // prior std of s around 1
    bool estimate_offset = true;           // range offset b in the state
    double offset_sigma_m = 0.3;           // m, prior std of b around 0
    double gate_sigma = 5.0;               // innovations beyond this many std (and NLOS-looking) are refused
    double motion_start_m = 0.05;          // m travelled before the robot counts as moving
    uint32_t heading_hypotheses = 24;      // the heading bank (with a map to start from); 15 deg apart:
                                           // at 30 deg (12) the corridor path was 0.8 m off while undecided
    double heading_collapse_weight = 0.99; // one hypothesis with this weight wins
    double heading_prune_weight = 1e-4;    // hypotheses below this weight are dropped
    double heading_merge_m = 0.3;          // m, hypotheses this close ...
    double heading_merge_rad = 0.05;       // rad, ... and this aligned are merged
    // Beacons first seen by the robot alone (a SoG around the robot):
    double beacon_arc_spacing_m = 1.0; // m between the ring's means
    uint32_t beacon_min_components = 36;
    double beacon_prune_ratio = 1e-3;   // components below this fraction of the best are dropped
    uint32_t beacon_min_ranges = 10;    // ranges before it may enter the EKF ...
    double beacon_insert_std_m = 1.5;   // ... and its SoG's largest std must be below this (m)
    double beacon_min_baseline_m = 3.0; // m, and the robot must have ranged it from places this far apart
    // A link whose recent innovations sit persistently off (an NLOS link reads long wherever the
    // robot is) is left out of the EKF until they come back: its median innovation over the
    // last nlos_window ranges beyond max(nlos_min_m, nlos_sigmas x the noise).
    uint32_t nlos_window = 20; // ranges per link
    double nlos_min_m = 0.3;   // m
    double nlos_sigmas = 3.0;
};

// The frame a robot pose is in. Before the robot moves and while no node is placed, its pose is
// dead reckoning from where it started (Odometry); the EKF keeps that frame when no map appears
// before the robot moves (beacons that never range each other). Once stage 1 has placed nodes,
// the pose is in the map's frame (Map); a run whose map appears while the robot stands switches
// from Odometry to Map, and the poses before the switch are not comparable with those after it.
enum class RobotFrame : uint8_t { Odometry, Map };
const char *robotFrameName(RobotFrame frame);

struct RobotOutput {
    NodeId id = 0;
    double t_s = 0.0;                                     // s, time of the last input
    Pose2 pose;                                           // output frame
    Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero(); // (m^2, m^2 rad, rad^2)
    bool localized = false;                               // the EKF runs (false: dead reckoning before it starts)
    bool placed = false;                                  // has a position: the EKF runs, or the initialization
                                                          // placed the robot's node while it stood (and it is not
                                                          // ambiguous), or no map exists (dead reckoning, Odometry)
    RobotFrame frame = RobotFrame::Odometry;              // the frame `pose` is in (see RobotFrame)
    uint32_t hypotheses = 0;                              // heading hypotheses alive (1 once decided)
    double range_scale = 1.0;
    double range_scale_sigma = 0.0;
    double range_offset_m = 0.0;       // m
    double range_offset_sigma_m = 0.0; // m
};

struct MovementCounters {
    uint64_t odometry_steps = 0;
    uint64_t robot_ranges = 0;
    uint64_t ekf_updates = 0;
    uint64_t ekf_gated = 0;
    uint64_t nodes_inserted = 0;
    uint64_t nodes_removed = 0; // moving nodes taken out of the EKF
    uint64_t beacon_sogs = 0;   // beacons started as a SoG around the robot
    uint64_t hypotheses_pruned = 0;
    uint64_t nlos_link_ranges_skipped = 0; // ranges on links that read long persistently (not used)
};

class MovementStage {
public:
    MovementStage(Engine &engine, const MovementParams &params);

    void addOdometry(double t_s, const OdometryStep &step);
    RangeVerdict addRange(NodeId from, NodeId to, double range_m, double t_s);
    void setMoving(NodeId id, bool moving, double t_s);

    std::optional<RobotOutput> robot() const;
    void setTrace(std::function<void(const std::string &)> sink) { trace_ = std::move(sink); }
    // Every node, output frame: the EKF's estimate where it holds the node, else the
    // initialization stage's (or a beacon SoG's merged estimate).
    std::vector<NodeOutput> estimates() const;
    const MovementCounters &counters() const { return counters_; }
    const MovementParams &params() const { return params_; }
    bool started() const { return started_; }
    double rangeSigmaInUse() const { return rangeSigma(); } // m
    uint64_t revision() const { return revision_ + engine_.revision(); }

    // A node ranged from the robot before the EKF holds it: a ring (ring_sog.hpp) around the
    // robot's first pose, narrowed by the ranges from the places the robot and the map's nodes
    // ranged it from.
    struct BeaconSog {
        RingSog ring; // absolute means (RingSog::setAbsoluteComponents), weights without a floor
        uint32_t ranges = 0;
        Vector2 first_robot_m = Vector2::Zero(); // m, the robot when the ring started
        double baseline_m = 0.0;                 // m, farthest place it was ranged from (robot or map node) from there
    };
    struct Hypothesis {
        RobotFilter filter;
        double log_weight = 0.0;
    };
    struct LinkWatch {
        std::vector<double> innovations_m; // recent innovations of this link, a ring
        size_t next = 0;
        bool excluded = false;
    };
    // Everything the stage holds, for checkpoints: restore() it into a stage made with the same
    // parameters, over an engine restored from the same checkpoint, and the two go on as one.
    struct Saved {
        bool started = false;
        bool own_frame = false;
        bool waiting_for_fix = false;
        double moved_m = 0.0;  // m
        double last_t_s = 0.0; // s
        bool have_time = false;
        Pose2 dead_reckoning;
        std::vector<Hypothesis> hypotheses;
        std::map<NodeId, BeaconSog> beacons;
        std::map<NodeId, bool> moving;
        std::map<std::pair<NodeId, NodeId>, LinkWatch> links;
        std::vector<double> innovations_m;      // m, a ring
        std::vector<double> prior_variances_m2; // m^2
        size_t innovation_next = 0;
        std::optional<double> adaptive_sigma_m; // m
        MovementCounters counters;
        uint64_t revision = 0;
    };
    Saved saved() const;
    void restore(const Saved &saved);

private:
    void start(double t_s);
    // Converged (or fixed) nodes the robot's tag has links to.
    size_t convergedNeighbours() const;
    void insertConvergedNodes();
    bool insertNode(NodeId id);
    // A range to a node that has a SoG (or gets one: only a range from the robot starts a ring)
    // from a known centre, the robot's or a map node's; the node enters the EKF once its SoG has
    // one concentrated mode.
    void updateBeacon(NodeId id, const Vector2 &centre_m, const Matrix2 &centre_covariance_m2, bool from_robot,
                      double range_m, double height_difference_m);
    void updateBeaconSog(NodeId id, BeaconSog &sog, const Vector2 &centre_m, const Matrix2 &centre_covariance_m2,
                         bool from_robot, double range_m, double height_difference_m);
    void pinNodes();
    double heightDifference(NodeId a, NodeId b) const;
    double rangeSigma() const;
    void learnNoise(const RangeUpdateOutcome &outcome, double sigma_m);
    const RobotFilter &best() const;
    RobotFilter &best();
    void normaliseHypotheses();

    Engine &engine_;
    MovementParams params_;
    RangeLikelihood likelihood_;
    bool started_ = false;
    bool own_frame_ = false;       // the odometry frame (no map to start from)
    bool waiting_for_fix_ = false; // a map exists but the robot is not placed in it yet
    double moved_m_ = 0.0;
    double last_t_s_ = 0.0;
    bool have_time_ = false;
    Pose2 dead_reckoning_; // before the EKF starts (odometry frame)
    std::vector<Hypothesis> hypotheses_;
    std::map<NodeId, BeaconSog> beacons_;
    std::map<NodeId, bool> moving_;
    bool linkExcluded(NodeId a, NodeId b, double innovation_m);
    std::map<std::pair<NodeId, NodeId>, LinkWatch> links_;
    std::vector<double> innovations_m_;      // recent robot-range innovations (m), a ring
    std::vector<double> prior_variances_m2_; // their predicted variances without the noise (m^2)
    size_t innovation_next_ = 0;
    std::optional<double> adaptive_sigma_m_; // m, once learned (0 when the state explains the spread)
    MovementCounters counters_;
    uint64_t revision_ = 0;
    std::function<void(const std::string &)> trace_;
    void trace(const std::string &message) const
    {
        if (trace_) {
            trace_(message);
        }
    }
};

} // namespace cdro::engine
