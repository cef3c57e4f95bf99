#include "cdro/engine/range_likelihood.hpp"

#include <algorithm>
#include <cmath>

namespace cdro::engine {

namespace {
constexpr double kInvSqrtTwoPi = 0.39894228040143267794;
} // namespace

double RangeLikelihood::nlosDensity(double residual_m, double variance_m2) const
{
    if (!(residual_m > 0.0)) {
        return 0.0;
    }
    const double excess = nlos_rate_per_m_ * residual_m;
    if (excess >= 40.0) {
        return 0.0; // exp(-40): far below the floor
    }
    // The NLOS term rises from 0 over the first standard deviation instead of jumping: a
    // density that is discontinuous at e = 0 would make a slightly long fit cheaper than an
    // exact one.
    const double ramp = std::min(residual_m / std::sqrt(std::max(variance_m2, 1e-12)), 1.0);
    return std::clamp(params_.nlos_fraction, 0.0, 1.0) * nlos_rate_per_m_ * std::exp(-excess) * ramp;
}

RangeLikelihood::RangeLikelihood(const RangeLikelihoodParams &params)
    : params_(params), nlos_rate_per_m_(1.0 / std::max(params.nlos_mean_excess_m, 1e-6))
{
}

ResidualEvaluation RangeLikelihood::evaluate(double residual_m, double variance_m2) const
{
    const double variance = std::max(variance_m2, 1e-12);
    const double normalised = residual_m * residual_m / variance;
    ResidualEvaluation result;
    if (!params_.robust) {
        result.log_density = -0.5 * normalised - 0.5 * std::log(variance) + std::log(kInvSqrtTwoPi);
        result.inlier_probability = 1.0;
        return result;
    }
    const double eps = std::clamp(params_.nlos_fraction, 0.0, 1.0);
    const double line_of_sight = (1.0 - eps) * kInvSqrtTwoPi / std::sqrt(variance) * std::exp(-0.5 * normalised);
    const double nlos = nlosDensity(residual_m, variance);
    // The floor keeps log() finite even when every term underflows (a residual of kilometres).
    const double total = std::max(line_of_sight + nlos + params_.gross_density_per_m, 1e-300);
    result.log_density = std::log(total);
    result.inlier_probability = total > 0.0 ? line_of_sight / total : 0.0;
    return result;
}

double RangeLikelihood::inlierProbability(double residual_m, double variance_m2) const
{
    if (!params_.robust) {
        return 1.0;
    }
    const double variance = std::max(variance_m2, 1e-12);
    const double normalised = residual_m * residual_m / variance;
    if (normalised >= 80.0) {
        return 0.0;
    }
    const double eps = std::clamp(params_.nlos_fraction, 0.0, 1.0);
    const double line_of_sight = (1.0 - eps) * kInvSqrtTwoPi / std::sqrt(variance) * std::exp(-0.5 * normalised);
    const double nlos = nlosDensity(residual_m, variance);
    return line_of_sight / (line_of_sight + nlos + params_.gross_density_per_m + 1e-300);
}

double RangeLikelihood::density(double residual_m, double variance_m2) const
{
    const double variance = std::max(variance_m2, 1e-12);
    const double normalised = residual_m * residual_m / variance;
    if (!params_.robust) {
        return kInvSqrtTwoPi / std::sqrt(variance) * std::exp(-0.5 * normalised);
    }
    const double eps = std::clamp(params_.nlos_fraction, 0.0, 1.0);
    double total = params_.gross_density_per_m;
    // exp(-0.5 * 80) = 4e-18: far below any floor, not worth an exponential.
    if (normalised < 80.0) {
        total += (1.0 - eps) * kInvSqrtTwoPi / std::sqrt(variance) * std::exp(-0.5 * normalised);
    }
    total += nlosDensity(residual_m, variance);
    return std::max(total, 1e-300);
}

} // namespace cdro::engine
