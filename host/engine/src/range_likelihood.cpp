#include "cdro/engine/range_likelihood.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace cdro::engine {

namespace {

constexpr double kLogSqrtTwoPi = 0.91893853320467274178;
constexpr double kLogSqrtPi = 0.57236494292470008707;
constexpr double kSqrtTwoPi = 2.50662827463100050242;
constexpr double kSqrtTwo = 1.41421356237309504880;
constexpr double kMinusInfinity = -std::numeric_limits<double>::infinity();

// log erfc(x), also where erfc underflows (x beyond ~26): the asymptotic series there.
double logErfc(double x)
{
    if (x < 4.0) {
        return std::log(std::erfc(x));
    }
    const double inv2 = 1.0 / (x * x);
    return -x * x - std::log(x) - kLogSqrtPi + std::log1p(-0.5 * inv2 + 0.75 * inv2 * inv2 - 1.875 * inv2 * inv2 * inv2);
}

// log EMG(e; S, rate): the density of X + n, X ~ Exp(rate), n ~ N(0, S).
double logEmg(double e, double variance, double rate)
{
    const double sigma = std::sqrt(variance);
    const double x = (rate * variance - e) / (std::sqrt(2.0) * sigma);
    return std::log(0.5 * rate) + 0.5 * rate * rate * variance - rate * e + logErfc(x);
}

double logSumExp(double a, double b)
{
    const double high = std::max(a, b);
    if (!std::isfinite(high)) {
        return high;
    }
    return high + std::log(std::exp(a - high) + std::exp(b - high));
}

} // namespace

RangeLikelihood::RangeLikelihood(const RangeLikelihoodParams &params)
    : params_(params), nlos_rate_per_m_(1.0 / std::max(params.nlos_mean_excess_m, 1e-6)),
      short_rate_per_m_(1.0 / kShortMeanM)
{
}

ResidualEvaluation RangeLikelihood::evaluate(double residual_m, double variance_m2) const
{
    const double variance = variance_m2 > 1e-12 ? variance_m2 : 1e-12; // also for NaN
    const double e = std::clamp(residual_m, -1e150, 1e150); // e^2 stays finite
    const double log_normal = -0.5 * e * e / variance - 0.5 * std::log(variance) - kLogSqrtTwoPi;
    ResidualEvaluation result;
    if (!params_.robust) {
        result.log_density = log_normal;
        result.slope_per_m = -e / variance;
        return result;
    }
    const double eps = std::clamp(params_.nlos_fraction, 0.0, 1.0 - kShortFraction);
    const double eta = kShortFraction;
    const double sigma = std::sqrt(variance);
    if (e > -6.0 * sigma && e < 100.0 && nlos_rate_per_m_ * e < 600.0 &&
        0.5 * short_rate_per_m_ * short_rate_per_m_ * variance + short_rate_per_m_ * e < 600.0 &&
        0.5 * nlos_rate_per_m_ * nlos_rate_per_m_ * variance < 600.0) {
        // Where nothing underflows (nearly every call): the densities themselves, one logarithm.
        const double normal = std::exp(-0.5 * e * e / variance) / (sigma * kSqrtTwoPi);
        const double lambda = nlos_rate_per_m_;
        const double mu = short_rate_per_m_;
        const double emg_long = 0.5 * lambda * std::exp(0.5 * lambda * lambda * variance - lambda * e) *
                                std::erfc((lambda * variance - e) / (kSqrtTwo * sigma));
        const double emg_short = 0.5 * mu * std::exp(0.5 * mu * mu * variance + mu * e) *
                                 std::erfc((mu * variance + e) / (kSqrtTwo * sigma));
        const double los = (1.0 - eps - eta) * normal;
        const double nlos = eps * emg_long;
        const double shortish = eta * emg_short;
        const double total = std::max(los + nlos + shortish + std::max(params_.gross_density_per_m, 0.0), 1e-300);
        result.log_density = std::max(std::log(total), -690.0);
        result.inlier_probability = std::clamp(los / total, 0.0, 1.0);
        result.slope_per_m = (-los * e / variance + lambda * (eps * normal - nlos) - mu * (eta * normal - shortish)) / total;
        return result;
    }
    // The terms in log space: each underflows somewhere else.
    const double log_los = std::log(1.0 - eps - eta) + log_normal;
    const double log_long = eps > 0.0 ? std::log(eps) + logEmg(e, variance, nlos_rate_per_m_) : kMinusInfinity;
    const double log_short = std::log(eta) + logEmg(-e, variance, short_rate_per_m_);
    const double log_floor = params_.gross_density_per_m > 0.0 ? std::log(params_.gross_density_per_m) : kMinusInfinity;
    const double log_total = std::max(logSumExp(logSumExp(log_los, log_long), logSumExp(log_short, log_floor)), -690.0);
    result.log_density = log_total;
    const double p_los = std::exp(log_los - log_total);
    const double p_long = std::exp(log_long - log_total);
    const double p_short = std::exp(log_short - log_total);
    result.inlier_probability = std::clamp(p_los, 0.0, 1.0);
    // d/de of each term over p: N' = -e/S N; EMG'(e; rate) = rate (N - EMG) (the normal density
    // without the mixture weight), and the short term is mirrored.
    const double normal_over_total = std::exp(log_normal - log_total);
    result.slope_per_m = -p_los * e / variance + nlos_rate_per_m_ * (eps * normal_over_total - p_long) -
                         short_rate_per_m_ * (eta * normal_over_total - p_short);
    return result;
}

double RangeLikelihood::density(double residual_m, double variance_m2) const
{
    return std::max(std::exp(evaluate(residual_m, variance_m2).log_density), 1e-300);
}

double RangeLikelihood::irlsWeight(double residual_m, double variance_m2) const
{
    const double variance = std::max(variance_m2, 1e-12);
    if (std::abs(residual_m) < 1e-6 * std::sqrt(variance)) {
        // The limit at e = 0: the curvature of the line-of-sight term, as much as it carries.
        return evaluate(0.0, variance).inlier_probability / variance;
    }
    const ResidualEvaluation at = evaluate(residual_m, variance);
    return std::max(-at.slope_per_m / residual_m, 0.0);
}

} // namespace cdro::engine
