// motion_track.hpp: the estimate of a node while it moves: a constant-velocity EKF over
// (x, y, vx, vy), each range to a static neighbour used at its own time.
//
// The SoG resets of the paper's Fig. 4 place a moving node from the neighbours' latest ranges,
// but a node carried at walking pace has moved by the time the last of them arrives (each link
// is ranged every few hundred ms). Predicting with a velocity and updating with one range at a
// time removes that lag. Process noise: white acceleration of std accel_sigma (m/s^2):
//     Q = q [dt^3/3 I, dt^2/2 I; dt^2/2 I, dt I],  q = accel_sigma^2.
// Range update: h = |p - a| (range_model.hpp), H = [u^T, 0 0].
#pragma once

#include <Eigen/Core>

#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

class MotionTrack {
public:
    MotionTrack() = default;
    MotionTrack(const Vector2 &position_m, double position_sigma_m, double speed_sigma_mps);

    // Predicts to time t_s (s); the first call only sets the time.
    void predict(double t_s, double accel_sigma_mps2);
    // Returns whether the range was used (false: refused as an outlier, or singular).
    bool updateRange(const Vector2 &anchor_m, const Matrix2 &anchor_covariance_m2, double range_m, double sigma_m,
                     const RangeLikelihood &likelihood, double gate_sigma);
    // Caps the speed (m/s): noisy ranges must not fling the track away.
    void limitSpeed(double max_speed_mps);

    Vector2 position() const { return Vector2(state_(0), state_(1)); }
    // Where the track puts the node at t_s (s), by its velocity (no update).
    Vector2 positionAt(double t_s) const
    {
        const double dt = timed_ && t_s > t_s_ ? t_s - t_s_ : 0.0;
        return position() + dt * velocity();
    }
    // The node has stopped: its velocity is known to be zero from now on.
    void stop()
    {
        state_(2) = state_(3) = 0.0;
        covariance_.block<2, 2>(2, 2) = Eigen::Matrix2d::Identity() * 1e-4;
        covariance_.block<2, 2>(0, 2).setZero();
        covariance_.block<2, 2>(2, 0).setZero();
    }
    Vector2 velocity() const { return Vector2(state_(2), state_(3)); }
    Matrix2 positionCovariance() const { return covariance_.topLeftCorner<2, 2>(); }
    uint32_t updates() const { return updates_; }
    bool timed() const { return timed_; }

private:
    Eigen::Vector4d state_ = Eigen::Vector4d::Zero();
    Eigen::Matrix4d covariance_ = Eigen::Matrix4d::Identity();
    double t_s_ = 0.0;
    bool timed_ = false;
    uint32_t updates_ = 0;
};

} // namespace cdro::engine
