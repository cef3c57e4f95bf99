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
    return -x * x - std::log(x) - kLogSqrtPi +
           std::log1p(-0.5 * inv2 + 0.75 * inv2 * inv2 - 1.875 * inv2 * inv2 * inv2);
}

// log EMG(e; S, rate): the density of X + n, X ~ Exp(rate), n ~ N(0, S).
double logEmg(double e, double variance, double rate)
{
    const double sigma = std::sqrt(variance);
    const double x = (rate * variance - e) / (std::sqrt(2.0) * sigma);
    return std::log(0.5 * rate) + 0.5 * rate * rate * variance - rate * e + logErfc(x);
}

// erfcx(x) = exp(x^2) erfc(x) for x >= 0, in (0, 1]: the EMG terms are exp(-e^2 / 2S) times it,
// so the density needs one exponential and two look-ups instead of three exponentials and two
// erfc. A cubic Hermite interpolation on [0, 12] with the exact derivative
// erfcx'(x) = 2x erfcx(x) - 2/sqrt(pi) at nodes 1/128 apart (error below h^4/384 times the
// largest fourth derivative, 12: 1.2e-10, relative 3e-9 at most); beyond, the asymptotic
// series to the x^-12 term (relative error below 2e-11 there).
class ScaledErfc {
public:
    static constexpr double kStep = 1.0 / 128.0;
    static constexpr double kEnd = 12.0;
    static constexpr int kNodes = static_cast<int>(kEnd / kStep) + 1;

    ScaledErfc()
    {
        for (int i = 0; i < kNodes; ++i) {
            const double x = i * kStep;
            // erfc does not underflow below ~26: the product is exact to a few ulps.
            value_[i] = std::exp(x * x) * std::erfc(x);
            slope_[i] = 2.0 * x * value_[i] - kTwoOverSqrtPi;
        }
    }

    double operator()(double x) const
    {
        if (x >= kEnd) {
            const double u = 1.0 / (2.0 * x * x);
            const double series =
                1.0 - u * (1.0 - 3.0 * u * (1.0 - 5.0 * u * (1.0 - 7.0 * u * (1.0 - 9.0 * u * (1.0 - 11.0 * u)))));
            return series / (x * kSqrtPi);
        }
        const double position = x / kStep;
        const int i = static_cast<int>(position);
        const double t = position - i;
        const double t2 = t * t;
        const double t3 = t2 * t;
        return (2.0 * t3 - 3.0 * t2 + 1.0) * value_[i] + (t3 - 2.0 * t2 + t) * kStep * slope_[i] +
               (-2.0 * t3 + 3.0 * t2) * value_[i + 1] + (t3 - t2) * kStep * slope_[i + 1];
    }

private:
    static constexpr double kSqrtPi = 1.77245385090551602730;
    static constexpr double kTwoOverSqrtPi = 1.12837916709551257390;
    double value_[kNodes + 1] = {};
    double slope_[kNodes + 1] = {};
};

// Built once at start-up (a function-local static would test its guard on every call of the hot
// path).
const ScaledErfc kScaledErfc;

// rate/2 exp(rate^2 S/2 - rate e) erfc(x), x = (rate S - e) / sqrt(2S) (an EMG density), given
// gauss = exp(-e^2 / 2S) and exponent = rate^2 S/2 - rate e: for x >= 0 it is
// rate/2 gauss erfcx(x); for x < 0, erfc(x) = 2 - erfc(-x) makes it rate (exp(exponent) - gauss erfcx(-x) / 2).
double emgDensity(double rate, double x, double gauss, double exponent)
{
    if (x >= 0.0) {
        return gauss > 0.0 ? 0.5 * rate * gauss * kScaledErfc(x) : 0.0;
    }
    const double tail = std::exp(exponent);
    return gauss > 0.0 ? rate * (tail - 0.5 * gauss * kScaledErfc(-x)) : rate * tail;
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

RangeLikelihood::Terms RangeLikelihood::terms(double e, double variance) const
{
    Terms out;
    const double lambda = nlos_rate_per_m_;
    const double mu = short_rate_per_m_;
    const double long_exponent = 0.5 * lambda * lambda * variance - lambda * e;
    const double short_exponent = 0.5 * mu * mu * variance + mu * e;
    if (!(long_exponent < 600.0 && short_exponent < 600.0)) {
        return out; // an exponent would overflow: the log-space evaluation
    }
    const double eps = std::clamp(params_.nlos_fraction, 0.0, 1.0 - kShortFraction);
    const double eta = kShortFraction;
    const double sigma = std::sqrt(variance);
    // Beyond ~9 sigma the Gaussian is below 4e-18 of its peak: it and the EMG terms' share of it
    // are nothing next to the rest (exactly 0 here, so the look-ups are skipped).
    const double half_squared = 0.5 * e * e / variance;
    const double gauss = half_squared < 40.0 ? std::exp(-half_squared) : 0.0;
    out.normal = gauss / (sigma * kSqrtTwoPi);
    out.los = (1.0 - eps - eta) * out.normal;
    out.nlos = eps * emgDensity(lambda, (lambda * variance - e) / (kSqrtTwo * sigma), gauss, long_exponent);
    out.shortish = eta * emgDensity(mu, (mu * variance + e) / (kSqrtTwo * sigma), gauss, short_exponent);
    out.total = std::max(out.los + out.nlos + out.shortish + std::max(params_.gross_density_per_m, 0.0), 1e-300);
    out.finite = true;
    return out;
}

ResidualEvaluation RangeLikelihood::evaluate(double residual_m, double variance_m2) const
{
    const double variance = variance_m2 > 1e-12 ? variance_m2 : 1e-12; // also for NaN
    const double e = std::clamp(residual_m, -1e150, 1e150);            // e^2 stays finite
    ResidualEvaluation result;
    if (!params_.robust) {
        result.log_density = -0.5 * e * e / variance - 0.5 * std::log(variance) - kLogSqrtTwoPi;
        result.slope_per_m = -e / variance;
        return result;
    }
    const double eps = std::clamp(params_.nlos_fraction, 0.0, 1.0 - kShortFraction);
    const double eta = kShortFraction;
    const double sigma = std::sqrt(variance);
    if (e > -6.0 * sigma && e < 100.0 && nlos_rate_per_m_ * e < 600.0) {
        // Where nothing underflows (nearly every call): the densities themselves, one logarithm.
        const Terms t = terms(e, variance);
        if (t.finite) {
            result.log_density = std::max(std::log(t.total), -690.0);
            result.inlier_probability = std::clamp(t.los / t.total, 0.0, 1.0);
            result.slope_per_m = (-t.los * e / variance + nlos_rate_per_m_ * (eps * t.normal - t.nlos) -
                                  short_rate_per_m_ * (eta * t.normal - t.shortish)) /
                                 t.total;
            return result;
        }
    }
    // The terms in log space: each underflows somewhere else.
    const double log_normal = -0.5 * e * e / variance - 0.5 * std::log(variance) - kLogSqrtTwoPi;
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
    // The weight update's hot path: the terms themselves wherever no exponent can overflow. A
    // term that underflows is 0 there, which changes nothing next to the floor; only without a
    // floor, or where an exponent would overflow, the log-space evaluation is needed.
    if (params_.robust && params_.gross_density_per_m > 0.0) {
        const Terms t = terms(std::clamp(residual_m, -1e150, 1e150), variance_m2 > 1e-12 ? variance_m2 : 1e-12);
        if (t.finite) {
            return t.total;
        }
    }
    return std::max(std::exp(evaluate(residual_m, variance_m2).log_density), 1e-300);
}

RangeLikelihood::DensityWithInlier RangeLikelihood::densityWithInlier(double residual_m, double variance_m2) const
{
    if (params_.robust && params_.gross_density_per_m > 0.0) {
        const Terms t = terms(std::clamp(residual_m, -1e150, 1e150), variance_m2 > 1e-12 ? variance_m2 : 1e-12);
        if (t.finite) {
            return {t.total, std::clamp(t.los / t.total, 0.0, 1.0)};
        }
    }
    const ResidualEvaluation evaluation = evaluate(residual_m, variance_m2);
    return {std::max(std::exp(evaluation.log_density), 1e-300), evaluation.inlier_probability};
}

double RangeLikelihood::inlierProbability(double residual_m, double variance_m2) const
{
    // The refinement's weights: the responsibility of the line-of-sight term, no logarithm.
    if (params_.robust && params_.gross_density_per_m > 0.0) {
        const Terms t = terms(std::clamp(residual_m, -1e150, 1e150), variance_m2 > 1e-12 ? variance_m2 : 1e-12);
        if (t.finite) {
            return std::clamp(t.los / t.total, 0.0, 1.0);
        }
    }
    return evaluate(residual_m, variance_m2).inlier_probability;
}

double RangeLikelihood::irlsWeight(double residual_m, double variance_m2) const
{
    return irlsWeight(residual_m, variance_m2, evaluate(residual_m, std::max(variance_m2, 1e-12)));
}

double RangeLikelihood::irlsWeight(double residual_m, double variance_m2, const ResidualEvaluation &at) const
{
    const double variance = std::max(variance_m2, 1e-12);
    if (std::abs(residual_m) < 1e-6 * std::sqrt(variance)) {
        return evaluate(0.0, variance).inlier_probability / variance;
    }
    return std::max(-at.slope_per_m / residual_m, 0.0);
}

} // namespace cdro::engine
