// range_model: h(x, c) = |x - c| and its two Jacobians against central differences, the
// guard where x = c, and the projection of 3D ranges to the plane.
#include <cmath>

#include <gtest/gtest.h>

#include "cdro/engine/range_model.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::predictRange;
using engine::projectRange;

// Central difference of h along one coordinate of the point (wrt_point) or of the centre.
double numericalDerivative(const Vector2 &point_m, const Vector2 &center_m, bool wrt_point, int axis)
{
    // Truncation error ~ step^2 |h'''| / 6 and rounding ~ eps |h| / step: 1e-6 m keeps both
    // near 1e-10 for the distances used here (0.01 .. 100 m).
    const double step_m = 1e-6;
    Vector2 plus = wrt_point ? point_m : center_m;
    Vector2 minus = plus;
    plus[axis] += step_m;
    minus[axis] -= step_m;
    const double h_plus = wrt_point ? predictRange(plus, center_m).range_m : predictRange(point_m, plus).range_m;
    const double h_minus = wrt_point ? predictRange(minus, center_m).range_m : predictRange(point_m, minus).range_m;
    return (h_plus - h_minus) / (2.0 * step_m);
}

TEST(RangeModel, PredictionIsTheDistance)
{
    const auto prediction = predictRange(Vector2(4.0, 6.0), Vector2(1.0, 2.0));
    EXPECT_DOUBLE_EQ(prediction.range_m, 5.0);
    EXPECT_FALSE(prediction.singular);
    EXPECT_DOUBLE_EQ(prediction.jacobian_point(0), 0.6);
    EXPECT_DOUBLE_EQ(prediction.jacobian_point(1), 0.8);
    EXPECT_DOUBLE_EQ(prediction.jacobian_center(0), -0.6);
    EXPECT_DOUBLE_EQ(prediction.jacobian_center(1), -0.8);
}

TEST(RangeModel, ThePlanarCaseIsThePlainDistanceToTheBit)
{
    // Stage 1 calls the model without a height difference, scale or offset: what it gets must be
    // exactly |a - b| and its unit vector, so that the one model serves both stages.
    const uint64_t seed = testSeed(3002);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    for (int i = 0; i < 1000; ++i) {
        const Vector2 a_m = uniformPoint(random, -50.0, 50.0);
        const Vector2 b_m = uniformPoint(random, -50.0, 50.0);
        const auto prediction = predictRange(a_m, b_m);
        const Vector2 unit = (a_m - b_m) / (a_m - b_m).norm();
        ASSERT_EQ(prediction.range_m, (a_m - b_m).norm());
        ASSERT_EQ(prediction.distance_m, prediction.range_m);
        ASSERT_EQ(prediction.jacobian_point, unit.transpose());
        ASSERT_EQ(prediction.jacobian_center, (-unit).transpose());
    }
}

TEST(RangeModel, JacobiansMatchCentralDifferences)
{
    const uint64_t seed = testSeed(3001);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    double worst = 0.0;
    for (int trial = 0; trial < 200; ++trial) {
        // Distances from 1 cm to about 100 m, in every direction.
        const Vector2 center_m = uniformPoint(random, -50.0, 50.0);
        const double distance_m = std::pow(10.0, random.uniform(-2.0, 2.0));
        const double angle_rad = random.uniform(0.0, 6.283185307179586);
        const Vector2 point_m = center_m + distance_m * Vector2(std::cos(angle_rad), std::sin(angle_rad));
        const auto prediction = predictRange(point_m, center_m);
        ASSERT_FALSE(prediction.singular);
        EXPECT_NEAR(prediction.range_m, distance_m, 1e-12 * (1.0 + distance_m));
        for (int axis = 0; axis < 2; ++axis) {
            const double point_error =
                std::abs(prediction.jacobian_point(axis) - numericalDerivative(point_m, center_m, true, axis));
            const double center_error =
                std::abs(prediction.jacobian_center(axis) - numericalDerivative(point_m, center_m, false, axis));
            worst = std::max({worst, point_error, center_error});
            EXPECT_LT(point_error, 1e-8) << "trial " << trial << " axis " << axis;
            EXPECT_LT(center_error, 1e-8) << "trial " << trial << " axis " << axis;
        }
        // A unit vector and its opposite.
        EXPECT_NEAR(prediction.jacobian_point.norm(), 1.0, 1e-14);
        EXPECT_EQ(prediction.jacobian_center, -prediction.jacobian_point);
    }
    std::printf("largest Jacobian error against central differences: %.3g\n", worst);
}

TEST(RangeModel, CoincidentPointsAreSingularWithAZeroJacobian)
{
    const Vector2 c_m(3.0, -2.0);
    const auto same = predictRange(c_m, c_m);
    EXPECT_TRUE(same.singular);
    EXPECT_EQ(same.range_m, 0.0);
    EXPECT_TRUE(same.jacobian_point.isZero(0.0));
    EXPECT_TRUE(same.jacobian_center.isZero(0.0));
    for (const double finite : {same.jacobian_point(0), same.jacobian_point(1)}) {
        EXPECT_TRUE(std::isfinite(finite));
    }
    // Just inside the guard: still singular; just outside: a unit Jacobian.
    const auto inside = predictRange(c_m + Vector2(0.5 * engine::kSingularDistanceM, 0.0), c_m);
    EXPECT_TRUE(inside.singular);
    EXPECT_TRUE(inside.jacobian_point.isZero(0.0));
    const auto outside = predictRange(c_m + Vector2(0.0, 10.0 * engine::kSingularDistanceM), c_m);
    EXPECT_FALSE(outside.singular);
    EXPECT_NEAR(outside.jacobian_point(1), 1.0, 1e-6);
    EXPECT_NEAR(outside.jacobian_point(0), 0.0, 1e-6);
}

TEST(RangeModel, ProjectionRemovesTheHeightDifference)
{
    bool clamped = true;
    EXPECT_DOUBLE_EQ(projectRange(5.0, 3.0, &clamped), 4.0);
    EXPECT_FALSE(clamped); // reset on success, not left from the last call
    EXPECT_DOUBLE_EQ(projectRange(5.0, -3.0, &clamped), 4.0);
    EXPECT_FALSE(clamped);
    EXPECT_DOUBLE_EQ(projectRange(7.5, 0.0, &clamped), 7.5);
    EXPECT_FALSE(clamped);
    // Exactly the height difference: a vertical link, projected length 0, not clamped.
    EXPECT_EQ(projectRange(3.0, 3.0, &clamped), 0.0);
    EXPECT_FALSE(clamped);
}

TEST(RangeModel, ProjectionClampsARangeShorterThanTheHeightDifference)
{
    bool clamped = false;
    EXPECT_EQ(projectRange(2.0, 3.0, &clamped), 0.0);
    EXPECT_TRUE(clamped);
    clamped = false;
    EXPECT_EQ(projectRange(2.0, -3.0, &clamped), 0.0);
    EXPECT_TRUE(clamped);
    clamped = false;
    EXPECT_EQ(projectRange(2.999, 3.0, &clamped), 0.0);
    EXPECT_TRUE(clamped);
}

} // namespace
} // namespace cdro::enginetest
