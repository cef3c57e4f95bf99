// A small robot world for the movement stage's tests (engine and checkpoint suites): a robot
// with noisy odometry (2 % of each step, 3 mrad a step, a 5 mrad/s heading drift) driving among
// nodes at known heights, ranging one of them per 0.1 s tick (0.1 m noise, scale 1.03), the
// nodes ranging each other round robin over their links, one node optionally carried with
// motion reports. Seeded (support.hpp's Random): the same seed gives the same world everywhere.
#pragma once

#include <cstdint>
#include <limits>
#include <optional>
#include <utility>
#include <vector>

#include "cdro/engine/odometry_model.hpp"
#include "support.hpp"

namespace cdro::enginetest {

using engine::OdometryStep;
using engine::Pose2;

constexpr double kPi = 3.14159265358979323846;
constexpr double kTickS = 0.1; // s, odometry at 10 Hz

// One piece of the robot's drive: this long at this speed and turn rate.
struct Segment {
    double duration_s = 0.0;
    double speed_mps = 0.0;
    double turn_rate_rad_s = 0.0;
};

// A node carried from where it stands to `to_m` between start_s and stop_s (straight, at
// constant speed), with motion reports at both ends.
struct Carry {
    NodeId id = 0;
    double start_s = 0.0;
    double stop_s = 0.0;
    Vector2 to_m = Vector2::Zero();
};

struct WorldSpec {
    NodeId robot_id = 100;
    double robot_height_m = 0.4;
    Pose2 robot_start;
    std::vector<Segment> drive; // after standing
    double stand_s = 5.0;       // s standing still (zero odometry steps) before the drive
    double end_stand_s = 0.0;   // s standing after it
    std::vector<NodeId> ids;
    std::vector<Vector2> truth_m; // where the nodes stand at first
    std::vector<double> height_m;
    std::vector<std::pair<size_t, size_t>> links; // node pairs that range each other
    double robot_max_range_m = std::numeric_limits<double>::infinity();
    std::optional<Carry> carry;
    double range_noise_m = 0.1;
    double range_scale = 1.03;
    double distance_noise_fraction = 0.02;
    double heading_noise_rad = 0.003;   // per step
    double heading_drift_rad_s = 0.005; // a gyro bias (plaza2's odometry drifts 5.4e-3 rad/s)
};

struct Event {
    enum class Kind { Odometry, Range, Motion };
    Kind kind = Kind::Odometry;
    double t_s = 0.0;
    OdometryStep step;
    NodeId from = 0;
    NodeId to = 0;
    double range_m = 0.0;
    NodeId id = 0;
    bool moving = false;
};

struct World {
    WorldSpec spec;
    std::vector<Event> events;          // in time order
    std::vector<Pose2> robot_truth;     // after each odometry event
    std::vector<Pose2> dead_reckoning;  // the odometry integrated, from the true start
    std::vector<Vector2> final_truth_m; // where the nodes are at the end
};

// Where node `node` (index into spec.ids) stands at t_s (s).
Vector2 nodeAt(const WorldSpec &spec, size_t node, double t_s);
// Per 0.1 s tick: the odometry step (ending at t), then one robot range (round robin over the
// nodes in its range) and one node-node range (round robin over the links).
World simulate(const WorldSpec &spec, uint64_t seed);

} // namespace cdro::enginetest
