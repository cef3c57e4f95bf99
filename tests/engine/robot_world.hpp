// The robot world of the movement stage's tests under the names the hostd checkpoint suite
// (tests/hostd/test_checkpoint.cpp) uses: the world itself is netgen's
// (cdro/netgen/robot_world.hpp), which the engine suites use directly.
#pragma once

#include "cdro/engine/odometry_model.hpp"
#include "cdro/netgen/robot_world.hpp"
#include "support.hpp"

namespace cdro::enginetest {

using engine::OdometryStep;
using engine::Pose2;

constexpr double kPi = 3.14159265358979323846;
constexpr double kTickS = netgen::kOdometryTickS; // s

using Segment = netgen::DriveSegment;
using Carry = netgen::Carry;
using WorldSpec = netgen::RobotWorldSpec;
using Event = netgen::RobotEvent;
using World = netgen::RobotWorld;

inline World simulate(const WorldSpec &spec, uint64_t seed) { return netgen::simulateRobot(spec, seed); }

} // namespace cdro::enginetest
