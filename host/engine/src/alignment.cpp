#include "cdro/engine/alignment.hpp"

#include <cmath>

#include <Eigen/LU>
#include <Eigen/SVD>

namespace cdro::engine {

namespace {

RigidTransform fitProper(const std::vector<Vector2> &source, const std::vector<Vector2> &target, bool reflect)
{
    const Matrix2 mirror = reflect ? Matrix2(Eigen::Vector2d(1.0, -1.0).asDiagonal()) : Matrix2::Identity();
    const size_t count = source.size();
    Vector2 source_mean = Vector2::Zero();
    Vector2 target_mean = Vector2::Zero();
    for (size_t i = 0; i < count; ++i) {
        source_mean += mirror * source[i];
        target_mean += target[i];
    }
    source_mean /= static_cast<double>(count);
    target_mean /= static_cast<double>(count);
    Matrix2 cross = Matrix2::Zero();
    for (size_t i = 0; i < count; ++i) {
        cross += (mirror * source[i] - source_mean) * (target[i] - target_mean).transpose();
    }
    const Eigen::JacobiSVD<Matrix2> svd(cross, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Matrix2 correction = Matrix2::Identity();
    if ((svd.matrixV() * svd.matrixU().transpose()).determinant() < 0.0) {
        correction(1, 1) = -1.0;
    }
    const Matrix2 rotation = svd.matrixV() * correction * svd.matrixU().transpose();
    RigidTransform transform;
    transform.rotation = rotation * mirror;
    transform.translation_m = target_mean - rotation * source_mean;
    transform.reflected = reflect;
    double squared = 0.0;
    for (size_t i = 0; i < count; ++i) {
        squared += (transform.apply(source[i]) - target[i]).squaredNorm();
    }
    transform.rms_error_m = std::sqrt(squared / static_cast<double>(count));
    return transform;
}

// sqrt(mean |p_i - p_mean|^2) (m): how far the points lie from their centre.
double spreadOf(const std::vector<Vector2> &points_m)
{
    Vector2 mean_m = Vector2::Zero();
    for (const Vector2 &p : points_m) {
        mean_m += p;
    }
    mean_m /= static_cast<double>(points_m.size());
    double squared_m2 = 0.0;
    for (const Vector2 &p : points_m) {
        squared_m2 += (p - mean_m).squaredNorm();
    }
    return std::sqrt(squared_m2 / static_cast<double>(points_m.size()));
}

// A reflection is kept only when it fits better by more than this share of the points' spread:
// on a collinear set both fit exactly as well, and rounding alone would pick one (differently in
// Eigen and in the tools' LAPACK fit). cdro_tools/evaluation/alignment.py keeps the same rule.
constexpr double kReflectionTie = 1e-9;

} // namespace

RigidTransform fitRigid(const std::vector<Vector2> &source_m, const std::vector<Vector2> &target_m,
                        bool allow_reflection)
{
    if (source_m.size() != target_m.size() || source_m.empty()) {
        return RigidTransform{};
    }
    if (source_m.size() == 1) {
        RigidTransform shift; // one point fixes the translation only
        shift.translation_m = target_m.front() - source_m.front();
        return shift;
    }
    RigidTransform proper = fitProper(source_m, target_m, false);
    if (!allow_reflection) {
        return proper;
    }
    RigidTransform mirrored = fitProper(source_m, target_m, true);
    const double tie_m = kReflectionTie * (spreadOf(source_m) + spreadOf(target_m));
    return mirrored.rms_error_m < proper.rms_error_m - tie_m ? mirrored : proper;
}

} // namespace cdro::engine
