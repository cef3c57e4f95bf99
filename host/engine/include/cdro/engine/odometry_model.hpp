// odometry_model.hpp: the robot's motion model, one odometry step at a time, in the Plaza
// convention (Djugash et al.): a step of travelled distance d and heading change dh advances
// along the mid-point heading,
//
//     x' = x + d cos(theta + dh/2),   y' = y + d sin(theta + dh/2),   theta' = theta + dh.
//
// Jacobian with respect to the pose (x, y, theta):
//     F = [1 0 -d sin(theta + dh/2);  0 1 d cos(theta + dh/2);  0 0 1]
// and with respect to the step (d, dh), for the process noise:
//     G = [cos(m) -d/2 sin(m);  sin(m) d/2 cos(m);  0 1],   m = theta + dh/2.
// Velocities (v, omega over dt) are the same step with d = v dt, dh = omega dt.
// Tested against numerical derivatives (tests/engine).
#pragma once

#include <Eigen/Core>

namespace cdro::engine {

struct Pose2 {
    double x_m = 0.0;
    double y_m = 0.0;
    double heading_rad = 0.0; // counter-clockwise from +x
};

struct OdometryStep {
    double distance_m = 0.0;   // m travelled (negative when reversing)
    double dheading_rad = 0.0; // rad
};

struct OdometryPrediction {
    Pose2 pose;
    Eigen::Matrix3d jacobian_pose = Eigen::Matrix3d::Identity();                     // dpose'/dpose
    Eigen::Matrix<double, 3, 2> jacobian_step = Eigen::Matrix<double, 3, 2>::Zero(); // dpose'/d(d, dh)
};

OdometryPrediction predictOdometry(const Pose2 &pose, const OdometryStep &step);

// Wraps an angle to (-pi, pi].
double wrapAngle(double angle_rad);

} // namespace cdro::engine
