#include "cdro/engine/motion_track.hpp"

#include <algorithm>
#include <cmath>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

MotionTrack::MotionTrack(const Vector2 &position_m, double position_sigma_m, double speed_sigma_mps)
{
    state_ << position_m.x(), position_m.y(), 0.0, 0.0;
    covariance_.setZero();
    covariance_(0, 0) = covariance_(1, 1) = position_sigma_m * position_sigma_m;
    covariance_(2, 2) = covariance_(3, 3) = speed_sigma_mps * speed_sigma_mps;
}

void MotionTrack::predict(double t_s, double accel_sigma_mps2)
{
    if (!timed_) {
        t_s_ = t_s;
        timed_ = true;
        return;
    }
    const double dt = t_s - t_s_;
    if (!(dt > 0.0)) {
        return; // same time (or out of order): nothing to predict
    }
    t_s_ = t_s;
    Eigen::Matrix4d f = Eigen::Matrix4d::Identity();
    f(0, 2) = f(1, 3) = dt;
    state_ = f * state_;
    const double q = accel_sigma_mps2 * accel_sigma_mps2;
    Eigen::Matrix4d noise = Eigen::Matrix4d::Zero();
    noise(0, 0) = noise(1, 1) = q * dt * dt * dt / 3.0;
    noise(0, 2) = noise(2, 0) = noise(1, 3) = noise(3, 1) = q * dt * dt / 2.0;
    noise(2, 2) = noise(3, 3) = q * dt;
    covariance_ = f * covariance_ * f.transpose() + noise;
}

bool MotionTrack::updateRange(const Vector2 &anchor_m, const Matrix2 &anchor_covariance_m2, double range_m,
                              double sigma_m, const RangeLikelihood &likelihood, double gate_sigma)
{
    const RangePrediction prediction = predictRange(position(), anchor_m);
    if (prediction.singular) {
        return false;
    }
    Eigen::RowVector4d h = Eigen::RowVector4d::Zero();
    h(0) = prediction.jacobian_point(0);
    h(1) = prediction.jacobian_point(1);
    const double noise =
        sigma_m * sigma_m +
        (prediction.jacobian_point * anchor_covariance_m2 * prediction.jacobian_point.transpose()).value();
    const Eigen::Vector4d ph = covariance_ * h.transpose();
    const double variance = (h * ph).value() + noise;
    const double innovation = range_m - prediction.range_m;
    const double inlier = likelihood.inlierProbability(innovation, variance);
    if (innovation * innovation > gate_sigma * gate_sigma * variance && inlier < 0.01) {
        return false;
    }
    // NLOS-looking ranges count for less (their noise widened by 1 / P(line of sight)).
    const double widened = noise / std::max(inlier, 0.05);
    const double s = (h * ph).value() + widened;
    state_ += ph / s * innovation;
    covariance_ -= (ph / s) * ph.transpose();
    covariance_ = 0.5 * (covariance_ + covariance_.transpose());
    ++updates_;
    return true;
}

void MotionTrack::limitSpeed(double max_speed_mps)
{
    const double speed = velocity().norm();
    if (speed > max_speed_mps && speed > 0.0) {
        state_.segment<2>(2) *= max_speed_mps / speed;
    }
}

} // namespace cdro::engine
