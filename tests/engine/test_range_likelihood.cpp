// range_likelihood: the four ways of asking (density, logDensity, evaluate, inlierProbability)
// agree; the Gaussian mode is the normal pdf; the robust mode is one-sided, redescending and
// floored.
#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {
namespace {

constexpr double kPi = 3.14159265358979323846;

double normalPdf(double e, double variance) { return std::exp(-0.5 * e * e / variance) / std::sqrt(2.0 * kPi * variance); }

RangeLikelihoodParams gaussian()
{
    RangeLikelihoodParams params;
    params.robust = false;
    return params;
}

const double kResiduals_m[] = {-1e6, -50.0, -3.0, -1.0, -0.31, -0.1, -0.02, 0.0, 0.02, 0.1,
                               0.31, 1.0,   2.5,  7.0,  45.0,  1e3,  1e6};
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
            // density() leaves out terms below exp(-40) of the others: relative 1e-9 is plenty.
            EXPECT_NEAR(std::log(density), evaluation.log_density, 1e-9 * (1.0 + std::abs(evaluation.log_density)));
            EXPECT_NEAR(likelihood.inlierProbability(e, s), evaluation.inlier_probability, 1e-12);
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
            // The density itself underflows where the log does not (beyond ~38 sigma).
            if (evaluation.log_density > std::log(1e-300)) {
                EXPECT_NEAR(std::log(likelihood.density(e, s)), evaluation.log_density,
                            1e-12 * (1.0 + std::abs(evaluation.log_density)));
            } else {
                EXPECT_LT(likelihood.density(e, s), 1e-300);
            }
            EXPECT_EQ(likelihood.logDensity(e, s), evaluation.log_density);
            EXPECT_EQ(likelihood.inlierProbability(e, s), 1.0);
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
            EXPECT_NEAR(likelihood.density(e, s), normalPdf(e, s), 1e-13 * normalPdf(e, s)) << e << " " << s;
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
    // Long by 1 m is far more plausible than short by 1 m (the NLOS term), not just a bit.
    EXPECT_GT(likelihood.logDensity(1.0, s) - likelihood.logDensity(-1.0, s), 5.0);
    // Without an NLOS term the robust model is symmetric again.
    RangeLikelihoodParams symmetric;
    symmetric.nlos_fraction = 0.0;
    const RangeLikelihood flat(symmetric);
    EXPECT_DOUBLE_EQ(flat.density(1.0, s), flat.density(-1.0, s));
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
    EXPECT_NEAR(-likelihood.logDensity(-5.0, s), ceiling, 1e-9);
    EXPECT_EQ(-likelihood.logDensity(-5.0, s), -likelihood.logDensity(-5000.0, s));
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
    EXPECT_LT(std::abs(slope(-3.0)), 1e-9);
    EXPECT_LT(std::abs(slope(30.0)), 1e-9);
    // The inlier probability falls from near 1 to 0 as the residual grows.
    EXPECT_GT(likelihood.inlierProbability(0.0, s), 0.99);
    EXPECT_LT(likelihood.inlierProbability(0.5, s), 0.5);
    EXPECT_LT(likelihood.inlierProbability(-0.5, s), 0.5);
    EXPECT_EQ(likelihood.inlierProbability(-3.0, s), 0.0);
}

TEST(RangeLikelihood, FloorKeepsTheLogarithmFiniteForHugeResiduals)
{
    const RangeLikelihood likelihood;
    for (double e : {-1e300, -1e12, 1e12, 1e300}) {
        for (double s : {1e-12, 1e-30, 0.0, 0.01}) {
            const ResidualEvaluation evaluation = likelihood.evaluate(e, s);
            EXPECT_TRUE(std::isfinite(evaluation.log_density)) << e << " " << s;
            EXPECT_NEAR(evaluation.log_density, std::log(RangeLikelihoodParams{}.gross_density_per_m), 1e-12);
            EXPECT_EQ(evaluation.inlier_probability, 0.0);
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

// Regression test. The robust density used to jump at e = 0 (engine as of 3646197): The NLOS term
// eps lambda exp(-lambda e) is added for e > 0 only, so p(0+) - p(0-) = eps lambda (0.1 / m by
// default): a residual of +1 nm is 0.027 nats cheaper than an exact fit, and the line-of-sight
// probability drops from 1.00 to 0.973. A map whose links all read a little long therefore
// costs less than the exact one (mapCost), which the noise-free property test shows
// (NoiseFreeRecovery, seed 1005). The NLOS term now ramps in over one standard deviation.
TEST(RangeLikelihood, DensityIsContinuousAtZero)
{
    const RangeLikelihood likelihood;
    const double s = 0.01;
    EXPECT_NEAR(likelihood.logDensity(1e-9, s), likelihood.logDensity(-1e-9, s), 1e-6);
    EXPECT_NEAR(likelihood.inlierProbability(1e-9, s), likelihood.inlierProbability(-1e-9, s), 1e-6);
}

} // namespace
} // namespace cdro::engine
