// robot_filter.hpp: the movement stage's EKF (paper section II-C, "the standard odometry
// update and the EKF update"): one state with the robot's pose, the radios' range calibration
// and the positions of the nodes it has taken over,
//
//     [x, y, theta | s, b | x_1, y_1, ..., x_M, y_M]      (m, m, rad | 1, m | m ...)
//
// with a dense covariance (M is tens of nodes, not thousands). Odometry predicts the pose
// (odometry_model.hpp); each range, robot-node or node-node, is a sequential scalar update
// through range_model.hpp. Ranges are robust: the innovation's line-of-sight
// probability under the mixture of range_likelihood.hpp widens the measurement noise
// (R / w), and an innovation beyond the gate is refused and counted.
#pragma once

#include <cstdint>
#include <optional>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "cdro/engine/odometry_model.hpp"
#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

struct RobotFilterNoise {
    double distance_fraction = 0.05;            // sigma_d = fraction |d| + floor
    double distance_floor_m = 0.001;            // m per step
    double heading_fraction = 0.05;             // sigma_dh = fraction |dh| + floor + walk sqrt(dt)
    double heading_floor_rad = 0.0005;          // rad per step
    double heading_walk_rad_per_sqrt_s = 0.005; // rad/sqrt(s): a drifting gyro or wheel slip
    double scale_walk_per_sqrt_s = 0.0;         // 1/sqrt(s): slow drift of the range scale
    double offset_walk_m_per_sqrt_s = 0.0;      // m/sqrt(s)
};

struct RangeUpdateOutcome {
    bool used = false;
    bool gated = false;          // refused: beyond the gate
    double innovation_m = 0.0;   // m, measured - predicted
    double variance_m2 = 0.0;    // m^2, innovation variance (before robust widening)
    double log_likelihood = 0.0; // of the innovation (for hypothesis weights)
    double inlier_probability = 1.0;
};

class RobotFilter {
public:
    static constexpr size_t kMaxNodes = 120; // nodes the EKF takes at most (dense: O(n^2) per range)

    // Robot pose and its covariance; scale s and offset b with their prior standard deviations
    // (a zero std keeps that parameter fixed at its value).
    RobotFilter(const Pose2 &pose, const Eigen::Matrix3d &pose_covariance, double scale, double scale_sigma,
                double offset_m, double offset_sigma_m);

    void predict(const OdometryStep &step, double dt_s, const RobotFilterNoise &noise);

    // The map's frame may be the mirror image of the world (an anchor-free map is only defined
    // up to a reflection): then the robot's left turns are right turns in it.
    void setMirrored(bool mirrored) { mirrored_ = mirrored; }
    bool mirrored() const { return mirrored_; }

    bool hasNode(NodeId id) const { return slot_.count(id) != 0; }
    bool full() const { return order_.size() >= kMaxNodes; }
    // Returns false (and changes nothing) when the EKF is full.
    bool insertNode(NodeId id, const Vector2 &position_m, const Matrix2 &covariance_m2);
    void removeNode(NodeId id); // marginalises it out
    std::vector<NodeId> nodes() const { return order_; }

    // A range from the robot to a node in the state, and between two nodes in the state.
    // dz: height difference (m); sigma_m: line-of-sight noise.
    RangeUpdateOutcome updateRobotRange(NodeId node, double range_m, double height_difference_m, double sigma_m,
                                        double gate_sigma, const RangeLikelihood &likelihood);
    RangeUpdateOutcome updateNodeRange(NodeId a, NodeId b, double range_m, double height_difference_m, double sigma_m,
                                       double gate_sigma, const RangeLikelihood &likelihood);

    // The innovation (measured - predicted, m) a range would have, without using it.
    double robotRangeInnovation(NodeId node, double range_m, double height_difference_m) const;
    double nodeRangeInnovation(NodeId a, NodeId b, double range_m, double height_difference_m) const;

    Pose2 pose() const;
    Eigen::Matrix3d poseCovariance() const { return covariance_.topLeftCorner<3, 3>(); }
    double scale() const { return state_(3); }
    double offset() const { return state_(4); }
    double scaleSigma() const { return std::sqrt(std::max(covariance_(3, 3), 0.0)); }
    double offsetSigma() const { return std::sqrt(std::max(covariance_(4, 4), 0.0)); }
    Vector2 nodePosition(NodeId id) const;
    Matrix2 nodeCovariance(NodeId id) const;

    // The whole state, for checkpoints and tests.
    const Eigen::VectorXd &state() const { return state_; }
    const Eigen::MatrixXd &covariance() const { return covariance_; }
    bool scaleFixed() const { return scale_fixed_; }
    bool offsetFixed() const { return offset_fixed_; }
    // A filter with exactly this state (a checkpoint's): `nodes` in state order; the state has
    // 5 + 2 x nodes entries and the covariance as many rows and columns (else std::invalid_argument).
    static RobotFilter restored(const Eigen::VectorXd &state, const Eigen::MatrixXd &covariance,
                                const std::vector<NodeId> &nodes, bool mirrored, bool scale_fixed, bool offset_fixed);

private:
    RangeUpdateOutcome scalarUpdate(const Eigen::VectorXd &jacobian_dense, double innovation, double sigma_m,
                                    double gate_sigma, const RangeLikelihood &likelihood);
    size_t slotOf(NodeId id) const { return slot_.at(id); }

    Eigen::VectorXd state_;
    Eigen::MatrixXd covariance_;
    // Scratch: dh/dstate of the update being made. Inline storage up to kMaxState entries (the
    // EKF holds at most kMaxNodes nodes; insertNode refuses more).
    Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 5 + 2 * 120, 1> jacobian_;
    std::unordered_map<NodeId, size_t> slot_; // node id -> index of its x in the state
    std::vector<NodeId> order_;               // nodes in state order
    bool mirrored_ = false;
    bool scale_fixed_ = false;
    bool offset_fixed_ = false;
};

} // namespace cdro::engine
