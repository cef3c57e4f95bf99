#include "cdro/engine/movement.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

namespace {
constexpr double kTwoPi = 6.28318530717958647692;

double headingOf(const Matrix2 &rotation, double heading_rad)
{
    const Vector2 direction = rotation * Vector2(std::cos(heading_rad), std::sin(heading_rad));
    return std::atan2(direction.y(), direction.x());
}
} // namespace

MovementStage::MovementStage(Engine &engine, const MovementParams &params)
    : engine_(engine), params_(params), likelihood_(engine.params().likelihood)
{
    if (params_.robot_id != 0) {
        engine_.excludeFromFrame(params_.robot_id);
    }
}

double MovementStage::rangeSigma() const
{
    if (params_.range_sigma_m > 0.0) {
        return params_.range_sigma_m;
    }
    const double floor_m = engine_.params().range.sigma_m;
    // A learnt 0 (the state's uncertainty explains the innovations' whole spread) means the
    // floor, not the initial guess: that read 0 as "not learnt" and ran on 1 m.
    return std::max(adaptive_sigma_m_.value_or(params_.adaptive_initial_sigma_m), floor_m);
}

bool MovementStage::linkExcluded(NodeId a, NodeId b, double innovation_m)
{
    LinkWatch &watch = links_[{std::min(a, b), std::max(a, b)}];
    const size_t window = std::max<size_t>(params_.nlos_window, 4U);
    if (watch.innovations_m.size() < window) {
        watch.innovations_m.push_back(innovation_m);
    } else {
        watch.innovations_m[watch.next] = innovation_m;
        watch.next = (watch.next + 1) % window;
    }
    if (watch.innovations_m.size() >= window / 2) {
        std::vector<double> sorted = watch.innovations_m;
        std::nth_element(sorted.begin(), sorted.begin() + static_cast<long>(sorted.size() / 2), sorted.end());
        const double median = sorted[sorted.size() / 2];
        const double limit = std::max(params_.nlos_min_m, params_.nlos_sigmas * rangeSigma());
        // Hysteresis: out beyond the limit, back in below half of it.
        if (!watch.excluded && std::abs(median) > limit) {
            watch.excluded = true;
            trace("link " + std::to_string(a) + "-" + std::to_string(b) + " reads " + std::to_string(median) +
                  " m off persistently: left out of the EKF");
        } else if (watch.excluded && std::abs(median) < 0.5 * limit) {
            watch.excluded = false;
            trace("link " + std::to_string(a) + "-" + std::to_string(b) + " agrees again: back in the EKF");
        }
    }
    if (watch.excluded) {
        ++counters_.nlos_link_ranges_skipped;
    }
    return watch.excluded;
}

void MovementStage::learnNoise(const RangeUpdateOutcome &outcome, double sigma_m)
{
    if (params_.range_sigma_m > 0.0 || outcome.variance_m2 <= 0.0) {
        return;
    }
    // The innovations' spread is the noise plus what the state still does not know: a robust
    // spread (1.4826 x the median absolute innovation) minus the predicted part.
    const size_t window = std::max<size_t>(params_.adaptive_window, 8U);
    const double prior = std::max(outcome.variance_m2 - sigma_m * sigma_m, 0.0);
    if (innovations_m_.size() < window) {
        innovations_m_.push_back(outcome.innovation_m);
        prior_variances_m2_.push_back(prior);
    } else {
        innovations_m_[innovation_next_] = outcome.innovation_m;
        prior_variances_m2_[innovation_next_] = prior;
        innovation_next_ = (innovation_next_ + 1) % window;
    }
    if (innovations_m_.size() < window) {
        return;
    }
    std::vector<double> absolute(innovations_m_.size());
    for (size_t i = 0; i < absolute.size(); ++i) {
        absolute[i] = std::abs(innovations_m_[i]);
    }
    std::nth_element(absolute.begin(), absolute.begin() + static_cast<long>(absolute.size() / 2), absolute.end());
    const double spread = 1.4826 * absolute[absolute.size() / 2];
    double prior_mean = 0.0;
    for (double value : prior_variances_m2_) {
        prior_mean += value;
    }
    prior_mean /= static_cast<double>(prior_variances_m2_.size());
    adaptive_sigma_m_ = std::sqrt(std::max(spread * spread - prior_mean, 0.0));
}

double MovementStage::heightDifference(NodeId a, NodeId b) const
{
    const MapState &map = engine_.map();
    const uint32_t ia = map.findNode(a);
    const uint32_t ib = map.findNode(b);
    if (ia == kNoIndex || ib == kNoIndex || !map.nodes[ia].height_m || !map.nodes[ib].height_m) {
        return 0.0;
    }
    return *map.nodes[ia].height_m - *map.nodes[ib].height_m;
}

const RobotFilter &MovementStage::best() const
{
    size_t index = 0;
    for (size_t i = 1; i < hypotheses_.size(); ++i) {
        if (hypotheses_[i].log_weight > hypotheses_[index].log_weight) {
            index = i;
        }
    }
    return hypotheses_[index].filter;
}

RobotFilter &MovementStage::best()
{
    return const_cast<RobotFilter &>(static_cast<const MovementStage *>(this)->best());
}

void MovementStage::addOdometry(double t_s, const OdometryStep &step)
{
    const double dt = have_time_ ? std::max(t_s - last_t_s_, 0.0) : 0.0;
    last_t_s_ = t_s;
    have_time_ = true;
    ++counters_.odometry_steps;
    ++revision_;
    if (!started_) {
        dead_reckoning_ = predictOdometry(dead_reckoning_, step).pose;
        moved_m_ += std::abs(step.distance_m);
        if (moved_m_ >= params_.motion_start_m) {
            start(t_s);
        }
        return;
    }
    for (Hypothesis &hypothesis : hypotheses_) {
        hypothesis.filter.predict(step, dt, params_.odometry);
    }
    if (trace_ && hypotheses_.size() > 1 && counters_.odometry_steps % 100 == 0) {
        std::string text = "t " + std::to_string(t_s) + " s:";
        for (const Hypothesis &hypothesis : hypotheses_) {
            const Pose2 pose = hypothesis.filter.pose();
            text += " [" + std::to_string(pose.x_m) + ", " + std::to_string(pose.y_m) + ", " +
                    std::to_string(pose.heading_rad) + (hypothesis.filter.mirrored() ? " mirrored" : "") + ": " +
                    std::to_string(hypothesis.log_weight) + "]";
        }
        trace(text);
    }
}

void MovementStage::start(double t_s)
{
    (void)t_s;
    const NodeId robot = params_.robot_id;
    const MapState &network = engine_.map();
    bool map = false;
    for (const NodeState &node : network.nodes) {
        map = map || (node.placed() && node.id != robot);
    }
    const uint32_t robot_node = network.findNode(robot);
    const double scale_sigma = params_.estimate_scale ? params_.scale_sigma : 0.0;
    const double offset_sigma = params_.estimate_offset ? params_.offset_sigma_m : 0.0;
    if (!map) {
        // No map to join: the odometry's frame is the map's. The robot is where it started.
        own_frame_ = true;
        engine_.holdFrame(true);
        Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity() * 1e-6;
        hypotheses_.push_back({RobotFilter(dead_reckoning_, covariance, 1.0, scale_sigma, 0.0, offset_sigma), 0.0});
        started_ = true;
        waiting_for_fix_ = false;
        engine_.setMoving(robot, true);
        trace("robot moves: no map to join, the EKF starts in the odometry frame");
        return;
    }
    engine_.setMoving(robot, true);
    if (robot_node == kNoIndex || !network.nodes[robot_node].placed()) {
        // The map exists but does not hold the robot yet: the initialization stage tracks it
        // (it is moving) until it is placed, then the EKF starts from there.
        waiting_for_fix_ = true;
        return;
    }
    const NodeState &fix = network.nodes[robot_node];
    const uint32_t count = std::max<uint32_t>(params_.heading_hypotheses, 1U);
    const double spread = kTwoPi / count;
    // Every heading, in the map's frame and in its mirror image (the map may be reflected).
    for (bool mirrored : {false, true}) {
        for (uint32_t k = 0; k < count; ++k) {
            Pose2 pose{fix.position_m.x(), fix.position_m.y(), wrapAngle(spread * k)};
            Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
            covariance.topLeftCorner<2, 2>() = fix.covariance_m2 + 0.01 * Matrix2::Identity();
            covariance(2, 2) = (spread / 2.0) * (spread / 2.0);
            Hypothesis hypothesis{RobotFilter(pose, covariance, 1.0, scale_sigma, 0.0, offset_sigma), 0.0};
            hypothesis.filter.setMirrored(mirrored);
            hypotheses_.push_back(std::move(hypothesis));
        }
    }
    normaliseHypotheses();
    started_ = true;
    waiting_for_fix_ = false;
    insertConvergedNodes();
    trace("robot moves: EKF starts in the map's frame at (" + std::to_string(fix.position_m.x()) + ", " +
          std::to_string(fix.position_m.y()) + ") with " + std::to_string(count) + " heading hypotheses and " +
          std::to_string(hypotheses_.front().filter.nodes().size()) + " nodes");
}

void MovementStage::insertConvergedNodes()
{
    for (const NodeState &node : engine_.map().nodes) {
        if (node.id != params_.robot_id && !hypotheses_.front().filter.hasNode(node.id)) {
            insertNode(node.id);
        }
    }
}

bool MovementStage::insertNode(NodeId id)
{
    const MapState &network = engine_.map();
    const uint32_t index = network.findNode(id);
    if (index == kNoIndex || id == params_.robot_id || hypotheses_.empty()) {
        return false;
    }
    const NodeState &node = network.nodes[index];
    const bool moving = moving_.count(id) != 0 && moving_.at(id);
    // A node whose doubt is the link graph's (a part that can fold, links nothing checks) is where
    // the map solve put it: the robot's ranges from many poses are what settles such a part. A
    // node with a rival position, too few links or a moving estimate waits for a SoG around the
    // robot instead.
    const bool graph_doubt = node.doubt == NodeDoubt::Foldable || node.doubt == NodeDoubt::Flexible;
    if (!node.placed() || node.moving() || moving || node.pinned() ||
        !(node.converged() || node.fixed() || graph_doubt)) {
        return false;
    }
    // Never more certain than one range could make it: the initialization's covariances
    // ignore its neighbours' correlations.
    const double floor_m2 = rangeSigma() * rangeSigma();
    Matrix2 covariance = node.fixed() ? Matrix2::Identity() * 1e-8 : node.covariance_m2;
    if (!node.fixed() && minEigenvalue(covariance) < floor_m2) {
        covariance += floor_m2 * Matrix2::Identity();
    }
    if (hypotheses_.front().filter.full()) {
        return false; // the EKF is dense; beyond its size the initialization stage keeps the node
    }
    for (Hypothesis &hypothesis : hypotheses_) {
        hypothesis.filter.insertNode(id, node.position_m, covariance);
    }
    ++counters_.nodes_inserted;
    engine_.pinNode(id, node.position_m, covariance);
    return true;
}

void MovementStage::pinNodes()
{
    const RobotFilter &filter = best();
    for (NodeId id : filter.nodes()) {
        engine_.pinNode(id, filter.nodePosition(id), filter.nodeCovariance(id));
    }
}

void MovementStage::normaliseHypotheses()
{
    if (hypotheses_.empty()) {
        return;
    }
    double largest = -std::numeric_limits<double>::infinity();
    for (const Hypothesis &hypothesis : hypotheses_) {
        largest = std::max(largest, hypothesis.log_weight);
    }
    double total = 0.0;
    for (const Hypothesis &hypothesis : hypotheses_) {
        total += std::exp(hypothesis.log_weight - largest);
    }
    const double log_total = largest + std::log(total);
    for (Hypothesis &hypothesis : hypotheses_) {
        hypothesis.log_weight -= log_total;
    }
    if (hypotheses_.size() == 1) {
        hypotheses_.front().log_weight = 0.0;
        return;
    }
    // Hypotheses that have reached the same pose are one: their weights add up.
    for (size_t i = 0; i < hypotheses_.size(); ++i) {
        for (size_t j = hypotheses_.size(); j-- > i + 1;) {
            const Pose2 a = hypotheses_[i].filter.pose();
            const Pose2 b = hypotheses_[j].filter.pose();
            // Closer than their own uncertainty (or the fixed thresholds): the same hypothesis.
            const Eigen::Matrix3d &p = hypotheses_[i].filter.poseCovariance();
            const Matrix2 position_covariance = p.topLeftCorner<2, 2>();
            const double position_sigma =
                std::sqrt(std::max(position_covariance.trace() - minEigenvalue(position_covariance), 0.0));
            const double heading_sigma = std::sqrt(std::max(p(2, 2), 0.0));
            if (hypotheses_[i].filter.mirrored() == hypotheses_[j].filter.mirrored() &&
                std::hypot(a.x_m - b.x_m, a.y_m - b.y_m) < std::max(params_.heading_merge_m, 3.0 * position_sigma) &&
                std::abs(wrapAngle(a.heading_rad - b.heading_rad)) <
                    std::max(params_.heading_merge_rad, 3.0 * heading_sigma)) {
                const double high = std::max(hypotheses_[i].log_weight, hypotheses_[j].log_weight);
                const double sum = high + std::log(std::exp(hypotheses_[i].log_weight - high) +
                                                   std::exp(hypotheses_[j].log_weight - high));
                if (hypotheses_[j].log_weight > hypotheses_[i].log_weight) {
                    std::swap(hypotheses_[i], hypotheses_[j]);
                }
                hypotheses_[i].log_weight = sum;
                hypotheses_.erase(hypotheses_.begin() + static_cast<long>(j));
                ++counters_.hypotheses_pruned;
            }
        }
    }
    const double collapse = std::log(params_.heading_collapse_weight);
    const double prune = std::log(params_.heading_prune_weight);
    std::vector<Hypothesis> kept;
    for (Hypothesis &hypothesis : hypotheses_) {
        if (hypothesis.log_weight >= collapse) {
            kept = {hypothesis};
            kept.front().log_weight = 0.0;
            break;
        }
        if (hypothesis.log_weight >= prune) {
            kept.push_back(hypothesis);
        }
    }
    counters_.hypotheses_pruned += hypotheses_.size() - kept.size();
    if (!kept.empty()) {
        const bool decided = kept.size() == 1 && hypotheses_.size() > 1;
        hypotheses_ = std::move(kept);
        if (decided) {
            trace(std::string("robot heading decided: ") +
                  std::to_string(hypotheses_.front().filter.pose().heading_rad) + " rad" +
                  (hypotheses_.front().filter.mirrored() ? ", the map is the world's mirror image" : ""));
        }
    }
    if (hypotheses_.size() == 1) {
        pinNodes();
    }
}

void MovementStage::updateBeaconSog(NodeId id, BeaconSog &sog, const Vector2 &centre_m,
                                    const Matrix2 &centre_covariance_m2, bool from_robot, double range_m,
                                    double height_difference_m)
{
    const RobotFilter &filter = best();
    const RangeTerms terms{height_difference_m, filter.scale(), filter.offset()};
    const double noise = rangeSigma() * rangeSigma() + filter.scaleSigma() * filter.scaleSigma() * range_m * range_m +
                         filter.offsetSigma() * filter.offsetSigma();
    if (sog.ring.empty()) {
        if (!from_robot) {
            return; // rings start around the robot; the map's nodes then help decide between them
        }
        // A ring around the robot, of the range corrected by the current calibration.
        const double radius_m = std::sqrt(std::max(std::pow((range_m - terms.offset_m) / terms.scale, 2.0) -
                                                       height_difference_m * height_difference_m,
                                                   0.0));
        RingSogParams shape;
        shape.arc_spacing_m = std::max(params_.beacon_arc_spacing_m, 0.05);
        shape.min_components = params_.beacon_min_components;
        shape.radial_sigma_m = std::sqrt(noise);
        shape.min_tangential_sigma_m = 0.0;
        shape.weight_floor = 0.0; // what has lost is pruned, not kept
        sog.ring = RingSog::generate(params_.robot_id, id, centre_m, radius_m, shape, centre_covariance_m2);
        sog.ring.setAbsoluteComponents(sog.ring.components());
        sog.first_robot_m = centre_m;
        sog.ranges = 1;
        ++counters_.beacon_sogs;
        return;
    }
    ++sog.ranges;
    // The spread of the places it was ranged from (the robot's, or a map node's): what tells a
    // ring's modes apart.
    sog.baseline_m = std::max(sog.baseline_m, (centre_m - sog.first_robot_m).norm());
    RingUpdateRule rule;
    rule.weigh_by = &likelihood_;
    sog.ring.updateWithRange(centre_m, centre_covariance_m2, range_m, noise, terms, rule);
    // Only the plausible part of the ring is kept.
    sog.ring.prune(params_.beacon_prune_ratio);
}

void MovementStage::updateBeacon(NodeId id, const Vector2 &centre_m, const Matrix2 &centre_covariance_m2,
                                 bool from_robot, double range_m, double height_difference_m)
{
    BeaconSog &sog = beacons_[id];
    updateBeaconSog(id, sog, centre_m, centre_covariance_m2, from_robot, range_m, height_difference_m);
    if (sog.ring.empty()) {
        beacons_.erase(id);
        return;
    }
    const Gaussian2 merged = sog.ring.moments();
    const double largest_variance =
        merged.covariance_m2.trace() - minEigenvalue(merged.covariance_m2); // the larger eigenvalue
    // A full EKF leaves it a SoG (the map's nodes wait the same way in insertNode).
    if (sog.ranges >= params_.beacon_min_ranges && sog.baseline_m >= params_.beacon_min_baseline_m &&
        largest_variance <= params_.beacon_insert_std_m * params_.beacon_insert_std_m &&
        !hypotheses_.front().filter.full()) {
        for (Hypothesis &hypothesis : hypotheses_) {
            hypothesis.filter.insertNode(id, merged.mean_m, merged.covariance_m2);
        }
        ++counters_.nodes_inserted;
        engine_.pinNode(id, merged.mean_m, merged.covariance_m2);
        beacons_.erase(id);
    }
}

RangeVerdict MovementStage::addRange(NodeId from, NodeId to, double range_m, double t_s)
{
    last_t_s_ = std::max(last_t_s_, t_s);
    const RangeVerdict verdict = engine_.addRange(from, to, range_m, t_s);
    if (verdict == RangeVerdict::RejectedSelf || verdict == RangeVerdict::RejectedValue) {
        return verdict;
    }
    ++revision_;
    if (!started_) {
        if (waiting_for_fix_) {
            const uint32_t robot = engine_.map().findNode(params_.robot_id);
            if (robot != kNoIndex && engine_.map().nodes[robot].placed()) {
                start(t_s);
            }
        }
        return verdict;
    }
    const NodeId robot = params_.robot_id;
    const bool robot_range = from == robot || to == robot;
    const double sigma = rangeSigma();
    if (robot_range) {
        const NodeId other = from == robot ? to : from;
        ++counters_.robot_ranges;
        if (moving_.count(other) != 0 && moving_.at(other)) {
            return verdict; // a carried node is tracked by the initialization stage
        }
        const double dz = heightDifference(robot, other);
        if (!hypotheses_.front().filter.hasNode(other) && !insertNode(other)) {
            // A node the map does not hold yet: a SoG around the robot, once its heading is known.
            if (hypotheses_.size() != 1) {
                return verdict;
            }
            const RobotFilter &filter = best();
            const Pose2 pose = filter.pose();
            updateBeacon(other, Vector2(pose.x_m, pose.y_m), filter.poseCovariance().topLeftCorner<2, 2>(), true,
                         range_m, dz);
            return verdict;
        }
        if (hypotheses_.size() == 1 &&
            linkExcluded(robot, other, hypotheses_.front().filter.robotRangeInnovation(other, range_m, dz))) {
            return verdict;
        }
        const RobotFilter *leader = &best();
        for (Hypothesis &hypothesis : hypotheses_) {
            const RangeUpdateOutcome outcome =
                hypothesis.filter.updateRobotRange(other, range_m, dz, sigma, params_.gate_sigma, likelihood_);
            hypothesis.log_weight += outcome.log_likelihood;
            counters_.ekf_updates += outcome.used ? 1U : 0U;
            counters_.ekf_gated += outcome.gated ? 1U : 0U;
            // Only a decided heading says anything about the noise (the wrong ones see huge innovations).
            if (&hypothesis.filter == leader && hypotheses_.size() == 1) {
                learnNoise(outcome, sigma);
            }
        }
        normaliseHypotheses();
        if (hypotheses_.size() == 1) {
            pinNodes();
        }
        return verdict;
    }
    // Between two nodes: the EKF refines both when it holds both.
    RobotFilter &filter = hypotheses_.front().filter;
    if (!filter.hasNode(from)) {
        insertNode(from);
    }
    if (!filter.hasNode(to)) {
        insertNode(to);
    }
    // A node the EKF holds ranging one that has a SoG around the robot: one more place it is
    // ranged from (the robot alone, driving a straight line, cannot tell a ring's mirror modes
    // apart; a map node off that line can).
    if (hypotheses_.size() == 1 && filter.hasNode(from) != filter.hasNode(to)) {
        const NodeId known = filter.hasNode(from) ? from : to;
        const NodeId other = known == from ? to : from;
        if (beacons_.count(other) != 0 && (moving_.count(other) == 0 || !moving_.at(other))) {
            updateBeacon(other, filter.nodePosition(known), filter.nodeCovariance(known), false, range_m,
                         heightDifference(known, other));
            return verdict;
        }
    }
    if (filter.hasNode(from) && filter.hasNode(to)) {
        // A link the initialization found NLOS (it reads long, persistently) would pull the EKF a
        // little with every range; its ranges are left out.
        const double dz = heightDifference(from, to);
        if (linkExcluded(from, to, filter.nodeRangeInnovation(from, to, range_m, dz))) {
            return verdict;
        }
        for (Hypothesis &hypothesis : hypotheses_) {
            const RangeUpdateOutcome outcome =
                hypothesis.filter.updateNodeRange(from, to, range_m, dz, sigma, params_.gate_sigma, likelihood_);
            counters_.ekf_updates += outcome.used ? 1U : 0U;
            counters_.ekf_gated += outcome.gated ? 1U : 0U;
        }
        if (hypotheses_.size() == 1) {
            pinNodes();
        }
    }
    return verdict;
}

void MovementStage::setMoving(NodeId id, bool moving, double t_s)
{
    last_t_s_ = std::max(last_t_s_, t_s);
    if (id == params_.robot_id) {
        return; // the robot's motion comes from its odometry
    }
    moving_[id] = moving;
    ++revision_;
    if (moving && !hypotheses_.empty() && hypotheses_.front().filter.hasNode(id)) {
        for (Hypothesis &hypothesis : hypotheses_) {
            hypothesis.filter.removeNode(id);
        }
        ++counters_.nodes_removed;
        engine_.unpinNode(id);
    }
    engine_.setMoving(id, moving);
}

MovementStage::Saved MovementStage::saved() const
{
    Saved out;
    out.started = started_;
    out.own_frame = own_frame_;
    out.waiting_for_fix = waiting_for_fix_;
    out.moved_m = moved_m_;
    out.last_t_s = last_t_s_;
    out.have_time = have_time_;
    out.dead_reckoning = dead_reckoning_;
    out.hypotheses = hypotheses_;
    out.beacons = beacons_;
    out.moving = moving_;
    out.links = links_;
    out.innovations_m = innovations_m_;
    out.prior_variances_m2 = prior_variances_m2_;
    out.innovation_next = innovation_next_;
    out.adaptive_sigma_m = adaptive_sigma_m_;
    out.counters = counters_;
    out.revision = revision_;
    return out;
}

void MovementStage::restore(const Saved &saved)
{
    started_ = saved.started;
    own_frame_ = saved.own_frame;
    waiting_for_fix_ = saved.waiting_for_fix;
    moved_m_ = saved.moved_m;
    last_t_s_ = saved.last_t_s;
    have_time_ = saved.have_time;
    dead_reckoning_ = saved.dead_reckoning;
    hypotheses_ = saved.hypotheses;
    beacons_ = saved.beacons;
    moving_ = saved.moving;
    links_ = saved.links;
    innovations_m_ = saved.innovations_m;
    prior_variances_m2_ = saved.prior_variances_m2;
    innovation_next_ = saved.innovation_next;
    adaptive_sigma_m_ = saved.adaptive_sigma_m;
    counters_ = saved.counters;
    revision_ = saved.revision;
}

size_t MovementStage::convergedNeighbours() const
{
    const MapState &map = engine_.map();
    const uint32_t robot = map.findNode(params_.robot_id);
    size_t count = 0;
    if (robot == kNoIndex) {
        return count;
    }
    for (uint32_t link : map.nodes[robot].links) {
        const NodeState &other = map.nodes[map.otherNode(link, robot)];
        count += other.converged() || other.fixed() ? 1U : 0U;
    }
    return count;
}

const char *robotFrameName(RobotFrame frame) { return frame == RobotFrame::Map ? "map" : "odometry"; }

std::optional<RobotOutput> MovementStage::robot() const
{
    if (params_.robot_id == 0) {
        return std::nullopt;
    }
    RobotOutput out;
    out.id = params_.robot_id;
    out.t_s = last_t_s_;
    const RigidTransform transform = engine_.outputTransform();
    if (!started_ || hypotheses_.empty()) {
        const std::optional<NodeOutput> node = engine_.estimate(params_.robot_id);
        // A node whose links fit another position about as well (too few links, a mirror image
        // while the map forms, a part that can fold): that is no position yet. Measured on the
        // simulated runs: those estimates are 5-13 m off, the first unambiguous one 0.1 m. Nor is
        // one that ranges fewer than three converged nodes: while the map forms from its first
        // ranges the robot's tag can be the hub of a map of doubtful nodes, its covariance zero
        // (the map's gauge on it), ~50 m off (the robot corridor, seeds 4 and 5).
        const bool undecided = node && (node->doubt == NodeDoubt::Ambiguous || node->doubt == NodeDoubt::TooFewLinks ||
                                        node->doubt == NodeDoubt::Foldable || convergedNeighbours() < 3);
        if (node && node->placed() && !undecided) {
            out.placed = true;
            out.frame = RobotFrame::Map;
            out.pose = Pose2{node->position_m.x(), node->position_m.y(), 0.0};
            out.covariance.topLeftCorner<2, 2>() = node->covariance_m2;
            out.covariance(2, 2) = kTwoPi * kTwoPi / 12.0; // heading unknown
        } else {
            // Without a map yet, the odometry's frame is the one the EKF will start in.
            out.pose = dead_reckoning_;
            bool map = false;
            for (const NodeState &state : engine_.map().nodes) {
                map = map || state.placed();
            }
            out.placed = !map && !waiting_for_fix_;
        }
        return out;
    }
    const RobotFilter &filter = best();
    const Pose2 pose = filter.pose();
    const Vector2 position = transform.apply(Vector2(pose.x_m, pose.y_m));
    out.pose = Pose2{position.x(), position.y(), headingOf(transform.rotation, pose.heading_rad)};
    // The whole pose covariance into the output frame: J P J^T with J = diag(R, det R), since the
    // heading turns with the rotation (a reflection mirrors it: d heading' / d heading = -1).
    Eigen::Matrix3d jacobian = Eigen::Matrix3d::Zero();
    jacobian.topLeftCorner<2, 2>() = transform.rotation;
    const Matrix2 &r = transform.rotation;
    jacobian(2, 2) = r(0, 0) * r(1, 1) - r(0, 1) * r(1, 0) < 0.0 ? -1.0 : 1.0;
    const Eigen::Matrix3d turned = jacobian * filter.poseCovariance() * jacobian.transpose();
    out.covariance = 0.5 * (turned + turned.transpose());
    out.localized = true;
    out.placed = true;
    out.frame = own_frame_ ? RobotFrame::Odometry : RobotFrame::Map;
    out.hypotheses = static_cast<uint32_t>(hypotheses_.size());
    out.range_scale = filter.scale();
    out.range_scale_sigma = filter.scaleSigma();
    out.range_offset_m = filter.offset();
    out.range_offset_sigma_m = filter.offsetSigma();
    return out;
}

std::vector<NodeOutput> MovementStage::estimates() const
{
    std::vector<NodeOutput> out = engine_.estimates();
    if (!started_ || hypotheses_.empty()) {
        return out;
    }
    const RigidTransform transform = engine_.outputTransform();
    const RobotFilter &filter = best();
    for (NodeOutput &node : out) {
        const bool held = node.id == params_.robot_id || filter.hasNode(node.id) ||
                          (beacons_.count(node.id) != 0 && !beacons_.at(node.id).ring.empty());
        if (held && node.doubt == NodeDoubt::Foldable) {
            // Placed by the robot's ranges from many poses, not by the link graph alone: the
            // graph's folds (foldable.hpp) say nothing about it.
            node.doubt = NodeDoubt::None;
            node.hinge_nodes = 0;
        }
        if (node.id == params_.robot_id) {
            const Pose2 pose = filter.pose();
            node.lifecycle = NodeLifecycle::Moving;
            node.doubt = hypotheses_.size() == 1 ? NodeDoubt::None : NodeDoubt::Ambiguous; // heading undecided
            node.position_m = transform.apply(Vector2(pose.x_m, pose.y_m));
            node.covariance_m2 = transform.applyToCovariance(filter.poseCovariance().topLeftCorner<2, 2>());
        } else if (filter.hasNode(node.id)) {
            node.lifecycle = NodeLifecycle::Converged;
            node.doubt = NodeDoubt::None;
            node.position_m = transform.apply(filter.nodePosition(node.id));
            node.covariance_m2 = transform.applyToCovariance(filter.nodeCovariance(node.id));
        } else {
            const auto beacon = beacons_.find(node.id);
            if (beacon != beacons_.end() && !beacon->second.ring.empty()) {
                // Still a SoG around the robot's path: its merged mean, not converged.
                const Gaussian2 merged = beacon->second.ring.moments();
                node.lifecycle = NodeLifecycle::Placed;
                node.doubt = NodeDoubt::Unsettled;
                node.position_m = transform.apply(merged.mean_m);
                node.covariance_m2 = transform.applyToCovariance(merged.covariance_m2);
            }
        }
    }
    return out;
}

} // namespace cdro::engine
