#include "cdro/engine/odometry_model.hpp"

#include <cmath>

namespace cdro::engine {

namespace {
constexpr double kPi = 3.14159265358979323846;
} // namespace

double wrapAngle(double angle_rad)
{
    double wrapped = std::fmod(angle_rad + kPi, 2.0 * kPi);
    if (wrapped <= 0.0) {
        wrapped += 2.0 * kPi;
    }
    return wrapped - kPi;
}

OdometryPrediction predictOdometry(const Pose2 &pose, const OdometryStep &step)
{
    OdometryPrediction prediction;
    const double middle = pose.heading_rad + 0.5 * step.dheading_rad;
    const double c = std::cos(middle);
    const double s = std::sin(middle);
    prediction.pose.x_m = pose.x_m + step.distance_m * c;
    prediction.pose.y_m = pose.y_m + step.distance_m * s;
    prediction.pose.heading_rad = wrapAngle(pose.heading_rad + step.dheading_rad);
    prediction.jacobian_pose(0, 2) = -step.distance_m * s;
    prediction.jacobian_pose(1, 2) = step.distance_m * c;
    prediction.jacobian_step << c, -0.5 * step.distance_m * s, s, 0.5 * step.distance_m * c, 0.0, 1.0;
    return prediction;
}

} // namespace cdro::engine
