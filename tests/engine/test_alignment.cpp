// alignment: fitRigid recovers a rotation and translation, a reflection when allowed, and its
// rms error is that of the transform it returns, no larger than the true transform's.
#include <cmath>
#include <fstream>
#include <sstream>

#include <Eigen/LU>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "cdro/engine/alignment.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::fitRigid;
using engine::Matrix2;
using engine::RigidTransform;

constexpr double kTwoPi = 6.28318530717958647692;

Matrix2 rotationOf(double angle_rad)
{
    Matrix2 r;
    r << std::cos(angle_rad), -std::sin(angle_rad), std::sin(angle_rad), std::cos(angle_rad);
    return r;
}

std::vector<Vector2> randomPoints(Random &random, size_t count)
{
    std::vector<Vector2> points;
    for (size_t i = 0; i < count; ++i) {
        points.push_back(uniformPoint(random, -40.0, 40.0));
    }
    return points;
}

double rmsOf(const RigidTransform &t, const std::vector<Vector2> &source, const std::vector<Vector2> &target)
{
    double sum = 0.0;
    for (size_t i = 0; i < source.size(); ++i) {
        sum += (t.apply(source[i]) - target[i]).squaredNorm();
    }
    return std::sqrt(sum / static_cast<double>(source.size()));
}

TEST(Alignment, RecoversARandomRotationAndTranslation)
{
    const uint64_t seed = testSeed(3301);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    for (int trial = 0; trial < 50; ++trial) {
        const std::vector<Vector2> source = randomPoints(random, 2 + random.below(30));
        const Matrix2 rotation = rotationOf(random.uniform(0.0, kTwoPi));
        const Vector2 translation_m = uniformPoint(random, -100.0, 100.0);
        std::vector<Vector2> target;
        target.reserve(source.size());
        for (const Vector2 &p : source) {
            target.push_back(rotation * p + translation_m);
        }
        for (const bool allow_reflection : {false, true}) {
            const RigidTransform fit = fitRigid(source, target, allow_reflection);
            EXPECT_FALSE(fit.reflected);
            EXPECT_NEAR((fit.rotation - rotation).norm(), 0.0, 1e-9) << trial;
            EXPECT_NEAR((fit.translation_m - translation_m).norm(), 0.0, 1e-9) << trial;
            EXPECT_LT(fit.rms_error_m, 1e-9);
            EXPECT_NEAR(fit.rotation.determinant(), 1.0, 1e-12);
        }
    }
}

TEST(Alignment, RecoversAReflectionWhenAllowed)
{
    const uint64_t seed = testSeed(3302);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    for (int trial = 0; trial < 50; ++trial) {
        const std::vector<Vector2> source = randomPoints(random, 3 + random.below(30));
        Matrix2 mirror = rotationOf(random.uniform(0.0, kTwoPi));
        mirror.col(1) *= -1.0; // determinant -1
        const Vector2 translation_m = uniformPoint(random, -100.0, 100.0);
        std::vector<Vector2> target;
        target.reserve(source.size());
        for (const Vector2 &p : source) {
            target.push_back(mirror * p + translation_m);
        }
        const RigidTransform fit = fitRigid(source, target, true);
        EXPECT_TRUE(fit.reflected) << trial;
        EXPECT_NEAR(fit.rotation.determinant(), -1.0, 1e-12);
        EXPECT_NEAR((fit.rotation - mirror).norm(), 0.0, 1e-9) << trial;
        EXPECT_NEAR((fit.translation_m - translation_m).norm(), 0.0, 1e-9) << trial;
        EXPECT_LT(fit.rms_error_m, 1e-9);
        for (size_t i = 0; i < source.size(); ++i) {
            EXPECT_NEAR((fit.apply(source[i]) - target[i]).norm(), 0.0, 1e-9);
        }
        // Without the reflection the best proper fit is far off.
        const RigidTransform proper = fitRigid(source, target, false);
        EXPECT_FALSE(proper.reflected);
        EXPECT_GT(proper.rms_error_m, 1.0) << trial;
    }
}

TEST(Alignment, RmsErrorOfNoisyPointsIsThatOfTheReturnedTransform)
{
    const uint64_t seed = testSeed(3303);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    for (int trial = 0; trial < 20; ++trial) {
        const std::vector<Vector2> source = randomPoints(random, 40);
        const Matrix2 rotation = rotationOf(random.uniform(0.0, kTwoPi));
        const Vector2 translation_m = uniformPoint(random, -10.0, 10.0);
        const double noise_m = 0.05;
        std::vector<Vector2> target;
        target.reserve(source.size());
        for (const Vector2 &p : source) {
            target.push_back(rotation * p + translation_m + noise_m * normalPoint(random));
        }
        const RigidTransform fit = fitRigid(source, target, true);
        EXPECT_FALSE(fit.reflected);
        EXPECT_NEAR(fit.rms_error_m, rmsOf(fit, source, target), 1e-12);
        // Least squares: no worse than the transform that made the points.
        RigidTransform truth;
        truth.rotation = rotation;
        truth.translation_m = translation_m;
        EXPECT_LE(fit.rms_error_m, rmsOf(truth, source, target) + 1e-12);
        // And about the noise: sqrt(2) sigma per point, less the 3 fitted degrees of freedom.
        EXPECT_NEAR(fit.rms_error_m, noise_m * std::sqrt(2.0), 0.35 * noise_m);
        EXPECT_NEAR((fit.rotation - rotation).norm(), 0.0, 0.01);
    }
}

TEST(Alignment, NoPointsOrMismatchedGiveTheIdentityOnePointTheShift)
{
    const RigidTransform none = fitRigid({}, {}, true);
    EXPECT_EQ(none.rotation, Matrix2::Identity());
    EXPECT_EQ(none.translation_m, Vector2::Zero());
    const RigidTransform one = fitRigid({Vector2(1.0, 1.0)}, {Vector2(5.0, 5.0)}, true);
    EXPECT_EQ(one.rotation, Matrix2::Identity());
    EXPECT_EQ(one.translation_m, Vector2(4.0, 4.0));
    const RigidTransform mismatched = fitRigid({Vector2(1.0, 1.0), Vector2(2.0, 0.0)}, {Vector2(5.0, 5.0)}, true);
    EXPECT_EQ(mismatched.rotation, Matrix2::Identity());
}

// One fit in two languages: the cases of tests/golden/alignment_cases.json (exact transforms,
// noisy ones with the Python fit's answer, collinear ones that both fit with the rotation) give
// the same transform here as in the tools (tests/tools/test_alignment_golden.py).
TEST(Alignment, GivesTheGoldenCasesAsThePythonFitDoes)
{
    std::ifstream in(std::string(CDRO_GOLDEN_DIR) + "/alignment_cases.json");
    ASSERT_TRUE(in) << "tests/golden/alignment_cases.json";
    std::stringstream text;
    text << in.rdbuf();
    const nlohmann::json golden = nlohmann::json::parse(text.str());
    ASSERT_GE(golden["cases"].size(), 12U);
    for (const nlohmann::json &c : golden["cases"]) {
        SCOPED_TRACE(c["name"].get<std::string>());
        std::vector<Vector2> source;
        std::vector<Vector2> target;
        for (size_t i = 0; i < c["source_m"].size(); ++i) {
            source.emplace_back(c["source_m"][i][0].get<double>(), c["source_m"][i][1].get<double>());
            target.emplace_back(c["target_m"][i][0].get<double>(), c["target_m"][i][1].get<double>());
        }
        const RigidTransform fit = fitRigid(source, target, true);
        const nlohmann::json &r = c["rotation"];
        Matrix2 golden_rotation;
        golden_rotation << r[0][0].get<double>(), r[0][1].get<double>(), r[1][0].get<double>(), r[1][1].get<double>();
        const Vector2 golden_translation_m(c["translation_m"][0].get<double>(), c["translation_m"][1].get<double>());
        EXPECT_LT((fit.rotation - golden_rotation).cwiseAbs().maxCoeff(), 1e-9) << fit.rotation;
        EXPECT_LT((fit.translation_m - golden_translation_m).cwiseAbs().maxCoeff(), 1e-9) << fit.translation_m;
        EXPECT_NEAR(fit.rms_error_m, c["rmse_m"].get<double>(), 1e-9);
        EXPECT_EQ(fit.reflected, fit.rotation.determinant() < 0.0);
        EXPECT_EQ(fit.reflected, golden_rotation.determinant() < 0.0);
    }
}

} // namespace
} // namespace cdro::enginetest
