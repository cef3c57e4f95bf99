// robot_world.hpp: a robot with wheel odometry driving among UWB nodes at known heights, for the
// movement stage (docs/engine.md, "Stage 2"): the one robot world of the tests (the engine's
// movement stage, the service's checkpoints), and the one a benchmark or tool of the moving robot
// is to draw from, as world.hpp is the one deployment of fixed nodes.
//
// Time advances in odometry ticks of kOdometryTickS. Per tick: the odometry step (ending at t),
// then robot_ranges_per_tick robot ranges (round robin over the nodes within robot_max_range_m,
// by t + 0.03 s) and one node-node range (round robin over the links, at t + 0.06 s). The truth integrates the drive with the engine's own
// odometry model (cdro/engine/odometry_model.hpp, the Plaza convention), so that a step means to
// the world what it means to the engine; the reported step errs by distance_noise_fraction of its
// length (a wheel's slip), heading_noise_rad per step and a heading drift (a gyro bias); a
// standing robot's wheels report exactly nothing. A range of true 3D distance d reads
//     r = range_scale d + n,   n ~ N(0, range_noise_m^2)
// (UWB ranges read a few per cent long in a building). One node may be carried in a straight
// line at constant speed, with motion reports where it starts and stops. Seeded (random.hpp):
// the same seed gives the same world on every platform.
#pragma once

#include <cstdint>
#include <limits>
#include <optional>
#include <utility>
#include <vector>

#include "cdro/engine/odometry_model.hpp"
#include "cdro/netgen/world.hpp"

namespace cdro::netgen {

constexpr double kOdometryTickS = 0.1; // s, odometry at 10 Hz

// One piece of the robot's drive: this long at this speed and turn rate.
struct DriveSegment {
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

struct RobotWorldSpec {
    NodeId robot_id = 100;
    double robot_height_m = 0.4;
    engine::Pose2 robot_start;
    std::vector<DriveSegment> drive; // after standing
    double stand_s = 5.0;            // s standing still (zero odometry steps) before the drive
    double end_stand_s = 0.0;        // s standing after it
    std::vector<uint16_t> ids;
    std::vector<Vector2> truth_m;                 // m, where the nodes stand at first
    std::vector<double> height_m;                 // m
    std::vector<std::pair<size_t, size_t>> links; // node pairs (indices into ids) that range each other
    double robot_max_range_m = std::numeric_limits<double>::infinity(); // m, planar
    size_t robot_ranges_per_tick = 1;
    std::optional<Carry> carry;
    double range_noise_m = 0.1; // m, standard deviation
    double range_scale = 1.03;
    double distance_noise_fraction = 0.02; // of each step's length, standard deviation
    double heading_noise_rad = 0.003;      // rad per step, standard deviation
    double heading_drift_rad_s = 0.005;    // rad/s, a gyro bias (plaza2's odometry drifts 5.4e-3 rad/s)
};

struct RobotEvent {
    enum class Kind { Odometry, Range, Motion };
    Kind kind = Kind::Odometry;
    double t_s = 0.0;
    engine::OdometryStep step; // Odometry: as the wheels report it
    NodeId from = 0;           // Range
    NodeId to = 0;
    double range_m = 0.0;
    NodeId id = 0; // Motion: the node, and whether it starts or stops moving
    bool moving = false;
};

struct RobotWorld {
    RobotWorldSpec spec;
    std::vector<RobotEvent> events;            // in time order
    std::vector<engine::Pose2> robot_truth;    // after each odometry event
    std::vector<engine::Pose2> dead_reckoning; // the reported odometry integrated, from the true start
    std::vector<Vector2> final_truth_m;        // m, where the nodes are at the end
};

// Where node `node` (an index into spec.ids) stands at t_s (m).
Vector2 nodePositionM(const RobotWorldSpec &spec, size_t node, double t_s);

// The world's events for this seed. A spec that cannot be simulated (lists of different lengths,
// a link or carried node that is not there, a carry that does not move forward in time, a
// negative duration or noise) throws std::invalid_argument saying what is wrong.
RobotWorld simulateRobot(const RobotWorldSpec &spec, uint64_t seed);

} // namespace cdro::netgen
