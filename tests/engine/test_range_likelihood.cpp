// range_likelihood: the ways of asking (density, logDensity, evaluate, inlierProbability,
// densityWithInlier) agree;
// the Gaussian mode is the normal pdf; the robust mode is one-sided; with its floor it is bounded
// and redescending (the streaming steps), without it (the global solve) long readings cost
// linearly and short ones far more, never nothing; the slope is the derivative of the log density.
#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {
namespace {

constexpr double kPi = 3.14159265358979323846;

double normalPdf(double e, double variance)
{
    return std::exp(-0.5 * e * e / variance) / std::sqrt(2.0 * kPi * variance);
}

RangeLikelihoodParams gaussian()
{
    RangeLikelihoodParams params;
    params.robust = false;
    return params;
}

const double kResiduals_m[] = {-1e6, -50.0, -3.0, -1.0, -0.31, -0.1, -0.02, 0.0, 0.02,
                               0.1,  0.31,  1.0,  2.5,  7.0,   45.0, 1e3,   1e6};
const double kVariances_m2[] = {1e-6, 1e-4, 0.01, 0.0169, 0.25, 4.0};

void expectConsistent(const RangeLikelihood &likelihood)
{
    for (double e : kResiduals_m) {
        for (double s : kVariances_m2) {
            SCOPED_TRACE(::testing::Message() << "e " << e << " m, S " << s << " m^2");
            const ResidualEvaluation evaluation = likelihood.evaluate(e, s);
            ASSERT_TRUE(std::isfinite(evaluation.log_density));
            EXPECT_EQ(likelihood.logDensity(e, s), evaluation.log_density);
            const double density = likelihood.density(e, s);
            ASSERT_GT(density, 0.0);
            // density() and inlierProbability() compute the terms in linear space (the EMG terms
            // through an erfcx table, relative error below 3e-9) where evaluate() may use logs.
            EXPECT_NEAR(std::log(density), evaluation.log_density, 1e-8 * (1.0 + std::abs(evaluation.log_density)));
            EXPECT_NEAR(likelihood.inlierProbability(e, s), evaluation.inlier_probability,
                        1e-8 * evaluation.inlier_probability + 1e-15);
            // The weight update's query of both at once gives exactly what the two give apart.
            const RangeLikelihood::DensityWithInlier both = likelihood.densityWithInlier(e, s);
            EXPECT_EQ(both.density_per_m, density);
            EXPECT_EQ(both.inlier_probability, likelihood.inlierProbability(e, s));
            EXPECT_GE(evaluation.inlier_probability, 0.0);
            EXPECT_LE(evaluation.inlier_probability, 1.0);
        }
    }
}

TEST(RangeLikelihood, TheFourQueriesAgreeRobust) { expectConsistent(RangeLikelihood()); }

TEST(RangeLikelihood, TheFourQueriesAgreeGaussian)
{
    const RangeLikelihood likelihood(gaussian());
    for (double e : {-2.0, -0.1, 0.0, 0.05, 0.3, 1.5}) {
        for (double s : kVariances_m2) {
            const ResidualEvaluation evaluation = likelihood.evaluate(e, s);
            // The density itself underflows where the log does not (beyond ~38 sigma): it is
            // clamped there, the log is not.
            if (evaluation.log_density > std::log(1e-300)) {
                EXPECT_NEAR(std::log(likelihood.density(e, s)), evaluation.log_density,
                            1e-12 * (1.0 + std::abs(evaluation.log_density)));
            } else {
                EXPECT_EQ(likelihood.density(e, s), 1e-300);
            }
            EXPECT_EQ(likelihood.logDensity(e, s), evaluation.log_density);
            EXPECT_EQ(likelihood.inlierProbability(e, s), 1.0);
            EXPECT_EQ(likelihood.densityWithInlier(e, s).density_per_m, likelihood.density(e, s));
            EXPECT_EQ(likelihood.densityWithInlier(e, s).inlier_probability, 1.0);
            EXPECT_EQ(evaluation.inlier_probability, 1.0);
        }
    }
}

TEST(RangeLikelihood, TheFourQueriesAgreeWithOtherParameters)
{
    RangeLikelihoodParams params;
    params.nlos_fraction = 0.3;
    params.nlos_mean_excess_m = 0.25;
    params.gross_density_per_m = 1e-6;
    expectConsistent(RangeLikelihood(params));
    params.nlos_fraction = 0.0;
    expectConsistent(RangeLikelihood(params));
}

TEST(RangeLikelihood, GaussianModeIsExactlyTheNormalPdf)
{
    const RangeLikelihood likelihood(gaussian());
    for (double e : {-0.7, -0.1, 0.0, 0.04, 0.2, 1.3}) {
        for (double s : {1e-4, 0.01, 0.0169, 1.0}) {
            if (normalPdf(e, s) > 1e-300) {
                EXPECT_NEAR(likelihood.density(e, s), normalPdf(e, s), 1e-13 * normalPdf(e, s)) << e << " " << s;
            }
            // The log in closed form, so also where the pdf underflows (1.3 m at 0.01 m: 8450 nats).
            const double log_pdf = -0.5 * e * e / s - 0.5 * std::log(2.0 * kPi * s);
            EXPECT_NEAR(likelihood.logDensity(e, s), log_pdf, 1e-12 * (1.0 + std::abs(log_pdf))) << e << " " << s;
        }
    }
    // Symmetric, and unbounded cost: 10 sigma costs 50 nats more than none.
    EXPECT_DOUBLE_EQ(likelihood.logDensity(0.3, 0.01), likelihood.logDensity(-0.3, 0.01));
    EXPECT_NEAR(likelihood.logDensity(0.0, 0.01) - likelihood.logDensity(1.0, 0.01), 50.0, 1e-9);
}

TEST(RangeLikelihood, RobustModeIsOneSided)
{
    const RangeLikelihood likelihood;
    const double s = 0.01; // (0.1 m)^2
    for (double e : {0.05, 0.2, 0.5, 1.0, 2.0, 3.0, 6.0}) {
        EXPECT_GT(likelihood.density(e, s), likelihood.density(-e, s)) << "residual " << e << " m";
        EXPECT_GT(likelihood.logDensity(e, s), likelihood.logDensity(-e, s)) << "residual " << e << " m";
    }
    // Long by 1 m is far more plausible than short by 1 m (the NLOS term), not just a bit; with
    // the floor the short side stops at the floor's cost, without it much further.
    EXPECT_GT(likelihood.logDensity(1.0, s) - likelihood.logDensity(-1.0, s), 3.0);
    RangeLikelihoodParams unfloored;
    unfloored.gross_density_per_m = 0.0;
    const RangeLikelihood bare(unfloored);
    EXPECT_GT(bare.logDensity(1.0, s) - bare.logDensity(-1.0, s), 3.5);
    EXPECT_GT(bare.logDensity(2.0, s) - bare.logDensity(-2.0, s), 6.0);
    // Without an NLOS term long readings lose their explanation: only the floor is left.
    RangeLikelihoodParams no_nlos;
    no_nlos.nlos_fraction = 0.0;
    const RangeLikelihood flat(no_nlos);
    EXPECT_NEAR(flat.logDensity(3.0, s), std::log(no_nlos.gross_density_per_m), 1e-9);
}

TEST(RangeLikelihood, RobustCostIsBoundedAndRedescending)
{
    const RangeLikelihoodParams params;
    const RangeLikelihood likelihood(params);
    const double s = 0.01;
    const double ceiling = -std::log(params.gross_density_per_m); // the cost of a gross error
    double previous_cost = -likelihood.logDensity(0.0, s);
    // Short readings: the cost rises, then stays at the ceiling however large the error.
    for (double e = 0.05; e <= 1000.0; e *= 1.5) {
        const double cost = -likelihood.logDensity(-e, s);
        EXPECT_LE(cost, ceiling + 1e-12) << e;
        EXPECT_GE(cost, previous_cost - 1e-12) << e; // monotone on the short side
        previous_cost = cost;
    }
    EXPECT_NEAR(-likelihood.logDensity(-5.0, s), ceiling, 1e-4);
    EXPECT_NEAR(-likelihood.logDensity(-5.0, s), -likelihood.logDensity(-5000.0, s), 1e-4);
    // Long readings: bounded by the same ceiling; far too long is not free either.
    for (double e = 0.05; e <= 1000.0; e *= 1.5) {
        EXPECT_LE(-likelihood.logDensity(e, s), ceiling + 1e-12) << e;
    }
    EXPECT_GT(-likelihood.logDensity(8.0, s), -likelihood.logDensity(2.0, s));
    // Redescending: the influence (slope of the cost) vanishes far out, unlike a Gaussian's.
    const auto slope = [&](double e) {
        return (likelihood.logDensity(e + 1e-4, s) - likelihood.logDensity(e - 1e-4, s)) / 2e-4;
    };
    EXPECT_GT(std::abs(slope(-0.15)), 1.0);
    EXPECT_LT(std::abs(slope(-3.0)), 0.05);
    EXPECT_LT(std::abs(slope(-6.0)), 1e-5);
    EXPECT_LT(std::abs(slope(30.0)), 1e-9);
    // The inlier probability falls from near 1 to 0 as the residual grows.
    EXPECT_GT(likelihood.inlierProbability(0.0, s), 0.98);
    EXPECT_LT(likelihood.inlierProbability(0.5, s), 0.5);
    EXPECT_LT(likelihood.inlierProbability(-0.5, s), 0.5);
    EXPECT_LT(likelihood.inlierProbability(-3.0, s), 1e-12);
}

TEST(RangeLikelihood, FloorKeepsTheLogarithmFiniteForHugeResiduals)
{
    const RangeLikelihood likelihood;
    for (double e : {-1e300, -1e12, 1e12, 1e300}) {
        for (double s : {1e-12, 1e-30, 0.0, 0.01}) {
            const ResidualEvaluation evaluation = likelihood.evaluate(e, s);
            EXPECT_TRUE(std::isfinite(evaluation.log_density)) << e << " " << s;
            if (e < 0.0) {
                // Far too short: only the floor explains it.
                EXPECT_NEAR(evaluation.log_density, std::log(RangeLikelihoodParams{}.gross_density_per_m), 1e-9);
            } else {
                // Far too long: the NLOS tail is below the floor too.
                EXPECT_LE(evaluation.log_density, std::log(RangeLikelihoodParams{}.gross_density_per_m) + 1e-9);
            }
            EXPECT_LT(evaluation.inlier_probability, 1e-12);
            EXPECT_TRUE(std::isfinite(std::log(likelihood.density(e, s))));
        }
    }
    // Even with no gross-error floor at all, nothing becomes -inf.
    RangeLikelihoodParams bare;
    bare.gross_density_per_m = 0.0;
    const RangeLikelihood unfloored(bare);
    const ResidualEvaluation far = unfloored.evaluate(-1e6, 0.01);
    EXPECT_TRUE(std::isfinite(far.log_density));
    EXPECT_TRUE(std::isfinite(std::log(unfloored.density(-1e6, 0.01))));
    EXPECT_GT(unfloored.density(-1e6, 0.01), 0.0);
}

TEST(RangeLikelihood, NonPositiveVarianceIsGuarded)
{
    const RangeLikelihood likelihood;
    for (double s : {0.0, -1.0}) {
        EXPECT_TRUE(std::isfinite(likelihood.logDensity(0.0, s)));
        EXPECT_TRUE(std::isfinite(likelihood.density(0.0, s)));
        EXPECT_GT(likelihood.inlierProbability(0.0, s), 0.99);
    }
}

// Regression test: the robust density must be continuous at e = 0. An NLOS term
// eps lambda exp(-lambda e) added for e > 0 only makes p(0+) - p(0-) = eps lambda (0.1 / m by
// default): a residual of +1 nm is then 0.027 nats cheaper than an exact fit, and the
// line-of-sight probability drops from 1.00 to 0.973. A map whose links all read a little long
// would cost less than the exact one (mapCost), which the noise-free property test shows
// (NoiseFreeRecovery, seed 1005). So the NLOS term ramps in over one standard deviation.
TEST(RangeLikelihood, DensityIsContinuousAtZero)
{
    const RangeLikelihood likelihood;
    const double s = 0.01;
    EXPECT_NEAR(likelihood.logDensity(1e-9, s), likelihood.logDensity(-1e-9, s), 1e-6);
    EXPECT_NEAR(likelihood.inlierProbability(1e-9, s), likelihood.inlierProbability(-1e-9, s), 1e-6);
}

TEST(RangeLikelihood, SlopeIsTheDerivativeOfTheLogDensity)
{
    // In every regime: near zero, in the NLOS tail, short, and where the evaluation leaves its
    // direct path for the logarithmic one (e = -6 sigma; large variances).
    RangeLikelihoodParams unfloored;
    unfloored.gross_density_per_m = 0.0;
    for (const RangeLikelihood &likelihood : {RangeLikelihood(), RangeLikelihood(unfloored)}) {
        for (double s : {1e-4, 0.01, 0.25, 4.0, 150.0}) {
            const double sigma = std::sqrt(s);
            for (double e : {-20.0 * sigma, -6.1 * sigma, -5.9 * sigma, -2.0 * sigma, -0.3 * sigma, 0.0, 0.2 * sigma,
                             sigma, 3.0 * sigma, 1.5, 7.0, 40.0, 99.0, 101.0, 300.0}) {
                const double h = 1e-6 * std::max(1.0, std::abs(e));
                const double numeric = (likelihood.logDensity(e + h, s) - likelihood.logDensity(e - h, s)) / (2.0 * h);
                const double analytic = likelihood.evaluate(e, s).slope_per_m;
                EXPECT_NEAR(analytic, numeric, 1e-4 * (1.0 + std::abs(numeric)))
                    << "e " << e << " m, S " << s << " m^2";
            }
        }
    }
}

TEST(RangeLikelihood, TheTwoEvaluationPathsMeetContinuously)
{
    // Direct densities within -6 sigma, logarithms beyond: the same function on both sides.
    const RangeLikelihood likelihood;
    for (double s : {1e-4, 0.01, 1.0}) {
        const double edge = -6.0 * std::sqrt(s);
        EXPECT_NEAR(likelihood.logDensity(edge * (1.0 - 1e-9), s), likelihood.logDensity(edge * (1.0 + 1e-9), s), 1e-6);
    }
    // The variance bound of the direct path (the short term's exponential would overflow).
    const double bound = 2.0 * 300.0 / std::pow(1.0 / RangeLikelihood::kShortMeanM, 2.0);
    EXPECT_NEAR(likelihood.logDensity(0.2, bound * 0.999), likelihood.logDensity(0.2, bound * 1.001), 1e-3);
}

TEST(RangeLikelihood, WithoutTheFloorLongReadingsCostLinearlyAndShortOnesMore)
{
    // The global solve's model: a map that stretches a link (a reading too short for it) or
    // folds one (too long) always pays, and the more the further, so a misplaced part is
    // pulled back instead of being written off.
    RangeLikelihoodParams params;
    params.gross_density_per_m = 0.0;
    const RangeLikelihood likelihood(params);
    const double s = 0.01;
    const double lambda = 1.0 / params.nlos_mean_excess_m;
    const double mu = 1.0 / RangeLikelihood::kShortMeanM;
    for (double e : {5.0, 20.0, 80.0}) {
        EXPECT_NEAR(likelihood.evaluate(e, s).slope_per_m, -lambda, 1e-6) << e; // linear, slope lambda
    }
    for (double e : {-2.0, -10.0, -50.0}) {
        EXPECT_NEAR(likelihood.evaluate(e, s).slope_per_m, mu, 1e-6) << e;
    }
    EXPECT_GT(mu, 3.0 * lambda);
    // Never flat, and dearer short than long.
    double previous = -likelihood.logDensity(0.0, s);
    for (double e = 0.5; e < 500.0; e *= 2.0) {
        const double cost_long = -likelihood.logDensity(e, s);
        const double cost_short = -likelihood.logDensity(-e, s);
        EXPECT_GT(cost_long, previous);
        EXPECT_GT(cost_short, cost_long) << e;
        previous = cost_long;
    }
}

TEST(RangeLikelihood, TheNlosTermIsAnExcessPlusTheNoise)
{
    // EMG: the density of X + n with X ~ Exp(mean 1/lambda), n ~ N(0, S), checked against the
    // convolution integral done numerically (the model says an NLOS reading is a line-of-sight
    // reading made longer, not a different distribution).
    RangeLikelihoodParams nlos_only;
    nlos_only.nlos_fraction = 1.0 - RangeLikelihood::kShortFraction; // all NLOS (and the tiny short term)
    nlos_only.gross_density_per_m = 0.0;
    nlos_only.nlos_mean_excess_m = 0.7;
    const RangeLikelihood likelihood(nlos_only);
    const double s = 0.04;
    const double lambda = 1.0 / 0.7;
    for (double e : {-0.3, 0.0, 0.2, 0.7, 2.0}) {
        double integral = 0.0;
        const double dx = 1e-4;
        for (double x = 0.5 * dx; x < 20.0; x += dx) {
            integral += lambda * std::exp(-lambda * x) * normalPdf(e - x, s) * dx;
        }
        const double expected = (1.0 - RangeLikelihood::kShortFraction) * integral;
        // The short term adds a little; bound it rather than model it here.
        const double density = likelihood.density(e, s);
        EXPECT_GE(density, expected * (1.0 - 1e-3)) << e;
        EXPECT_LE(density, expected * (1.0 + 1e-3) + RangeLikelihood::kShortFraction * 2.0) << e;
    }
}

TEST(RangeLikelihood, IrlsWeightIsTheCurvatureOfTheTouchingQuadratic)
{
    const RangeLikelihood likelihood;
    const double s = 0.01;
    for (double e : {-3.0, -0.4, -0.1, 0.05, 0.3, 1.0, 6.0}) {
        const double weight = likelihood.irlsWeight(e, s);
        EXPECT_GE(weight, 0.0);
        EXPECT_NEAR(weight, std::max(-likelihood.evaluate(e, s).slope_per_m / e, 0.0), 1e-12);
    }
    // At zero: the line-of-sight curvature.
    EXPECT_NEAR(likelihood.irlsWeight(0.0, s), likelihood.inlierProbability(0.0, s) / s, 1e-9);
}

} // namespace
} // namespace cdro::engine
