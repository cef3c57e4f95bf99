#include "cdro/engine/motion_track_3d.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

namespace {

constexpr double kPi = 3.14159265358979323846;

double normalPdf(double x) { return std::exp(-0.5 * x * x) / std::sqrt(2.0 * kPi); }

// P(lo < X < hi) for X ~ N(0, 1), from the tail that keeps its digits.
double normalMass(double lo, double hi)
{
    if (lo > 0.0) {
        return 0.5 * (std::erfc(lo / std::sqrt(2.0)) - std::erfc(hi / std::sqrt(2.0)));
    }
    if (hi < 0.0) {
        return 0.5 * (std::erfc(-hi / std::sqrt(2.0)) - std::erfc(-lo / std::sqrt(2.0)));
    }
    return 1.0 - 0.5 * (std::erfc(-lo / std::sqrt(2.0)) + std::erfc(hi / std::sqrt(2.0)));
}

// Mean and variance of N(mean, sigma^2) truncated to [lo, hi] (m, m^2).
std::pair<double, double> truncatedMoments(double mean, double sigma, double lo, double hi)
{
    const double alpha = (lo - mean) / sigma;
    const double beta = (hi - mean) / sigma;
    const double mass = normalMass(alpha, beta);
    if (mass < 1e-12) {
        // The mean is far outside the room: the truncated Gaussian hugs the nearest bound (its
        // exponential tail, asymptotically mean bound +- sigma / |z|, sigma / |z| wide).
        const double z = alpha > 0.0 ? alpha : -beta;
        const double bound = alpha > 0.0 ? lo : hi;
        const double step = std::min(sigma / z, 0.5 * (hi - lo));
        return {alpha > 0.0 ? bound + step : bound - step, step * step};
    }
    const double pa = normalPdf(alpha);
    const double pb = normalPdf(beta);
    const double shift = (pa - pb) / mass;
    // Infinite bounds do not occur (the room is a box); alpha * pdf(alpha) is finite.
    const double variance = sigma * sigma * std::max(1.0 + (alpha * pa - beta * pb) / mass - shift * shift, 1e-12);
    return {mean + sigma * shift, variance};
}

// One node's block of F and Q over dt_s: each velocity component an Ornstein-Uhlenbeck process
// (stationary sigma s, correlation time tau), the position its integral; exact discretisation.
void transitionOu(double dt_s, double s_mps, double tau_s, Eigen::Matrix<double, 6, 6> &f,
                  Eigen::Matrix<double, 6, 6> &q)
{
    const double x = dt_s / tau_s;
    const double e = std::exp(-x);
    const double s2 = s_mps * s_mps;
    f.setIdentity();
    q.setZero();
    // x - 2 (1 - e) + (1 - e^2) / 2, by its series where its terms cancel
    const double walk = x > 1e-2 ? x - 2.0 * (1.0 - e) + 0.5 * (1.0 - e * e)
                                 : x * x * x / 3.0 - x * x * x * x / 4.0 + 7.0 * x * x * x * x * x / 60.0;
    for (int k = 0; k < 3; ++k) {
        f(k, 3 + k) = tau_s * (1.0 - e);
        f(3 + k, 3 + k) = e;
        q(k, k) = 2.0 * s2 * tau_s * tau_s * walk;
        q(k, 3 + k) = q(3 + k, k) = s2 * tau_s * (1.0 - e) * (1.0 - e);
        q(3 + k, 3 + k) = s2 * (1.0 - e * e);
    }
}

} // namespace

FlightTracks::FlightTracks(const MotionParams &motion, double range_sigma_m, double gate_sigma,
                           const RangeLikelihood &likelihood)
    : motion_(motion), range_sigma_m_(range_sigma_m), gate_sigma_(gate_sigma), likelihood_(likelihood)
{
}

uint32_t FlightTracks::find(NodeId id) const
{
    for (uint32_t i = 0; i < ids_.size(); ++i) {
        if (ids_[i] == id) {
            return i;
        }
    }
    return kNone;
}

const Vector3 *FlightTracks::anchor(NodeId id) const
{
    for (const auto &[anchor_id, position] : anchors_) {
        if (anchor_id == id) {
            return &position;
        }
    }
    return nullptr;
}

void FlightTracks::add(NodeId id)
{
    if (tracks(id)) {
        return;
    }
    ids_.push_back(id);
    Node node;
    node.id = id;
    nodes_.push_back(node);
    const Eigen::Index n = static_cast<Eigen::Index>(6 * ids_.size());
    Eigen::VectorXd state = Eigen::VectorXd::Zero(n);
    Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(n, n);
    state.head(state_.size()) = state_;
    covariance.topLeftCorner(covariance_.rows(), covariance_.cols()) = covariance_;
    state_ = std::move(state);
    covariance_ = std::move(covariance);
}

void FlightTracks::addBody(NodeId a, NodeId b, double separation_m)
{
    const uint32_t ia = find(a);
    const uint32_t ib = find(b);
    if (ia == kNone || ib == kNone || ia == ib) {
        throw std::invalid_argument("a body needs two distinct nodes tracked in 3D (" + std::to_string(a) + ", " +
                                    std::to_string(b) + ")");
    }
    if (!std::isfinite(separation_m) || !(separation_m > 0.0)) {
        throw std::invalid_argument("the separation of nodes " + std::to_string(a) + " and " + std::to_string(b) +
                                    " on one body must be a positive number of metres");
    }
    for (const Body &body : bodies_) {
        for (const uint32_t i : {ia, ib}) {
            if (body.a == i || body.b == i) {
                throw std::invalid_argument("node " + std::to_string(ids_[i]) + " is already on a body");
            }
        }
    }
    bodies_.push_back({ia, ib, separation_m});
}

void FlightTracks::applyBodies(double dt_s)
{
    // Once per correlation time at most at full weight: predicted often (a range every 0.1 s), the
    // tie is applied as often, and each time with the noise scaled up by tau / dt, so that what it
    // teaches per second does not grow with the ranging rate.
    const double scale = std::max(1.0, motion_.flight_speed_tau_s / dt_s);
    for (const Body &body : bodies_) {
        if (nodes_[body.a].status == FlightStatus::Waiting || nodes_[body.b].status == FlightStatus::Waiting) {
            continue;
        }
        const Eigen::Index ba = 6 * static_cast<Eigen::Index>(body.a);
        const Eigen::Index bb = 6 * static_cast<Eigen::Index>(body.b);
        const double noise_m2 = scale * body.separation_m * body.separation_m / 3.0;
        for (Eigen::Index axis = 0; axis < 3; ++axis) {
            // h = e_a - e_b on this axis; the measurement is 0 (m).
            const Eigen::VectorXd ph = covariance_.col(ba + axis) - covariance_.col(bb + axis);
            const double hph = ph(ba + axis) - ph(bb + axis);
            const double innovation = state_(bb + axis) - state_(ba + axis);
            const Eigen::VectorXd k = ph / (hph + noise_m2);
            state_ += k * innovation;
            covariance_ -= k * ph.transpose();
            covariance_ = 0.5 * (covariance_ + covariance_.transpose());
        }
        ++counters_.body_updates;
    }
}

void FlightTracks::setAnchors(const std::vector<std::pair<NodeId, Vector3>> &anchors)
{
    anchors_ = anchors;
    anchors_set_ = AnchorsState::Set;
    nlos_.clear();
    for (const auto &[id, position] : anchors_) {
        nlos_.push_back({id, 0, 0, 0});
    }
    nlos_.push_back({0, 0, 0, 0}); // the ranges between tracked nodes
    if (anchors_.empty()) {
        return;
    }
    room_lo_m_ = anchors_.front().second;
    room_hi_m_ = anchors_.front().second;
    double z_sum = 0.0;
    for (const auto &[id, position] : anchors_) {
        room_lo_m_ = room_lo_m_.cwiseMin(position);
        room_hi_m_ = room_hi_m_.cwiseMax(position);
        z_sum += position.z();
    }
    plane_z_m_ = z_sum / static_cast<double>(anchors_.size());
    room_lo_m_.head<2>().array() -= kRoomMarginM;
    room_hi_m_.head<2>().array() += kRoomMarginM;
    room_lo_m_.z() = motion_.flight_floor_z_m;
    room_hi_m_.z() = std::max(plane_z_m_, motion_.flight_floor_z_m + 0.1);
}

void FlightTracks::predict(double t_s)
{
    if (t_s_ && t_s > *t_s_) {
        Eigen::Matrix<double, 6, 6> f;
        Eigen::Matrix<double, 6, 6> q;
        transitionOu(t_s - *t_s_, motion_.flight_speed_sigma_mps, motion_.flight_speed_tau_s, f, q);
        const Eigen::Index n = state_.size();
        Eigen::MatrixXd big_f = Eigen::MatrixXd::Identity(n, n);
        for (uint32_t i = 0; i < nodes_.size(); ++i) {
            if (nodes_[i].status != FlightStatus::Waiting) {
                const Eigen::Index b = 6 * static_cast<Eigen::Index>(i);
                big_f.block<6, 6>(b, b) = f;
            }
        }
        state_ = big_f * state_;
        covariance_ = big_f * covariance_ * big_f.transpose();
        for (uint32_t i = 0; i < nodes_.size(); ++i) {
            if (nodes_[i].status != FlightStatus::Waiting) {
                const Eigen::Index b = 6 * static_cast<Eigen::Index>(i);
                covariance_.block<6, 6>(b, b) += q;
            }
        }
        applyBodies(t_s - *t_s_);
    }
    t_s_ = t_s_ ? std::max(*t_s_, t_s) : t_s;
}

void FlightTracks::start(uint32_t node)
{
    const Eigen::Index b = 6 * static_cast<Eigen::Index>(node);
    const Vector3 centre = 0.5 * (room_lo_m_ + room_hi_m_);
    const Vector3 sigma = 0.5 * (room_hi_m_ - room_lo_m_);
    state_.segment<6>(b).setZero();
    state_.segment<3>(b) = centre;
    covariance_.middleRows(b, 6).setZero();
    covariance_.middleCols(b, 6).setZero();
    const double speed_variance = motion_.flight_speed_sigma_mps * motion_.flight_speed_sigma_mps;
    for (Eigen::Index k = 0; k < 3; ++k) {
        covariance_(b + k, b + k) = sigma(k) * sigma(k);
        covariance_(b + 3 + k, b + 3 + k) = speed_variance;
    }
    if (nodes_[node].status == FlightStatus::Waiting) {
        nodes_[node].status = FlightStatus::Starting;
    }
}

FlightRangeUse FlightTracks::update(uint32_t end_a, uint32_t end_b, const Vector3 &anchor_m, double range_m, bool force)
{
    const Eigen::Index ba = 6 * static_cast<Eigen::Index>(end_a);
    const Eigen::Index bb = end_b == kNone ? -1 : 6 * static_cast<Eigen::Index>(end_b);
    const Vector3 other = bb < 0 ? anchor_m : Vector3(state_.segment<3>(bb));
    const RangePrediction3 prediction = predictRange(Vector3(state_.segment<3>(ba)), other);
    const Vector3 unit = prediction.jacobian_point.transpose();
    const double distance = std::max(prediction.range_m, kSingularDistanceM); // m, kept off 0 below
    const Eigen::Index n = state_.size();
    Eigen::VectorXd h = Eigen::VectorXd::Zero(n);
    h.segment<3>(ba) = unit;
    // The covariance of the relative position a - b.
    Matrix3 relative = covariance_.block<3, 3>(ba, ba);
    if (bb >= 0) {
        h.segment<3>(bb) = -unit;
        const Matrix3 cross = covariance_.block<3, 3>(ba, bb);
        relative += covariance_.block<3, 3>(bb, bb) - cross - cross.transpose();
    }
    const Matrix3 across = Matrix3::Identity() - unit * unit.transpose();
    const Matrix3 perpendicular = across * relative * across;
    const double curvature_m2 = perpendicular.squaredNorm() / (2.0 * distance * distance);
    const double noise_m2 = range_sigma_m_ * range_sigma_m_ + curvature_m2;
    const Eigen::VectorXd ph = covariance_ * h;
    const double hph = h.dot(ph);
    const double innovation = range_m - prediction.range_m;
    const double inlier = likelihood_.inlierProbability(innovation, hph + noise_m2);
    if (!force && innovation * innovation > gate_sigma_ * gate_sigma_ * (hph + noise_m2) && inlier < 0.01) {
        return FlightRangeUse::Refused;
    }
    // NLOS-looking ranges count for less (their noise widened by 1 / P(line of sight)).
    const double widened_m2 = force ? noise_m2 : noise_m2 / std::max(inlier, 0.05);
    if (!force && inlier < 0.5) {
        ++counters_.down_weighted;
    }
    const Eigen::VectorXd k = ph / (hph + widened_m2);
    state_ += k * innovation;
    // Joseph form: (I - k h^T) P (I - k h^T)^T + r k k^T, expanded.
    const Eigen::MatrixXd kph = k * ph.transpose();
    covariance_ = covariance_ - kph - kph.transpose() + (hph + widened_m2) * (k * k.transpose());
    covariance_ = 0.5 * (covariance_ + covariance_.transpose());
    return force ? FlightRangeUse::Reset : FlightRangeUse::Used;
}

void FlightTracks::keepInside(uint32_t node)
{
    const Eigen::Index b = 6 * static_cast<Eigen::Index>(node);
    if (state_(b + 2) > plane_z_m_) {
        // The mirror image through the anchors' mean height: z, vz and their rows and columns.
        state_(b + 2) = 2.0 * plane_z_m_ - state_(b + 2);
        state_(b + 5) = -state_(b + 5);
        for (const Eigen::Index i : {b + 2, b + 5}) {
            covariance_.row(i) *= -1.0;
            covariance_.col(i) *= -1.0;
        }
        ++counters_.mirrored;
    }
    bool touched = false;
    for (Eigen::Index axis = 0; axis < 3; ++axis) {
        const Eigen::Index i = b + axis;
        const double variance = covariance_(i, i);
        if (!(variance > 0.0)) {
            continue;
        }
        const double sigma = std::sqrt(variance);
        const double lo = (room_lo_m_(axis) - state_(i)) / sigma;
        const double hi = (room_hi_m_(axis) - state_(i)) / sigma;
        if (lo < -kTruncationSigmas && hi > kTruncationSigmas) {
            continue;
        }
        const auto [mean_t, variance_t] = truncatedMoments(state_(i), sigma, room_lo_m_(axis), room_hi_m_(axis));
        const Eigen::VectorXd column = covariance_.col(i);
        state_ += column * ((mean_t - state_(i)) / variance);
        covariance_ -=
            (column * column.transpose()) * ((variance - std::min(variance_t, variance)) / (variance * variance));
        covariance_ = 0.5 * (covariance_ + covariance_.transpose());
        touched = true;
    }
    counters_.truncated += touched ? 1U : 0U;
}

void FlightTracks::countNlos(size_t entry, FlightRangeUse use, uint64_t down_weighted_before)
{
    FlightNlosCount &count = nlos_[entry];
    if (use == FlightRangeUse::Refused) {
        ++count.refused;
        return;
    }
    ++count.taken;
    count.down_weighted += counters_.down_weighted - down_weighted_before;
}

FlightRangeUse FlightTracks::addRange(NodeId a, NodeId b, double range_m, double t_s)
{
    const uint64_t down_weighted_before = counters_.down_weighted;
    uint32_t ta = find(a);
    uint32_t tb = find(b);
    if (ta == kNone) {
        std::swap(a, b);
        std::swap(ta, tb);
    }
    if (tb == kNone) {
        // To a static node: an anchor when fixed with a known height.
        const Vector3 *anchor_m = anchor(b);
        if (anchor_m == nullptr || ta == kNone) {
            ++counters_.no_anchor;
            return FlightRangeUse::NoAnchor;
        }
        Node &node = nodes_[ta];
        predict(t_s);
        if (node.status == FlightStatus::Waiting) {
            start(ta);
        }
        if (std::find(node.heard.begin(), node.heard.end(), b) == node.heard.end()) {
            node.heard.push_back(b);
            if (node.heard.size() >= kMinAnchors) {
                node.status = FlightStatus::Tracking;
            }
        }
        FlightRangeUse use = update(ta, kNone, *anchor_m, range_m, false);
        if (use == FlightRangeUse::Refused) {
            ++counters_.refused;
            if (++node.refused_in_a_row >= kResetAfterRefused) {
                const FlightStatus status = node.status;
                const Vector3 position = state_.segment<3>(6 * static_cast<Eigen::Index>(ta));
                start(ta);
                state_.segment<3>(6 * static_cast<Eigen::Index>(ta)) = position; // the state kept
                node.status = status;
                node.refused_in_a_row = 0;
                ++counters_.resets;
                use = update(ta, kNone, *anchor_m, range_m, true);
            }
        } else {
            node.refused_in_a_row = 0;
        }
        if (use != FlightRangeUse::Refused) {
            ++counters_.anchor_ranges;
        }
        size_t entry = 0;
        while (anchors_[entry].first != b) {
            ++entry; // found: anchor(b) is not null
        }
        countNlos(entry, use, down_weighted_before);
        keepInside(ta);
        return use;
    }
    // Both ends tracked.
    if (nodes_[ta].status == FlightStatus::Waiting || nodes_[tb].status == FlightStatus::Waiting) {
        ++counters_.waiting;
        return FlightRangeUse::Waiting;
    }
    predict(t_s);
    const FlightRangeUse use = update(ta, tb, Vector3::Zero(), range_m, false);
    if (use == FlightRangeUse::Refused) {
        ++counters_.refused;
    } else {
        ++counters_.tag_ranges;
    }
    countNlos(nlos_.size() - 1, use, down_weighted_before);
    keepInside(ta);
    keepInside(tb);
    return use;
}

std::optional<FlightEstimate> FlightTracks::estimate(NodeId id) const
{
    const uint32_t i = find(id);
    if (i == kNone) {
        return std::nullopt;
    }
    const Eigen::Index b = 6 * static_cast<Eigen::Index>(i);
    FlightEstimate out;
    out.id = id;
    out.status = nodes_[i].status;
    out.position_m = state_.segment<3>(b);
    out.velocity_mps = state_.segment<3>(b + 3);
    out.covariance_m2 = covariance_.block<3, 3>(b, b);
    out.anchors_heard = static_cast<uint32_t>(nodes_[i].heard.size());
    return out;
}

FlightTracks::Saved FlightTracks::saved() const
{
    Saved out;
    for (const Node &node : nodes_) {
        out.nodes.push_back({node.id, node.status, node.heard, node.refused_in_a_row});
    }
    for (const Body &body : bodies_) {
        out.bodies.push_back({ids_[body.a], ids_[body.b], body.separation_m});
    }
    out.anchors_set = anchors_set_ == AnchorsState::Set;
    out.anchors = anchors_;
    out.nlos = nlos_;
    out.state = state_;
    out.covariance = covariance_;
    out.t_s = t_s_;
    out.counters = counters_;
    return out;
}

namespace {

void checkSaved(const FlightTracks::Saved &saved)
{
    const auto fail = [](const std::string &what) { throw std::invalid_argument("the saved 3D tracks " + what); };
    const size_t n = saved.nodes.size();
    const auto size = static_cast<Eigen::Index>(6 * n);
    if (saved.state.size() != size || saved.covariance.rows() != size || saved.covariance.cols() != size) {
        fail("hold " + std::to_string(saved.state.size()) + " state values and a " +
             std::to_string(saved.covariance.rows()) + " x " + std::to_string(saved.covariance.cols()) +
             " covariance for " + std::to_string(n) + " nodes (6 per node)");
    }
    if (!saved.state.allFinite() || !saved.covariance.allFinite() || (saved.t_s && !std::isfinite(*saved.t_s))) {
        fail("hold a value that is not a finite number");
    }
    if (!saved.anchors_set && (!saved.anchors.empty() || !saved.nlos.empty())) {
        fail("have anchors without having taken them");
    }
    if (saved.anchors_set && saved.nlos.size() != saved.anchors.size() + 1) {
        fail("count the NLOS verdicts of " + std::to_string(saved.nlos.size()) + " link kinds for " +
             std::to_string(saved.anchors.size()) + " anchors (one per anchor, then tag to tag)");
    }
    std::vector<NodeId> anchor_ids;
    for (size_t a = 0; a < saved.anchors.size(); ++a) {
        const auto &[id, position] = saved.anchors[a];
        if (!position.allFinite() || saved.nlos[a].anchor != id) {
            fail("have anchor " + std::to_string(id) + " at no finite position or out of its NLOS counts' order");
        }
        anchor_ids.push_back(id);
    }
    if (saved.anchors_set && saved.nlos.back().anchor != 0) {
        fail("do not end their NLOS counts with the ranges between tracked nodes");
    }
    std::vector<NodeId> ids;
    for (const FlightTracks::SavedNode &node : saved.nodes) {
        if (std::find(ids.begin(), ids.end(), node.id) != ids.end()) {
            fail("list node " + std::to_string(node.id) + " twice");
        }
        ids.push_back(node.id);
        if (static_cast<unsigned>(node.status) > static_cast<unsigned>(FlightStatus::Tracking)) {
            fail("give node " + std::to_string(node.id) + " an unknown status");
        }
        for (const NodeId heard : node.heard) {
            if (std::find(anchor_ids.begin(), anchor_ids.end(), heard) == anchor_ids.end()) {
                fail("say node " + std::to_string(node.id) + " heard anchor " + std::to_string(heard) +
                     ", which is no anchor");
            }
        }
    }
}

} // namespace

FlightTracks::RestoreReport FlightTracks::restore(const Saved &saved)
{
    checkSaved(saved);
    RestoreReport report;
    std::vector<uint32_t> from(ids_.size(), kNone); // each declared node's index in `saved`
    for (uint32_t j = 0; j < saved.nodes.size(); ++j) {
        const uint32_t i = find(saved.nodes[j].id);
        if (i == kNone) {
            report.dropped.push_back(saved.nodes[j].id);
        } else {
            from[i] = j;
        }
    }
    const auto n = static_cast<Eigen::Index>(6 * ids_.size());
    Eigen::VectorXd state = Eigen::VectorXd::Zero(n);
    Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(n, n);
    std::vector<Node> nodes;
    for (uint32_t i = 0; i < ids_.size(); ++i) {
        Node node;
        node.id = ids_[i];
        if (from[i] == kNone) {
            report.restarted.push_back(ids_[i]);
            nodes.push_back(node);
            continue;
        }
        const SavedNode &in = saved.nodes[from[i]];
        node.status = in.status;
        node.heard = in.heard;
        node.refused_in_a_row = in.refused_in_a_row;
        nodes.push_back(node);
        const Eigen::Index bi = 6 * static_cast<Eigen::Index>(i);
        const Eigen::Index si = 6 * static_cast<Eigen::Index>(from[i]);
        state.segment<6>(bi) = saved.state.segment<6>(si);
        for (uint32_t k = 0; k < ids_.size(); ++k) {
            if (from[k] != kNone) {
                covariance.block<6, 6>(bi, 6 * static_cast<Eigen::Index>(k)) =
                    saved.covariance.block<6, 6>(si, 6 * static_cast<Eigen::Index>(from[k]));
            }
        }
    }
    report.bodies_differ = saved.bodies.size() != bodies_.size();
    for (size_t k = 0; k < bodies_.size() && !report.bodies_differ; ++k) {
        const SavedBody &in = saved.bodies[k];
        report.bodies_differ =
            in.a != ids_[bodies_[k].a] || in.b != ids_[bodies_[k].b] || in.separation_m != bodies_[k].separation_m;
    }
    if (saved.anchors_set) {
        setAnchors(saved.anchors); // the room, as it was derived
        nlos_ = saved.nlos;
    } else {
        anchors_.clear();
        anchors_set_ = AnchorsState::Unset;
        nlos_.clear();
        room_lo_m_.setZero();
        room_hi_m_.setZero();
        plane_z_m_ = 0.0;
    }
    nodes_ = std::move(nodes);
    state_ = std::move(state);
    covariance_ = std::move(covariance);
    t_s_ = saved.t_s;
    counters_ = saved.counters;
    return report;
}

} // namespace cdro::engine
