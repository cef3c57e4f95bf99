// range_likelihood.hpp: how plausible a range residual is, for the weight update, the
// placement, the refinement and the global solve.
//
// UWB ranges are Gaussian around the truth in line of sight, but behind walls and metal they
// read long (non-line-of-sight, NLOS): the first path is blocked and a later one is timed.
// PLANT has 5 % of its ranges more than 1 m too long and 7 links whose median is off by over
// 1 m; the labelled DW1000 ranges of kolakowski-nlos read +0.35 m (NLOS) and +0.9 m (no direct
// path, up to +3.1 m) long, never short. A Gaussian likelihood lets one such link veto the right
// answer, so the robust model of a residual e = measured - predicted (m), predictive variance
// S (m^2), is a mixture:
//
//     p(e) = (1 - eps - eta) N(e; 0, S)        line of sight
//          + eps  EMG(e; S, lambda)            NLOS: the reading is long by an excess
//                                              X ~ Exp(mean 1/lambda), plus the noise
//          + eta  EMG(-e; S, mu)               a rare reading short by Exp(mean 1/mu)
//          + floor                             an unexplained range (gross_density_per_m)
//
// EMG is the exponentially modified Gaussian (the density of X + noise): smooth, with a cost
// that grows linearly (slope lambda) for long readings. The model is one-sided: a reading far
// too long is possible but not free, and one that is too short hardly at all (mu >> lambda),
// so a map cannot stretch a link and write it off as NLOS. The floor bounds what one residual
// can cost: the streaming steps need it (a neighbour they lean on may itself be misplaced, and
// one such neighbour must not veto the right answer); the global solve, which moves every node
// at once, takes the model without it (floor 0), so that a misplaced part is always pulled
// back. `robust = false` gives the paper's plain Gaussian. The inlier probability is the
// responsibility of the line-of-sight term.
#pragma once

namespace cdro::engine {

struct RangeLikelihoodParams {
    bool robust = true;                // false: the paper's Gaussian only
    double nlos_fraction = 0.1;        // eps, prior probability of an NLOS reading, 0..1
    double nlos_mean_excess_m = 1.0;   // m, 1/lambda: mean of how much too long NLOS reads
    double gross_density_per_m = 1e-4; // 1/m, floor of the density: an unexplained range
};

struct ResidualEvaluation {
    double log_density = 0.0;        // log p(e), log(1/m)
    double inlier_probability = 1.0; // P(line of sight | e), 0..1
    double slope_per_m = 0.0;        // d log p / de (1/m): minus the residual's influence
};

class RangeLikelihood {
public:
    explicit RangeLikelihood(const RangeLikelihoodParams &params = {});

    // The readings short by more than the noise: their share (eta) and mean (1/mu). Not a
    // parameter: no building makes UWB read short; the term only keeps a rare glitch finite.
    static constexpr double kShortFraction = 0.005;
    static constexpr double kShortMeanM = 0.3; // m

    // residual_m = measured - predicted (m); variance_m2 > 0 (m^2).
    ResidualEvaluation evaluate(double residual_m, double variance_m2) const;
    double logDensity(double residual_m, double variance_m2) const
    {
        return evaluate(residual_m, variance_m2).log_density;
    }
    // evaluate()'s inlier probability (to rounding), without its logarithm.
    double inlierProbability(double residual_m, double variance_m2) const;
    // p(e) itself (1/m): the weight update multiplies these (clamped at 1e-300).
    double density(double residual_m, double variance_m2) const;
    // density() and inlierProbability() of one residual, the mixture's terms evaluated once.
    struct DensityWithInlier {
        double density_per_m = 0.0;
        double inlier_probability = 1.0; // 0..1
    };
    DensityWithInlier densityWithInlier(double residual_m, double variance_m2) const;
    // Iteratively reweighted least squares: the weight w(e) = -slope / e (1/m^2), the curvature of
    // the quadratic that touches the cost -log p at e (0 where the cost is not increasing in |e|).
    double irlsWeight(double residual_m, double variance_m2) const;
    // The same from evaluate(residual_m, variance_m2), already at hand.
    double irlsWeight(double residual_m, double variance_m2, const ResidualEvaluation &at) const;

    const RangeLikelihoodParams &params() const { return params_; }

private:
    // The mixture's terms (1/m) in linear space, with the floor in `total`; not `finite` where an
    // exponent would overflow (then the log-space evaluation serves).
    struct Terms {
        bool finite = false;
        double normal = 0.0;   // N(e; 0, S)
        double los = 0.0;      // (1 - eps - eta) N
        double nlos = 0.0;     // eps EMG(e; S, lambda)
        double shortish = 0.0; // eta EMG(-e; S, mu)
        double total = 0.0;    // their sum with the floor, at least 1e-300
    };
    Terms terms(double residual_m, double variance_m2) const;

    RangeLikelihoodParams params_;
    double nlos_rate_per_m_;  // lambda, 1/m
    double short_rate_per_m_; // mu, 1/m
};

} // namespace cdro::engine
