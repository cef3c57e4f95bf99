// alignment: fitRigid recovers a rotation and translation, a reflection when allowed, and its
// rms error is that of the transform it returns, no larger than the true transform's.
// alignedErrors compares the nodes both maps place, with the errors a known map has.
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>

#include <Eigen/LU>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "cdro/engine/alignment.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::AlignedErrors;
using engine::alignedErrors;
using engine::fitRigid;
using engine::MapPoint;
using engine::Matrix2;
using engine::NodeId;
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

// A 4 m x 3 m rectangle's corners and its centre (ids 1-5), and a node (6) the map does not place.
const std::map<NodeId, Vector2> kRectangle = {{1, Vector2(0.0, 0.0)}, {2, Vector2(4.0, 0.0)}, {3, Vector2(4.0, 3.0)},
                                              {4, Vector2(0.0, 3.0)}, {5, Vector2(2.0, 1.5)}, {6, Vector2(10.0, 10.0)}};
const Vector2 kCentreM(2.0, 1.5);

// The rectangle grown by `scale` about its centre, then mirrored, turned by 30 degrees and
// shifted: in the map's own order, with a node (7) the reference does not have, far off.
std::vector<MapPoint> mirroredMap(double scale, const Matrix2 &mirror, const Vector2 &shift_m)
{
    std::vector<MapPoint> map;
    for (const NodeId id : std::vector<NodeId>{3, 7, 1, 5, 2, 4}) {
        if (id == 7) {
            map.push_back({id, Vector2(1000.0, -1000.0)});
            continue;
        }
        map.push_back({id, mirror * (kCentreM + scale * (kRectangle.at(id) - kCentreM)) + shift_m});
    }
    return map;
}

// A rectangle grown by 10 % about its centre fits the original best unturned (its cross-covariance
// is diagonal): each corner is then 10 % of the half-diagonal (2.5 m) off, 0.25 m, the centre 0 m,
// whatever rotation, reflection and shift the map was drawn in.
TEST(AlignedErrors, ComparesTheNodesBothMapsPlaceWithTheirKnownErrors)
{
    Matrix2 mirror = rotationOf(kTwoPi / 12.0);
    mirror.col(1) *= -1.0; // a reflection, then 30 degrees
    const Vector2 shift_m(10.0, -5.0);
    const std::vector<NodeId> compared = {3, 1, 5, 2, 4}; // the map's order; 6 and 7 in one map only
    for (const double scale : {1.0, 1.1}) {
        SCOPED_TRACE("scale " + std::to_string(scale));
        const double corner_m = (scale - 1.0) * 2.5;
        const std::vector<MapPoint> map = mirroredMap(scale, mirror, shift_m);
        const AlignedErrors aligned = alignedErrors(map, kRectangle, true);
        EXPECT_EQ(aligned.ids, compared);
        ASSERT_EQ(aligned.compared(), 5U);
        for (size_t k = 0; k < compared.size(); ++k) {
            EXPECT_NEAR(aligned.error_m[k], compared[k] == 5 ? 0.0 : corner_m, 1e-12) << compared[k];
        }
        EXPECT_NEAR(aligned.rmse_m, std::sqrt(4.0 * corner_m * corner_m / 5.0), 1e-12);
        EXPECT_NEAR(aligned.worst_m, corner_m, 1e-12);
        EXPECT_EQ(aligned.countOver(0.2), scale > 1.0 ? 4U : 0U);
        EXPECT_EQ(aligned.countOver(0.3), 0U);
        // The fit undoes the map's frame: the inverse of the mirror and the shift.
        EXPECT_TRUE(aligned.fit.reflected);
        EXPECT_LT((aligned.fit.rotation - mirror.inverse()).norm(), 1e-12);
        EXPECT_LT((aligned.fit.translation_m + mirror.inverse() * shift_m).norm(), 1e-12);
        // The node only the map has changes nothing; the paired form on the compared nodes agrees.
        std::vector<MapPoint> without_7;
        std::vector<Vector2> placed_m;
        std::vector<Vector2> reference_m;
        for (const MapPoint &point : map) {
            if (point.id != 7) {
                without_7.push_back(point);
                placed_m.push_back(point.position_m);
                reference_m.push_back(kRectangle.at(point.id));
            }
        }
        const AlignedErrors alone = alignedErrors(without_7, kRectangle, true);
        const AlignedErrors paired = alignedErrors(placed_m, reference_m, true);
        EXPECT_EQ(alone.error_m, aligned.error_m);
        EXPECT_EQ(paired.error_m, aligned.error_m);
        EXPECT_EQ(paired.rmse_m, aligned.rmse_m);
        EXPECT_TRUE(paired.ids.empty());
        // A mirror image does not fit by a rotation: without the reflection it is metres off.
        EXPECT_GT(alignedErrors(map, kRectangle, false).rmse_m, 1.0);
    }
}

TEST(AlignedErrors, NoNodeInCommonGivesNoFigureOneNodeNoError)
{
    const AlignedErrors none = alignedErrors({MapPoint{7, Vector2(1.0, 2.0)}}, kRectangle, true);
    EXPECT_EQ(none.compared(), 0U);
    EXPECT_TRUE(none.ids.empty());
    EXPECT_TRUE(std::isnan(none.rmse_m));
    EXPECT_TRUE(std::isnan(none.worst_m));
    EXPECT_EQ(none.countOver(0.0), 0U);
    EXPECT_EQ(none.fit.rotation, Matrix2::Identity());
    const AlignedErrors one = alignedErrors({MapPoint{2, Vector2(-3.0, 7.0)}}, kRectangle, true);
    EXPECT_EQ(one.ids, std::vector<NodeId>{2});
    EXPECT_EQ(one.rmse_m, 0.0);
    EXPECT_NEAR(one.error_m.at(0), 0.0, 1e-12);
    EXPECT_EQ(one.fit.translation_m, Vector2(7.0, -7.0));
}

TEST(AlignedErrors, ANodeListedTwiceOrUnpairedPositionsAreRefusedByName)
{
    const std::vector<MapPoint> twice = {{1, Vector2(0.0, 0.0)}, {3, Vector2(4.0, 3.0)}, {3, Vector2(4.0, 3.1)}};
    try {
        (void)alignedErrors(twice, kRectangle, true);
        ADD_FAILURE() << "a node listed twice was accepted";
    } catch (const std::invalid_argument &error) {
        EXPECT_NE(std::string(error.what()).find("node 3 is listed twice"), std::string::npos) << error.what();
    }
    try {
        (void)alignedErrors(std::vector<Vector2>{Vector2(0.0, 0.0), Vector2(1.0, 0.0)},
                            std::vector<Vector2>{Vector2(0.0, 0.0)}, true);
        ADD_FAILURE() << "unpaired positions were accepted";
    } catch (const std::invalid_argument &error) {
        EXPECT_NE(std::string(error.what()).find("2 map positions but 1 reference positions"), std::string::npos)
            << error.what();
    }
}

} // namespace
} // namespace cdro::enginetest
