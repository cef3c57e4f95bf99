// ring_sog: generation (eq. 5-7), the EKF update with gating, the weight bookkeeping (floor,
// normalisation, collapse and reset), weight transfer (eq. 15), moving a ring, the cooperative
// weight update (eq. 8-11) and partial updates of the active set.
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include <gtest/gtest.h>

#include "cdro/engine/ring_sog.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::Gaussian2;
using engine::Matrix2;
using engine::RangeLikelihood;
using engine::RangeWitness;
using engine::RingSog;
using engine::RingSogParams;
using engine::SogComponentState;

constexpr double kTwoPi = 6.28318530717958647692;

double weightSum(const RingSog &ring)
{
    double sum = 0.0;
    for (const SogComponentState &c : ring.components()) {
        sum += c.weight;
    }
    return sum;
}

// The moments computed from the components directly, the way eq. 12-14 define them.
Gaussian2 bruteForceMoments(const RingSog &ring)
{
    const std::vector<SogComponentState> components = ring.components();
    double total = 0.0;
    Vector2 mean = Vector2::Zero();
    for (const SogComponentState &c : components) {
        total += c.weight;
        mean += c.weight * c.mean_m;
    }
    mean /= total;
    Matrix2 covariance = Matrix2::Zero();
    for (const SogComponentState &c : components) {
        covariance += c.weight * (c.covariance_m2 + (c.mean_m - mean) * (c.mean_m - mean).transpose());
    }
    Gaussian2 out;
    out.mean_m = mean;
    out.covariance_m2 = covariance / total;
    return out;
}

uint32_t nearestComponent(const RingSog &ring, const Vector2 &point_m)
{
    const std::vector<SogComponentState> components = ring.components();
    uint32_t best = 0;
    for (uint32_t k = 1; k < components.size(); ++k) {
        if ((components[k].mean_m - point_m).norm() < (components[best].mean_m - point_m).norm()) {
            best = k;
        }
    }
    return best;
}

// A ring whose weights are concentrated on component `peak` (one strong likelihood).
RingSog concentrated(uint32_t peak, const Vector2 &center_m = Vector2(1.0, -2.0), double range_m = 10.0)
{
    RingSog ring = RingSog::generate(7, 9, center_m, range_m, RingSogParams{});
    std::vector<double> likelihood(ring.size(), 0.0);
    likelihood[peak] = 1.0;
    ring.applyLikelihood(likelihood);
    return ring;
}

TEST(RingSog, ComponentCountFollowsTheArcSpacingWithinItsClamp)
{
    const RingSogParams params; // 1 m spacing, 30..720 components
    const auto count = [&](double range_m, const RingSogParams &p) {
        return RingSog::generate(1, 2, Vector2::Zero(), range_m, p).size();
    };
    EXPECT_EQ(count(10.0, params), 63U);  // floor(2 pi 10 / 1) + 1
    EXPECT_EQ(count(20.0, params), 126U); // floor(125.66) + 1
    EXPECT_EQ(count(4.0, params), 30U);   // 26 wanted: the minimum
    EXPECT_EQ(count(0.0, params), 30U);
    EXPECT_EQ(count(200.0, params), 720U); // 1257 wanted: the maximum
    RingSogParams fine = params;
    fine.arc_spacing_m = 0.5;
    EXPECT_EQ(count(10.0, fine), 126U); // floor(125.66) + 1
    fine.min_components = 200;
    EXPECT_EQ(count(10.0, fine), 200U);
}

TEST(RingSog, GeneratedComponentsSitOnTheCircleWithTheDocumentedSpreads)
{
    RingSogParams params;
    params.radial_sigma_m = 0.13;
    const Vector2 center_m(3.5, -1.25);
    for (const double range_m : {2.0, 10.0, 37.3}) {
        SCOPED_TRACE(::testing::Message() << "range " << range_m << " m");
        const RingSog ring = RingSog::generate(11, 12, center_m, range_m, params);
        EXPECT_EQ(ring.center(), 11);
        EXPECT_EQ(ring.target(), 12);
        const uint32_t n = ring.size();
        const double sigma_t =
            std::max(kTwoPi * range_m / n / params.tangential_overlap, params.min_tangential_sigma_m);
        const std::vector<SogComponentState> components = ring.components();
        for (uint32_t k = 0; k < n; ++k) {
            const double angle = kTwoPi * k / n;
            const Vector2 radial(std::cos(angle), std::sin(angle));
            const Vector2 tangential(-radial.y(), radial.x());
            const SogComponentState &c = components[k];
            EXPECT_NEAR((c.mean_m - (center_m + range_m * radial)).norm(), 0.0, 1e-12) << k;
            EXPECT_NEAR((radial.transpose() * c.covariance_m2 * radial).value(), 0.13 * 0.13, 1e-15) << k;
            EXPECT_NEAR((tangential.transpose() * c.covariance_m2 * tangential).value(), sigma_t * sigma_t, 1e-14) << k;
            EXPECT_NEAR((radial.transpose() * c.covariance_m2 * tangential).value(), 0.0, 1e-15) << k;
            EXPECT_DOUBLE_EQ(c.weight, 1.0 / n) << k;
        }
        EXPECT_LT(ring.weightFloor(), 1.0 / n);
        EXPECT_NEAR(weightSum(ring), 1.0, 1e-12);
        // Equal weights on a full circle: the moments sit on the centre.
        EXPECT_NEAR((ring.moments().mean_m - center_m).norm(), 0.0, 1e-9);
    }
    // Neighbours overlap: the tangential spread is the spacing over c = 2.5 on a 10 m ring.
    const RingSog ring = RingSog::generate(1, 2, Vector2::Zero(), 10.0, RingSogParams{});
    const Matrix2 c0 = ring.component(0).covariance_m2; // radial = x, tangential = y
    EXPECT_NEAR(std::sqrt(c0(1, 1)), kTwoPi * 10.0 / 63.0 / 2.5, 1e-12);
    EXPECT_NEAR(std::sqrt(c0(0, 0)), 0.10, 1e-12);
}

TEST(RingSog, SmallRingsKeepTheLeastTangentialSpread)
{
    // 30 components on a 0.2 m ring: 0.04 m / 2.5 would be far below the range noise.
    const RingSog ring = RingSog::generate(1, 2, Vector2::Zero(), 0.2, RingSogParams{});
    const Matrix2 c0 = ring.component(0).covariance_m2;
    EXPECT_NEAR(c0(1, 1), 0.01, 1e-15);
    // Without a least spread (the movement stage's beacons), eq. 7 alone.
    RingSogParams eq7;
    eq7.min_tangential_sigma_m = 0.0;
    const double sigma_t = kTwoPi * 0.2 / 30.0 / 2.5;
    EXPECT_NEAR(RingSog::generate(1, 2, Vector2::Zero(), 0.2, eq7).component(0).covariance_m2(1, 1), sigma_t * sigma_t,
                1e-15);
    // A ring of radius 0 (a clamped projection): every mean on the centre, still a usable spread.
    const RingSog point = RingSog::generate(1, 2, Vector2(4.0, 4.0), 0.0, RingSogParams{});
    for (const SogComponentState &c : point.components()) {
        EXPECT_EQ(c.mean_m, Vector2(4.0, 4.0));
        EXPECT_GT(engine::minEigenvalue(c.covariance_m2), 0.0);
    }
}

TEST(RingSog, WeightFloorStaysBelowOneOverN)
{
    RingSogParams params;
    params.weight_floor = 0.5; // absurd: would flatten every ring
    const RingSog ring = RingSog::generate(1, 2, Vector2::Zero(), 10.0, params);
    EXPECT_LE(ring.weightFloor(), 0.1 / ring.size());
    EXPECT_EQ(RingSog::generate(1, 2, Vector2::Zero(), 10.0, RingSogParams{}).weightFloor(), 1e-6);
}

TEST(RingSog, RepeatedRangesPullEveryComponentToTheRadiusAndShrinkTheRadialVariance)
{
    const Vector2 center_m(2.0, 1.0);
    RingSog ring = RingSog::generate(1, 2, center_m, 5.0, RingSogParams{});
    const double measured_m = 5.2; // 2 sigma away from every component at first
    uint64_t updated = 0;
    for (int i = 0; i < 60; ++i) {
        const auto result = ring.updateWithRange(center_m, Matrix2::Zero(), measured_m, 0.1, 4.0, 1e-6);
        EXPECT_EQ(result.gated, 0U);
        updated += result.updated;
    }
    EXPECT_EQ(updated, 60U * ring.size());
    for (const SogComponentState &c : ring.components()) {
        const Vector2 radial = (c.mean_m - center_m).normalized();
        EXPECT_NEAR((c.mean_m - center_m).norm(), measured_m, 0.01);
        const double radial_variance = (radial.transpose() * c.covariance_m2 * radial).value();
        EXPECT_LT(radial_variance, 0.01 / 20.0); // started at (0.1 m)^2
        EXPECT_GT(radial_variance, 0.0);
        // Joseph form: symmetric up to rounding.
        EXPECT_NEAR(c.covariance_m2(0, 1), c.covariance_m2(1, 0), 1e-15 * c.covariance_m2.norm());
    }
}

TEST(RingSog, TheCentresUncertaintyAndPositionAreUsed)
{
    // The ring is updated about the centre it is given, not the one it was generated at.
    const Vector2 moved_m(0.2, 0.0);
    RingSog ring = RingSog::generate(1, 2, Vector2::Zero(), 5.0, RingSogParams{});
    for (int i = 0; i < 40; ++i) {
        ring.updateWithRange(moved_m, Matrix2::Zero(), 5.0, 0.1, 4.0, 0.0);
    }
    for (const SogComponentState &c : ring.components()) {
        EXPECT_NEAR((c.mean_m - moved_m).norm(), 5.0, 0.01);
    }
    // A very uncertain centre: the same range moves the components less.
    RingSog sure = RingSog::generate(1, 2, Vector2::Zero(), 5.0, RingSogParams{});
    RingSog unsure = sure;
    sure.updateWithRange(Vector2::Zero(), Matrix2::Zero(), 5.2, 0.1, 4.0, 0.0);
    unsure.updateWithRange(Vector2::Zero(), 0.04 * Matrix2::Identity(), 5.2, 0.1, 4.0, 0.0);
    EXPECT_NEAR(sure.component(0).mean_m.norm(), 5.1, 1e-9);               // gain 0.01 / (0.01 + 0.01)
    EXPECT_NEAR(unsure.component(0).mean_m.norm(), 5.0 + 0.2 / 6.0, 1e-9); // 0.01 / (0.01 + 0.04 + 0.01)
}

TEST(RingSog, TheRangeTermsAreTheRangeModels)
{
    // A ring of the planar radius; ranges read long by the radios' scale and offset, from a
    // node 1.5 m higher: at the truth, h = s sqrt(d^2 + dz^2) + b predicts them exactly, so the
    // component there does not move, and the ring is pulled to the planar radius, not the range.
    const engine::RangeTerms terms{1.5, 1.07, 0.12};
    const Vector2 target_m(6.0, 0.0);
    const double range_m = terms.scale * std::hypot(6.0, terms.height_difference_m) + terms.offset_m;
    RingSog ring = RingSog::generate(1, 2, Vector2::Zero(), 5.5, RingSogParams{});
    engine::RingUpdateRule rule;
    for (int i = 0; i < 60; ++i) {
        ring.updateWithRange(Vector2::Zero(), Matrix2::Zero(), range_m, 0.01, terms, rule);
    }
    for (const SogComponentState &c : ring.components()) {
        EXPECT_NEAR(c.mean_m.norm(), 6.0, 0.01);
    }
    EXPECT_NEAR((ring.component(0).mean_m - target_m).norm(), 0.0, 0.01);
}

TEST(RingSog, RangesFromAnotherPlaceWeighTheRingAndPruningKeepsTheSideTheyPredict)
{
    // The movement stage's beacon: a ring around the robot's first pose, ranged again from a
    // pose 3 m on. Weighed by those ranges, the side of the ring near the truth takes the
    // weight; pruning drops the rest and the moments sit at the truth.
    const Vector2 target_m(3.0, 4.0);
    RingSogParams shape;
    shape.weight_floor = 0.0;
    RingSog ring = RingSog::generate(1, 2, Vector2::Zero(), 5.0, shape);
    const size_t generated = ring.size();
    const RangeLikelihood likelihood;
    engine::RingUpdateRule rule;
    rule.weigh_by = &likelihood;
    const Vector2 second_m(3.0, 0.0);
    for (int i = 0; i < 5; ++i) {
        ring.updateWithRange(second_m, Matrix2::Zero(), (target_m - second_m).norm(), 0.01, engine::RangeTerms{}, rule);
        ring.updateWithRange(Vector2::Zero(), Matrix2::Zero(), target_m.norm(), 0.01, engine::RangeTerms{}, rule);
    }
    const uint32_t dropped = ring.prune(1e-3);
    EXPECT_EQ(dropped + ring.size(), generated);
    EXPECT_GT(dropped, generated / 2); // the far side and the mirror across the baseline's line stay
    double total = 0.0;
    for (const SogComponentState &c : ring.components()) {
        total += c.weight;
    }
    EXPECT_NEAR(total, 1.0, 1e-12);
    // Two ranges cannot tell (3, 4) from its mirror (3, -4) across the line of the two poses.
    const Gaussian2 merged = ring.moments();
    EXPECT_NEAR(merged.mean_m.x(), 3.0, 0.05);
    EXPECT_NEAR(std::abs(ring.component(ring.heaviest()).mean_m.y()), 4.0, 0.05);
    // A third place off that line decides it.
    const Vector2 third_m(0.0, 3.0);
    for (int i = 0; i < 3; ++i) {
        ring.updateWithRange(third_m, Matrix2::Zero(), (target_m - third_m).norm(), 0.01, engine::RangeTerms{}, rule);
    }
    ring.prune(1e-3);
    EXPECT_NEAR((ring.moments().mean_m - target_m).norm(), 0.0, 0.05);
}

TEST(RingSog, AbsoluteComponentsComeBackToTheBit)
{
    std::vector<SogComponentState> components(3);
    components[0] = {Vector2(1234.5678901, -98.7654321), 0.013 * Matrix2::Identity(), 0.2};
    components[1] = {Vector2(-0.1 / 3.0, 1.0 / 7.0), 0.5 * Matrix2::Identity(), 0.3};
    components[2] = {Vector2(7.0e5 / 3.0, 2.0 / 3.0), Matrix2::Identity(), 0.49999999999999994};
    RingSog ring;
    ring.setAbsoluteComponents(components);
    const std::vector<SogComponentState> back = ring.components();
    ASSERT_EQ(back.size(), components.size());
    for (size_t k = 0; k < back.size(); ++k) {
        EXPECT_EQ(back[k].mean_m, components[k].mean_m);
        EXPECT_EQ(back[k].covariance_m2, components[k].covariance_m2);
        EXPECT_EQ(back[k].weight, components[k].weight); // taken as they are, not normalised
    }
}

TEST(RingSog, GatingCountsAndLeavesAnOutlierAlone)
{
    RingSog ring = RingSog::generate(1, 2, Vector2::Zero(), 5.0, RingSogParams{});
    const std::vector<SogComponentState> before = ring.components();
    // 4 m too long, against an innovation std of sqrt(0.01 + 0.01) = 0.14 m: far beyond 4 sigma.
    const auto result = ring.updateWithRange(Vector2::Zero(), Matrix2::Zero(), 9.0, 0.1, 4.0, 0.0);
    EXPECT_EQ(result.gated, ring.size());
    EXPECT_EQ(result.updated, 0U);
    const std::vector<SogComponentState> after = ring.components();
    for (size_t k = 0; k < before.size(); ++k) {
        EXPECT_EQ(after[k].mean_m, before[k].mean_m);
        EXPECT_EQ(after[k].covariance_m2, before[k].covariance_m2);
        EXPECT_EQ(after[k].weight, before[k].weight);
    }
    // Process noise is added first, gated or not (so a ring never becomes too sure to move).
    ring.updateWithRange(Vector2::Zero(), Matrix2::Zero(), 9.0, 0.1, 4.0, 1e-4);
    const std::vector<SogComponentState> noisy = ring.components();
    for (size_t k = 0; k < before.size(); ++k) {
        EXPECT_EQ(noisy[k].mean_m, before[k].mean_m);
        EXPECT_NEAR(noisy[k].covariance_m2(0, 0), before[k].covariance_m2(0, 0) + 1e-4, 1e-17);
        EXPECT_NEAR(noisy[k].covariance_m2(1, 1), before[k].covariance_m2(1, 1) + 1e-4, 1e-17);
    }
    // Just inside the gate the same ring takes the range.
    const auto inside = ring.updateWithRange(Vector2::Zero(), Matrix2::Zero(), 5.5, 0.1, 4.0, 0.0);
    EXPECT_EQ(inside.gated, 0U);
    EXPECT_EQ(inside.updated, ring.size());
}

TEST(RingSog, ApplyLikelihoodKeepsWeightsNormalisedAndFloored)
{
    const uint64_t seed = testSeed(3101);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    RingSog ring = RingSog::generate(1, 2, Vector2::Zero(), 12.0, RingSogParams{});
    const double floor = ring.weightFloor();
    const uint32_t n = ring.size();
    for (int round = 0; round < 50; ++round) {
        std::vector<double> likelihood(n);
        for (double &value : likelihood) {
            // Spread over 30 orders of magnitude, some exactly zero.
            value = random.uniform() < 0.2 ? 0.0 : std::pow(10.0, random.uniform(-30.0, 0.0));
        }
        ring.applyLikelihood(likelihood, false);
        EXPECT_NEAR(weightSum(ring), 1.0, 1e-12) << round;
        for (const SogComponentState &c : ring.components()) {
            // The floor is applied, then the weights normalised once more: floor / (1 + n floor).
            EXPECT_GE(c.weight, floor / (1.0 + n * floor)) << round;
        }
    }
    // Only ratios matter: scaling the evidence changes nothing.
    RingSog a = RingSog::generate(1, 2, Vector2::Zero(), 12.0, RingSogParams{});
    RingSog b = a;
    std::vector<double> likelihood(n);
    for (uint32_t k = 0; k < n; ++k) {
        likelihood[k] = std::exp(-0.1 * k);
    }
    std::vector<double> scaled = likelihood;
    for (double &value : scaled) {
        value *= 1e-250;
    }
    a.applyLikelihood(likelihood);
    b.applyLikelihood(scaled);
    for (uint32_t k = 0; k < n; ++k) {
        EXPECT_NEAR(a.component(k).weight, b.component(k).weight, 1e-15);
    }
    // No usable evidence (wrong size, all zero, not finite): nothing changes.
    const std::vector<SogComponentState> before = a.components();
    EXPECT_FALSE(a.applyLikelihood(std::vector<double>(n + 1, 1.0)));
    EXPECT_FALSE(a.applyLikelihood(std::vector<double>(n, 0.0)));
    EXPECT_FALSE(a.applyLikelihood(std::vector<double>(n, std::numeric_limits<double>::infinity())));
    for (uint32_t k = 0; k < n; ++k) {
        EXPECT_EQ(a.component(k).weight, before[k].weight);
    }
}

TEST(RingSog, ACollapseResetsToTheEvidenceAndIsReported)
{
    const uint32_t n = concentrated(0).size();
    const uint32_t other = n / 2;
    // Evidence for the opposite side of the ring, which has only floor weight now.
    std::vector<double> evidence(n, 1e-7);
    evidence[other] = 1.0;

    RingSog reset = concentrated(0);
    ASSERT_GT(reset.component(0).weight, 0.99);
    EXPECT_TRUE(reset.applyLikelihood(evidence, true));
    EXPECT_EQ(reset.heaviest(), other);
    EXPECT_GT(reset.component(other).weight, 0.99);
    // Reset: the old mode keeps nothing of its weight, only what the evidence gives it.
    EXPECT_LT(reset.component(0).weight, 2.0 * reset.weightFloor());
    EXPECT_NEAR(weightSum(reset), 1.0, 1e-12);

    // Without the reset the same evidence is multiplied in: the old mode keeps a share.
    RingSog kept = concentrated(0);
    EXPECT_FALSE(kept.applyLikelihood(evidence, false));
    EXPECT_GT(kept.component(0).weight, 0.05);

    // Evidence the ring partly agrees with is no collapse.
    RingSog agreeing = concentrated(0);
    std::vector<double> partial(n, 1e-7);
    partial[other] = 1.0;
    partial[0] = 0.01;
    EXPECT_FALSE(agreeing.applyLikelihood(partial, true));
    EXPECT_EQ(agreeing.heaviest(), 0U);
}

TEST(RingSog, TransferGivesAGaussianShapeAroundTheHeaviestComponent)
{
    RingSog ring = RingSog::generate(1, 2, Vector2(5.0, 5.0), 10.0, RingSogParams{});
    const uint32_t n = ring.size();
    std::vector<double> likelihood(n, 0.2);
    likelihood[17] = 1.0;
    likelihood[40] = 0.9;
    ring.applyLikelihood(likelihood);
    const double sigma_w_m = 0.5;
    ring.transferWeights(sigma_w_m);
    EXPECT_EQ(ring.heaviest(), 17U);
    EXPECT_NEAR(weightSum(ring), 1.0, 1e-12);
    const std::vector<SogComponentState> components = ring.components();
    const Vector2 best = components[17].mean_m;
    uint32_t shaped = 0;
    for (uint32_t k = 0; k < n; ++k) {
        const double d = (components[k].mean_m - best).norm();
        const double expected = std::exp(-0.5 * d * d / (sigma_w_m * sigma_w_m));
        const double ratio = components[k].weight / components[17].weight;
        if (expected > 100.0 * ring.weightFloor()) {
            EXPECT_NEAR(ratio, expected, 1e-9 * expected) << k;
            ++shaped;
        } else {
            // Beyond the Gaussian's reach only the floor is left (the second mode is gone).
            EXPECT_LE(components[k].weight, ring.weightFloor() * 1.0001) << k;
        }
    }
    EXPECT_GE(shaped, 3U); // the heaviest and its neighbours (1 m apart, sigma 0.5 m)
    // Symmetric around the heaviest.
    EXPECT_NEAR(components[16].weight, components[18].weight, 1e-12);
}

TEST(RingSog, TranslateAndRigidMotionMoveMeansAndMomentsConsistently)
{
    const uint64_t seed = testSeed(3102);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    RingSog ring = RingSog::generate(3, 4, Vector2(10.0, -3.0), 7.0, RingSogParams{});
    std::vector<double> likelihood(ring.size());
    for (double &value : likelihood) {
        value = random.uniform();
    }
    ring.applyLikelihood(likelihood);
    const auto expectMomentsMatch = [](const RingSog &r) {
        const Gaussian2 cached = r.moments();
        const Gaussian2 brute = bruteForceMoments(r);
        EXPECT_NEAR((cached.mean_m - brute.mean_m).norm(), 0.0, 1e-10);
        EXPECT_NEAR((cached.covariance_m2 - brute.covariance_m2).norm(), 0.0, 1e-10);
        // accumulateMoments gives the raw moments of the same thing.
        Vector2 first = Vector2::Zero();
        Matrix2 second = Matrix2::Zero();
        double total = 0.0;
        r.accumulateMoments(&first, &second, &total);
        EXPECT_EQ(total, 1.0);
        EXPECT_NEAR((first - brute.mean_m).norm(), 0.0, 1e-10);
        EXPECT_NEAR((second - first * first.transpose() - brute.covariance_m2).norm(), 0.0, 1e-8);
    };
    expectMomentsMatch(ring);
    const std::vector<SogComponentState> before = ring.components();
    const Gaussian2 moments_before = ring.moments();

    const Vector2 delta_m(-2.5, 4.25);
    ring.translate(delta_m);
    std::vector<SogComponentState> after = ring.components();
    for (size_t k = 0; k < before.size(); ++k) {
        EXPECT_NEAR((after[k].mean_m - (before[k].mean_m + delta_m)).norm(), 0.0, 1e-12);
        EXPECT_EQ(after[k].covariance_m2, before[k].covariance_m2);
        EXPECT_EQ(after[k].weight, before[k].weight);
    }
    EXPECT_NEAR((ring.moments().mean_m - (moments_before.mean_m + delta_m)).norm(), 0.0, 1e-10);
    EXPECT_NEAR((ring.moments().covariance_m2 - moments_before.covariance_m2).norm(), 0.0, 1e-10);
    expectMomentsMatch(ring);

    for (const bool mirror : {false, true}) {
        const std::vector<SogComponentState> start = ring.components();
        const Gaussian2 start_moments = ring.moments();
        const double angle = random.uniform(0.0, kTwoPi);
        Matrix2 rotation;
        rotation << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle);
        if (mirror) {
            rotation.col(1) *= -1.0;
        }
        const Vector2 translation_m = uniformPoint(random, -20.0, 20.0);
        ring.applyRigid(rotation, translation_m);
        after = ring.components();
        for (size_t k = 0; k < start.size(); ++k) {
            EXPECT_NEAR((after[k].mean_m - (rotation * start[k].mean_m + translation_m)).norm(), 0.0, 1e-10);
            EXPECT_NEAR((after[k].covariance_m2 - rotation * start[k].covariance_m2 * rotation.transpose()).norm(), 0.0,
                        1e-14);
        }
        EXPECT_NEAR((ring.moments().mean_m - (rotation * start_moments.mean_m + translation_m)).norm(), 0.0, 1e-10);
        EXPECT_NEAR(
            (ring.moments().covariance_m2 - rotation * start_moments.covariance_m2 * rotation.transpose()).norm(), 0.0,
            1e-10);
        expectMomentsMatch(ring);
    }
}

TEST(RingSog, SetComponentsRoundTripsAndNormalises)
{
    RingSog source = concentrated(5, Vector2(40.0, 40.0));
    std::vector<SogComponentState> components = source.components();
    for (SogComponentState &c : components) {
        c.weight *= 3.0; // not normalised
    }
    RingSog copy;
    copy.setIdentity(7, 9);
    copy.setWeightFloor(source.weightFloor());
    copy.setComponents(components);
    EXPECT_NEAR(weightSum(copy), 1.0, 1e-12);
    EXPECT_NEAR((copy.moments().mean_m - source.moments().mean_m).norm(), 0.0, 1e-6);
    for (uint32_t k = 0; k < copy.size(); ++k) {
        EXPECT_NEAR((copy.component(k).mean_m - source.component(k).mean_m).norm(), 0.0, 1e-12);
        // Not bit for bit: normalising applies the floor again, and floor-level weights had been
        // scaled just under it by the previous normalisation (floor / (1 + N floor)).
        EXPECT_NEAR(copy.component(k).weight, source.component(k).weight, 1e-8);
    }
}

TEST(RingSog, WitnessesAtKnownGeometryMakeTheNearestComponentTheHeaviest)
{
    const uint64_t seed = testSeed(3103);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const RangeLikelihood likelihood;
    for (int trial = 0; trial < 20; ++trial) {
        const Vector2 center_m = uniformPoint(random, -5.0, 5.0);
        const double range_m = random.uniform(3.0, 20.0);
        RingSog ring = RingSog::generate(1, 2, center_m, range_m, RingSogParams{});
        // The truth on a component's bearing, so that "nearest" is not a matter of millimetres.
        const uint32_t truth_k = static_cast<uint32_t>(random.below(ring.size()));
        const double bearing = kTwoPi * truth_k / ring.size();
        const Vector2 target_m = center_m + range_m * Vector2(std::cos(bearing), std::sin(bearing));
        // Two witnesses, not on a line with the centre: no mirror image fits them both.
        std::vector<RangeWitness> witnesses;
        for (int w = 0; w < 2; ++w) {
            const double angle = bearing + (w == 0 ? 1.3 : -2.1);
            const Vector2 position_m = target_m + random.uniform(4.0, 12.0) * Vector2(std::cos(angle), std::sin(angle));
            witnesses.push_back(RangeWitness{position_m, 0.01 * Matrix2::Identity(), (position_m - target_m).norm()});
        }
        const auto result = ring.updateWeights(witnesses, likelihood, 0.1);
        EXPECT_FALSE(result.collapsed);
        EXPECT_EQ(nearestComponent(ring, target_m), truth_k);
        EXPECT_EQ(ring.heaviest(), truth_k) << "trial " << trial;
        EXPECT_NEAR(weightSum(ring), 1.0, 1e-12);
    }
}

TEST(RingSog, AnNlosWitnessIsCountedAndDoesNotMoveAConcentratedRing)
{
    const RangeLikelihood likelihood;
    const Vector2 center_m(0.0, 0.0);
    RingSog ring = RingSog::generate(1, 2, center_m, 10.0, RingSogParams{});
    const uint32_t truth_k = 9;
    const double bearing = kTwoPi * truth_k / ring.size();
    const Vector2 target_m = 10.0 * Vector2(std::cos(bearing), std::sin(bearing));
    const std::vector<RangeWitness> good = {
        {target_m + Vector2(8.0, 0.0), Matrix2::Zero(), 8.0},
        {target_m + Vector2(0.0, -8.0), Matrix2::Zero(), 8.0},
    };
    ring.updateWeights(good, likelihood, 0.1);
    ring.transferWeights(0.5);
    ASSERT_EQ(ring.heaviest(), truth_k);
    // A third node behind a wall, 10 m from the target, reads 3 m too long.
    const std::vector<RangeWitness> nlos = {{target_m + Vector2(-6.0, 8.0), Matrix2::Zero(), 10.0 + 3.0}};
    const auto result = ring.updateWeights(nlos, likelihood, 0.1);
    EXPECT_EQ(result.downweighted, 1U);
    EXPECT_FALSE(result.collapsed);
    EXPECT_EQ(ring.heaviest(), truth_k);
    // No witnesses: nothing to learn, nothing changes.
    const std::vector<SogComponentState> before = ring.components();
    const auto none = ring.updateWeights({}, likelihood, 0.1);
    EXPECT_FALSE(none.collapsed);
    for (uint32_t k = 0; k < ring.size(); ++k) {
        EXPECT_EQ(ring.component(k).weight, before[k].weight);
    }
}

TEST(RingSog, PartialUpdatesTouchOnlyTheActiveSet)
{
    RingSog ring = concentrated(10);
    ring.transferWeights(0.5); // a handful of components around 10 carry the weight
    const std::vector<SogComponentState> before = ring.components();
    const double heaviest_weight = before[ring.heaviest()].weight;
    std::vector<bool> active(before.size());
    uint32_t active_count = 0;
    for (size_t k = 0; k < before.size(); ++k) {
        active[k] = before[k].weight >= RingSog::kActiveRatio * heaviest_weight;
        active_count += active[k] ? 1U : 0U;
    }
    ASSERT_GE(active_count, 3U);
    ASSERT_LT(active_count, before.size() / 4);

    const auto update = ring.updateWithRange(Vector2(1.0, -2.0), Matrix2::Zero(), 10.2, 0.1, 4.0, 1e-6, false);
    EXPECT_EQ(update.updated + update.gated, active_count);
    std::vector<SogComponentState> after = ring.components();
    for (size_t k = 0; k < before.size(); ++k) {
        if (active[k]) {
            EXPECT_NE(after[k].mean_m, before[k].mean_m) << k;
        } else {
            EXPECT_EQ(after[k].mean_m, before[k].mean_m) << k;
            EXPECT_EQ(after[k].covariance_m2, before[k].covariance_m2) << k;
        }
    }

    // Evidence for the far side of the ring: a partial update cannot see it there, so it
    // cannot call it a collapse either; the floor-level components stay at the floor.
    const Vector2 far_m = ring.component(static_cast<uint32_t>(10 + before.size() / 2)).mean_m;
    const std::vector<RangeWitness> witnesses = {{far_m + Vector2(0.0, 5.0), Matrix2::Zero(), 5.0},
                                                 {far_m + Vector2(5.0, 0.0), Matrix2::Zero(), 5.0}};
    RingSog full = ring;
    const auto partial_result = ring.updateWeights(witnesses, RangeLikelihood(), 0.1, false);
    EXPECT_FALSE(partial_result.collapsed);
    after = ring.components();
    for (size_t k = 0; k < before.size(); ++k) {
        if (!active[k]) {
            EXPECT_LE(after[k].weight, ring.weightFloor() * 1.0001) << k;
        }
    }
    EXPECT_TRUE(active[ring.heaviest()]);
    // The full update over the same ring sees the far side and resets to it.
    const auto full_result = full.updateWeights(witnesses, RangeLikelihood(), 0.1, true);
    EXPECT_TRUE(full_result.collapsed);
    EXPECT_LT((full.component(full.heaviest()).mean_m - far_m).norm(), 1.5);
}

} // namespace
} // namespace cdro::enginetest
