// range_likelihood.hpp: how plausible a range residual is, for the weight update, the
// placement and the refinement.
//
// UWB ranges are Gaussian around the truth in line of sight, but behind walls and metal they
// read long (non-line-of-sight, NLOS): the first path is blocked and a later one is timed. The
// PLANT data has 5 % of its ranges more than 1 m too long, and 7 links whose median is off by
// over 1 m. A Gaussian likelihood lets one such link veto the right answer, so the robust model
// is a mixture of the residual e = measured - predicted (m) with predictive variance S (m^2):
//
//     p(e) = (1 - eps) N(e; 0, S)                       line of sight
//          + eps  lambda exp(-lambda e) min(e / sqrt(S), 1)   for e > 0
//                                                   NLOS: reads long, excess ~ Exp(mean 1/lambda),
//                                                   ramped in over one std (continuous at 0)
//          + floor                                      gross errors of any sign, any size
//
// It is redescending: a residual far outside the Gaussian costs a bounded amount, so a bad
// link is effectively dropped instead of pulling the solution (a Huber loss keeps pulling;
// on PLANT that is the difference between 0.51 m and 0.23 m). The NLOS term is one-sided and
// decays, so a reading far too long is not free either (which decides reflections that a
// symmetric, flat outlier term would leave ambiguous). `robust = false` gives the paper's
// plain Gaussian. The inlier probability is the EM weight of the line-of-sight term.
#pragma once

namespace cdro::engine {

struct RangeLikelihoodParams {
    bool robust = true;                 // false: the paper's Gaussian only
    double nlos_fraction = 0.1;         // eps, prior probability of an NLOS reading, 0..1
    double nlos_mean_excess_m = 1.0;    // m, 1/lambda: mean of how much too long NLOS reads
    double gross_density_per_m = 1e-4;  // 1/m, floor of the density for errors of any size
};

struct ResidualEvaluation {
    double log_density = 0.0;          // log p(e), log(1/m)
    double inlier_probability = 1.0;   // P(line of sight | e), 0..1
};

class RangeLikelihood {
public:
    explicit RangeLikelihood(const RangeLikelihoodParams &params = {});

    // residual_m = measured - predicted (m); variance_m2 > 0 (m^2).
    ResidualEvaluation evaluate(double residual_m, double variance_m2) const;
    double logDensity(double residual_m, double variance_m2) const { return evaluate(residual_m, variance_m2).log_density; }
    // P(line of sight | e) alone (no logarithm): the Gauss-Newton weights.
    double inlierProbability(double residual_m, double variance_m2) const;
    // p(e) itself (1/m), without the logarithm: the weight update multiplies these. Terms that
    // cannot matter next to the others are not computed (their exponentials underflow).
    double density(double residual_m, double variance_m2) const;

    const RangeLikelihoodParams &params() const { return params_; }

private:
    double nlosDensity(double residual_m, double variance_m2) const;

    RangeLikelihoodParams params_;
    double nlos_rate_per_m_; // lambda, 1/m
};

} // namespace cdro::engine
