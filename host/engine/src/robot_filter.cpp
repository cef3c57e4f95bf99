#include "cdro/engine/robot_filter.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

namespace {
constexpr Eigen::Index kPose = 0;
constexpr Eigen::Index kScale = 3;
constexpr Eigen::Index kOffset = 4;
constexpr Eigen::Index kFirstNode = 5;
} // namespace

RobotFilter::RobotFilter(const Pose2 &pose, const Eigen::Matrix3d &pose_covariance, double scale, double scale_sigma,
                         double offset_m, double offset_sigma_m)
    : state_(Eigen::VectorXd::Zero(kFirstNode)), covariance_(Eigen::MatrixXd::Zero(kFirstNode, kFirstNode))
{
    state_ << pose.x_m, pose.y_m, pose.heading_rad, scale, offset_m;
    covariance_.topLeftCorner<3, 3>() = pose_covariance;
    covariance_(kScale, kScale) = scale_sigma * scale_sigma;
    covariance_(kOffset, kOffset) = offset_sigma_m * offset_sigma_m;
    scale_fixed_ = !(scale_sigma > 0.0);
    offset_fixed_ = !(offset_sigma_m > 0.0);
}

RobotFilter RobotFilter::restored(const Eigen::VectorXd &state, const Eigen::MatrixXd &covariance,
                                  const std::vector<NodeId> &nodes, bool mirrored, bool scale_fixed, bool offset_fixed)
{
    const auto size = static_cast<Eigen::Index>(kFirstNode + 2 * static_cast<Eigen::Index>(nodes.size()));
    if (state.size() != size || covariance.rows() != size || covariance.cols() != size || nodes.size() > kMaxNodes) {
        throw std::invalid_argument("robot filter: the state, its covariance and its nodes do not fit together");
    }
    RobotFilter filter(Pose2{}, Eigen::Matrix3d::Identity(), 1.0, 0.0, 0.0, 0.0);
    filter.state_ = state;
    filter.covariance_ = covariance;
    filter.order_ = nodes;
    for (size_t i = 0; i < nodes.size(); ++i) {
        if (!filter.slot_.emplace(nodes[i], static_cast<size_t>(kFirstNode) + 2 * i).second) {
            throw std::invalid_argument("robot filter: a node is in the state twice");
        }
    }
    filter.mirrored_ = mirrored;
    filter.scale_fixed_ = scale_fixed;
    filter.offset_fixed_ = offset_fixed;
    return filter;
}

Pose2 RobotFilter::pose() const { return Pose2{state_(0), state_(1), state_(2)}; }

void RobotFilter::predict(const OdometryStep &odometry, double dt_s, const RobotFilterNoise &noise)
{
    OdometryStep step = odometry;
    if (mirrored_) {
        step.dheading_rad = -step.dheading_rad;
    }
    const OdometryPrediction prediction = predictOdometry(pose(), step);
    state_(0) = prediction.pose.x_m;
    state_(1) = prediction.pose.y_m;
    state_(2) = prediction.pose.heading_rad;
    const double dt = std::max(dt_s, 0.0);
    const double sigma_d = noise.distance_fraction * std::abs(step.distance_m) + noise.distance_floor_m;
    const double sigma_h = noise.heading_fraction * std::abs(step.dheading_rad) + noise.heading_floor_rad +
                           noise.heading_walk_rad_per_sqrt_s * std::sqrt(dt);
    Eigen::Matrix2d step_covariance = Eigen::Matrix2d::Zero();
    step_covariance(0, 0) = sigma_d * sigma_d;
    step_covariance(1, 1) = sigma_h * sigma_h;
    // P = F P F^T + G Q G^T, with F touching only the pose rows and columns.
    const Eigen::Matrix3d &f = prediction.jacobian_pose;
    const Eigen::Index n = covariance_.rows();
    const Eigen::MatrixXd pose_rows = f * covariance_.topRows<3>();
    covariance_.topRows<3>() = pose_rows;
    const Eigen::MatrixXd pose_cols = covariance_.leftCols<3>() * f.transpose();
    covariance_.leftCols<3>() = pose_cols;
    covariance_.topLeftCorner<3, 3>() +=
        prediction.jacobian_step * step_covariance * prediction.jacobian_step.transpose();
    if (!scale_fixed_) {
        covariance_(kScale, kScale) += noise.scale_walk_per_sqrt_s * noise.scale_walk_per_sqrt_s * dt;
    }
    if (!offset_fixed_) {
        covariance_(kOffset, kOffset) += noise.offset_walk_m_per_sqrt_s * noise.offset_walk_m_per_sqrt_s * dt;
    }
    (void)n;
}

bool RobotFilter::insertNode(NodeId id, const Vector2 &position_m, const Matrix2 &covariance_m2)
{
    if (hasNode(id)) {
        return true;
    }
    if (full()) {
        return false;
    }
    const Eigen::Index n = state_.size();
    state_.conservativeResize(n + 2);
    state_(n) = position_m.x();
    state_(n + 1) = position_m.y();
    Eigen::MatrixXd grown = Eigen::MatrixXd::Zero(n + 2, n + 2);
    grown.topLeftCorner(n, n) = covariance_;
    grown.block<2, 2>(n, n) = covariance_m2;
    covariance_ = std::move(grown);
    slot_[id] = static_cast<size_t>(n);
    order_.push_back(id);
    return true;
}

void RobotFilter::removeNode(NodeId id)
{
    const auto found = slot_.find(id);
    if (found == slot_.end()) {
        return;
    }
    const Eigen::Index slot = static_cast<Eigen::Index>(found->second);
    const Eigen::Index n = state_.size();
    // Marginalising a Gaussian is dropping its rows and columns.
    std::vector<Eigen::Index> keep;
    for (Eigen::Index i = 0; i < n; ++i) {
        if (i != slot && i != slot + 1) {
            keep.push_back(i);
        }
    }
    Eigen::VectorXd state(static_cast<Eigen::Index>(keep.size()));
    Eigen::MatrixXd covariance(static_cast<Eigen::Index>(keep.size()), static_cast<Eigen::Index>(keep.size()));
    for (size_t i = 0; i < keep.size(); ++i) {
        state(static_cast<Eigen::Index>(i)) = state_(keep[i]);
        for (size_t j = 0; j < keep.size(); ++j) {
            covariance(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = covariance_(keep[i], keep[j]);
        }
    }
    state_ = std::move(state);
    covariance_ = std::move(covariance);
    order_.erase(std::find(order_.begin(), order_.end(), id));
    slot_.clear();
    for (size_t i = 0; i < order_.size(); ++i) {
        slot_[order_[i]] = static_cast<size_t>(kFirstNode) + 2 * i;
    }
}

Vector2 RobotFilter::nodePosition(NodeId id) const
{
    const Eigen::Index slot = static_cast<Eigen::Index>(slotOf(id));
    return Vector2(state_(slot), state_(slot + 1));
}

Matrix2 RobotFilter::nodeCovariance(NodeId id) const
{
    const Eigen::Index slot = static_cast<Eigen::Index>(slotOf(id));
    return covariance_.block<2, 2>(slot, slot);
}

RangeUpdateOutcome RobotFilter::scalarUpdate(const Eigen::VectorXd &h, double innovation, double sigma_m,
                                             double gate_sigma, const RangeLikelihood &likelihood)
{
    RangeUpdateOutcome outcome;
    outcome.innovation_m = innovation;
    const Eigen::VectorXd ph = covariance_ * h;
    const double prior_variance = h.dot(ph);
    const double noise = sigma_m * sigma_m;
    outcome.variance_m2 = prior_variance + noise;
    const ResidualEvaluation evaluation = likelihood.evaluate(innovation, outcome.variance_m2);
    outcome.log_likelihood = evaluation.log_density;
    outcome.inlier_probability = evaluation.inlier_probability;
    if (innovation * innovation > gate_sigma * gate_sigma * outcome.variance_m2 &&
        evaluation.inlier_probability < 0.01) {
        outcome.gated = true;
        return outcome;
    }
    // A likely NLOS reading counts for less: its noise is widened by 1 / P(line of sight).
    const double widened = noise / std::max(evaluation.inlier_probability, 0.05);
    const double s = prior_variance + widened;
    const Eigen::VectorXd gain = ph / s;
    state_ += gain * innovation;
    state_(2) = wrapAngle(state_(2));
    // P - K H P = P - (P h)(P h)^T / s: O(n^2), symmetric by construction (a full Joseph
    // form is O(n^3) for a scalar measurement; the symmetric rank-one form is as stable here).
    covariance_.noalias() -= (ph / s) * ph.transpose();
    covariance_ = 0.5 * (covariance_ + covariance_.transpose());
    outcome.used = true;
    return outcome;
}

double RobotFilter::robotRangeInnovation(NodeId node, double range_m, double height_difference_m) const
{
    const Eigen::Index slot = static_cast<Eigen::Index>(slotOf(node));
    const Vector2 robot(state_(kPose), state_(kPose + 1));
    const Vector2 target(state_(slot), state_(slot + 1));
    return range_m - predictRange(robot, target, height_difference_m, scale(), offset()).range_m;
}

double RobotFilter::nodeRangeInnovation(NodeId a, NodeId b, double range_m, double height_difference_m) const
{
    const Vector2 position_a = nodePosition(a);
    const Vector2 position_b = nodePosition(b);
    return range_m - predictRange(position_a, position_b, height_difference_m, scale(), offset()).range_m;
}

RangeUpdateOutcome RobotFilter::updateRobotRange(NodeId node, double range_m, double height_difference_m,
                                                 double sigma_m, double gate_sigma, const RangeLikelihood &likelihood)
{
    const Eigen::Index slot = static_cast<Eigen::Index>(slotOf(node));
    // Element by element: gcc 12 sees a possible null in fixed-size views of a dynamic vector.
    const Vector2 robot(state_(kPose), state_(kPose + 1));
    const Vector2 target(state_(slot), state_(slot + 1));
    const RangePrediction prediction = predictRange(robot, target, height_difference_m, scale(), offset());
    if (prediction.singular) {
        return {};
    }
    auto &h = jacobian_;
    h.setZero(state_.size());
    h(kPose) = prediction.jacobian_point(0);
    h(kPose + 1) = prediction.jacobian_point(1);
    h(slot) = prediction.jacobian_center(0);
    h(slot + 1) = prediction.jacobian_center(1);
    h(kScale) = scale_fixed_ ? 0.0 : prediction.jacobian_scale;
    h(kOffset) = offset_fixed_ ? 0.0 : prediction.jacobian_offset;
    return scalarUpdate(h, range_m - prediction.range_m, sigma_m, gate_sigma, likelihood);
}

RangeUpdateOutcome RobotFilter::updateNodeRange(NodeId a, NodeId b, double range_m, double height_difference_m,
                                                double sigma_m, double gate_sigma, const RangeLikelihood &likelihood)
{
    const Eigen::Index slot_a = static_cast<Eigen::Index>(slotOf(a));
    const Eigen::Index slot_b = static_cast<Eigen::Index>(slotOf(b));
    const Vector2 position_a(state_(slot_a), state_(slot_a + 1));
    const Vector2 position_b(state_(slot_b), state_(slot_b + 1));
    const RangePrediction prediction = predictRange(position_a, position_b, height_difference_m, scale(), offset());
    if (prediction.singular) {
        return {};
    }
    auto &h = jacobian_;
    h.setZero(state_.size());
    h(slot_a) = prediction.jacobian_point(0);
    h(slot_a + 1) = prediction.jacobian_point(1);
    h(slot_b) = prediction.jacobian_center(0);
    h(slot_b + 1) = prediction.jacobian_center(1);
    h(kScale) = scale_fixed_ ? 0.0 : prediction.jacobian_scale;
    h(kOffset) = offset_fixed_ ? 0.0 : prediction.jacobian_offset;
    return scalarUpdate(h, range_m - prediction.range_m, sigma_m, gate_sigma, likelihood);
}

} // namespace cdro::engine
