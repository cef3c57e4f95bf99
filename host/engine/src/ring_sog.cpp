#include "cdro/engine/ring_sog.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

namespace {
constexpr double kTwoPi = 6.28318530717958647692;

// An update's working lists: which components it touches and each one's likelihood. One set a
// thread, not one a ring: they hold nothing between updates, and at 10,000 rings of ~70
// components kept in every ring they were 11 MB of the engine's state (docs/bench.md).
struct UpdateBuffers {
    std::vector<uint32_t> active;
    std::vector<double> likelihood;
};

UpdateBuffers &updateBuffers()
{
    thread_local UpdateBuffers buffers;
    return buffers;
}

} // namespace

RingSog RingSog::generate(NodeId center, NodeId target, const Vector2 &center_m, double range_m,
                          const RingSogParams &params, const Matrix2 &center_covariance_m2)
{
    RingSog ring;
    ring.center_ = center;
    ring.target_ = target;
    ring.offset_m_ = center_m;
    const double radius_m = std::max(range_m, 0.0);
    const double spacing_m = std::max(params.arc_spacing_m, 1e-3);
    const double wanted = std::floor(kTwoPi * radius_m / spacing_m) + 1.0;
    const uint32_t lower = std::max<uint32_t>(params.min_components, 1U);
    const uint32_t upper = std::max(params.max_components, lower);
    const uint32_t count =
        static_cast<uint32_t>(std::clamp(wanted, static_cast<double>(lower), static_cast<double>(upper)));
    // The floor must stay well below 1/N, or it would flatten every ring.
    ring.weight_floor_ = std::min(params.weight_floor, 0.1 / count);

    const double radial_variance = params.radial_sigma_m * params.radial_sigma_m;
    const double tangential_sigma =
        std::max(kTwoPi * radius_m / count / std::max(params.tangential_overlap, 1e-3), params.min_tangential_sigma_m);
    const double tangential_variance = tangential_sigma * tangential_sigma;
    ring.components_.resize(count);
    for (uint32_t k = 0; k < count; ++k) {
        const double angle = kTwoPi * k / count;
        const Vector2 radial(std::cos(angle), std::sin(angle));
        const Vector2 tangential(-radial.y(), radial.x());
        SogComponentState &component = ring.components_[k];
        component.mean_m = radius_m * radial;
        component.covariance_m2 =
            radial_variance * radial * radial.transpose() + tangential_variance * tangential * tangential.transpose();
        if (!center_covariance_m2.isZero(0.0)) {
            component.covariance_m2 += center_covariance_m2;
        }
        component.weight = 1.0 / count;
    }
    ring.refreshMoments();
    return ring;
}

void RingSog::collectActive(bool full, std::vector<uint32_t> &active) const
{
    active.clear();
    if (full) {
        for (uint32_t k = 0; k < components_.size(); ++k) {
            active.push_back(k);
        }
        return;
    }
    double heaviest_weight = 0.0;
    for (const SogComponentState &component : components_) {
        heaviest_weight = std::max(heaviest_weight, component.weight);
    }
    const double threshold = kActiveRatio * heaviest_weight;
    for (uint32_t k = 0; k < components_.size(); ++k) {
        if (components_[k].weight >= threshold) {
            active.push_back(k);
        }
    }
}

RangeUpdateResult RingSog::updateWithRange(const Vector2 &center_m, const Matrix2 &center_covariance_m2, double range_m,
                                           double noise_variance_m2, const RangeTerms &terms,
                                           const RingUpdateRule &rule)
{
    RangeUpdateResult result;
    const double noise_variance = noise_variance_m2;
    const double gate_squared = rule.gate_sigma * rule.gate_sigma;
    const Vector2 center_relative = center_m - offset_m_;
    UpdateBuffers &buffers = updateBuffers();
    std::vector<uint32_t> &active = buffers.active;
    std::vector<double> &scratch = buffers.likelihood;
    collectActive(rule.full, active);
    if (rule.weigh_by != nullptr) {
        // A component that takes no information from the range keeps its weight.
        scratch.assign(components_.size(), 1.0);
    }
    for (uint32_t k : active) {
        SogComponentState &component = components_[k];
        component.covariance_m2.diagonal().array() += rule.process_noise_m2;
        const RangePrediction prediction =
            predictRange(component.mean_m, center_relative, terms.height_difference_m, terms.scale, terms.offset_m);
        if (prediction.singular) {
            continue;
        }
        const Eigen::RowVector2d h = prediction.jacobian_point;
        const Eigen::Vector2d covariance_h = component.covariance_m2 * h.transpose();
        // The centre's uncertainty enters as extra measurement noise (it is not in this state).
        const double innovation_variance =
            (h * covariance_h).value() + (h * center_covariance_m2 * h.transpose()).value() + noise_variance;
        const double innovation = range_m - prediction.range_m;
        if (rule.weigh_by != nullptr) {
            scratch[k] = rule.weigh_by->density(innovation, innovation_variance);
        }
        if (innovation * innovation > gate_squared * innovation_variance) {
            ++result.gated;
            continue;
        }
        const Eigen::Vector2d gain = covariance_h / innovation_variance;
        component.mean_m += gain * innovation;
        // Joseph form: stays symmetric positive definite under rounding.
        const Matrix2 keep = Matrix2::Identity() - gain * h;
        component.covariance_m2 = keep * component.covariance_m2 * keep.transpose() +
                                  (innovation_variance - (h * covariance_h).value()) * gain * gain.transpose();
        ++result.updated;
    }
    if (rule.weigh_by != nullptr) {
        applyLikelihood(scratch, false);
    }
    refreshMoments();
    return result;
}

uint32_t RingSog::prune(double ratio)
{
    if (components_.empty()) {
        return 0;
    }
    const double threshold = ratio * components_[heaviest()].weight;
    const size_t before = components_.size();
    components_.erase(std::remove_if(components_.begin(), components_.end(),
                                     [threshold](const SogComponentState &c) { return c.weight < threshold; }),
                      components_.end());
    normalise();
    return static_cast<uint32_t>(before - components_.size());
}

WeightUpdateResult RingSog::updateWeights(const std::vector<RangeWitness> &witnesses, const RangeLikelihood &likelihood,
                                          double range_sigma_m, bool full, bool allow_reset)
{
    WeightUpdateResult result;
    if (witnesses.empty() || components_.empty()) {
        return result;
    }
    const double noise_variance = range_sigma_m * range_sigma_m;
    const uint32_t best = heaviest();
    UpdateBuffers &buffers = updateBuffers();
    std::vector<uint32_t> &active = buffers.active;
    std::vector<double> &scratch = buffers.likelihood;
    collectActive(full, active);
    // Components left out of a partial update get no evidence: they stay at the floor.
    scratch.assign(components_.size(), full ? 1.0 : 0.0);
    for (uint32_t k : active) {
        scratch[k] = 1.0;
    }
    for (const RangeWitness &witness : witnesses) {
        const Vector2 witness_relative = witness.position_m - offset_m_;
        double largest = 0.0;
        for (uint32_t k : active) {
            const SogComponentState &component = components_[k];
            const RangePrediction prediction = predictRange(component.mean_m, witness_relative);
            const Eigen::RowVector2d h = prediction.jacobian_point;
            const double variance =
                noise_variance + (h * (component.covariance_m2 + witness.covariance_m2) * h.transpose()).value();
            const double residual = witness.range_m - prediction.range_m;
            if (k == best) {
                const RangeLikelihood::DensityWithInlier at = likelihood.densityWithInlier(residual, variance);
                scratch[k] *= at.density_per_m;
                result.downweighted += at.inlier_probability < 0.5 ? 1U : 0U;
            } else {
                scratch[k] *= likelihood.density(residual, variance);
            }
            largest = std::max(largest, scratch[k]);
        }
        // Products of many small densities: keep them representable (only ratios matter).
        if (largest > 0.0 && largest < 1e-200) {
            for (double &value : scratch) {
                value *= 1e200;
            }
        }
    }
    // Only a full update sees the whole ring, so only it can tell that the ring collapsed.
    result.collapsed = applyLikelihood(scratch, full && allow_reset);
    return result;
}

bool RingSog::applyLikelihood(const std::vector<double> &likelihood, bool allow_reset)
{
    const size_t count = components_.size();
    if (likelihood.size() != count || count == 0) {
        return false;
    }
    double best = 0.0;
    for (double value : likelihood) {
        best = std::max(best, value);
    }
    if (!(best > 0.0) || !std::isfinite(best)) {
        return false; // no usable evidence: the weights stay as they are
    }
    // How much of the ring agrees with the evidence: sum_k w_k l_k / max l, in (0, 1].
    double agreement = 0.0;
    for (size_t k = 0; k < count; ++k) {
        agreement += components_[k].weight * (likelihood[k] / best);
    }
    // Only floor-level weights support the evidence: the ring has collapsed onto a wrong mode.
    // Start again from the evidence alone (EKF-GSF's reset), and say so.
    const bool collapsed = allow_reset && !(agreement > 10.0 * weight_floor_);
    for (size_t k = 0; k < count; ++k) {
        const double relative = likelihood[k] / best;
        components_[k].weight = collapsed ? relative : components_[k].weight * relative;
    }
    normalise();
    return collapsed;
}

bool RingSog::normalise()
{
    const size_t count = components_.size();
    if (count == 0) {
        return true;
    }
    double sum = 0.0;
    for (const SogComponentState &component : components_) {
        sum += component.weight;
    }
    bool ok = true;
    if (!(sum > 0.0) || !std::isfinite(sum)) {
        for (SogComponentState &component : components_) {
            component.weight = 1.0 / static_cast<double>(count);
        }
        ok = false;
    } else {
        double floored_sum = 0.0;
        for (SogComponentState &component : components_) {
            component.weight = std::max(component.weight / sum, weight_floor_);
            floored_sum += component.weight;
        }
        for (SogComponentState &component : components_) {
            component.weight /= floored_sum;
        }
    }
    refreshMoments();
    return ok;
}

void RingSog::transferWeights(double sigma_w_m)
{
    if (components_.empty()) {
        return;
    }
    const Vector2 best = components_[heaviest()].mean_m;
    const double inverse_two_variance = 0.5 / std::max(sigma_w_m * sigma_w_m, 1e-12);
    for (SogComponentState &component : components_) {
        const double exponent = (component.mean_m - best).squaredNorm() * inverse_two_variance;
        // Beyond exp(-40) the floor takes over anyway.
        component.weight = exponent < 40.0 ? std::exp(-exponent) : 0.0;
    }
    normalise();
}

void RingSog::applyRigid(const Matrix2 &rotation, const Vector2 &translation_m)
{
    for (SogComponentState &component : components_) {
        component.mean_m = rotation * component.mean_m;
        component.covariance_m2 = rotation * component.covariance_m2 * rotation.transpose();
    }
    offset_m_ = rotation * offset_m_ + translation_m;
    refreshMoments();
}

void RingSog::refreshMoments() { moments_stale_ = true; }

void RingSog::computeMoments() const
{
    moments_stale_ = false;
    first_moment_m_.setZero();
    second_moment_m2_.setZero();
    for (const SogComponentState &component : components_) {
        first_moment_m_ += component.weight * component.mean_m;
        second_moment_m2_ +=
            component.weight * (component.covariance_m2 + component.mean_m * component.mean_m.transpose());
    }
}

void RingSog::accumulateMoments(Vector2 *first_m, Matrix2 *second_m2, double *total) const
{
    if (components_.empty()) {
        return;
    }
    if (moments_stale_) {
        computeMoments();
    }
    // Shift the cached moments (relative to the offset) to absolute: m = r + o.
    *first_m += first_moment_m_ + offset_m_;
    *second_m2 += second_moment_m2_ + first_moment_m_ * offset_m_.transpose() +
                  offset_m_ * first_moment_m_.transpose() + offset_m_ * offset_m_.transpose();
    *total += 1.0;
}

Gaussian2 RingSog::moments() const
{
    Gaussian2 result;
    if (components_.empty()) {
        return result;
    }
    if (moments_stale_) {
        computeMoments();
    }
    result.mean_m = first_moment_m_ + offset_m_;
    // Centred on the ring's own mean, in relative coordinates (no cancellation).
    result.covariance_m2 = second_moment_m2_ - first_moment_m_ * first_moment_m_.transpose();
    return result;
}

uint32_t RingSog::heaviest() const
{
    uint32_t best = 0;
    for (uint32_t k = 1; k < components_.size(); ++k) {
        if (components_[k].weight > components_[best].weight) {
            best = k;
        }
    }
    return best;
}

std::vector<SogComponentState> RingSog::components() const
{
    std::vector<SogComponentState> out = components_;
    for (SogComponentState &component : out) {
        component.mean_m += offset_m_;
    }
    return out;
}

SogComponentState RingSog::component(uint32_t k) const
{
    SogComponentState out = components_[k];
    out.mean_m += offset_m_;
    return out;
}

void RingSog::setAbsoluteComponents(std::vector<SogComponentState> components)
{
    components_ = std::move(components);
    offset_m_.setZero();
    refreshMoments();
}

void RingSog::setComponents(const std::vector<SogComponentState> &components)
{
    components_ = components;
    offset_m_.setZero();
    if (!components_.empty()) {
        // Relative to the first mean: keeps the stored numbers small.
        offset_m_ = components_.front().mean_m;
        for (SogComponentState &component : components_) {
            component.mean_m -= offset_m_;
        }
    }
    normalise();
}

} // namespace cdro::engine
