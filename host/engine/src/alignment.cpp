#include "cdro/engine/alignment.hpp"

#include <algorithm>
#include <cmath>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>

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

size_t AlignedErrors::countOver(double limit_m) const
{
    return static_cast<size_t>(
        std::count_if(error_m.begin(), error_m.end(), [limit_m](double error) { return error > limit_m; }));
}

AlignedErrors alignedErrors(const std::vector<MapPoint> &map_m, const std::map<NodeId, Vector2> &reference_m,
                            bool allow_reflection)
{
    std::set<NodeId> seen;
    std::vector<NodeId> ids;
    std::vector<Vector2> placed_m;
    std::vector<Vector2> wanted_m;
    for (const MapPoint &point : map_m) {
        if (!seen.insert(point.id).second) {
            throw std::invalid_argument("alignedErrors: node " + std::to_string(point.id) +
                                        " is listed twice in the map (each node once)");
        }
        const auto reference = reference_m.find(point.id);
        if (reference != reference_m.end()) {
            ids.push_back(point.id);
            placed_m.push_back(point.position_m);
            wanted_m.push_back(reference->second);
        }
    }
    AlignedErrors aligned = alignedErrors(placed_m, wanted_m, allow_reflection);
    aligned.ids = std::move(ids);
    return aligned;
}

AlignedErrors alignedErrors(const std::vector<Vector2> &map_m, const std::vector<Vector2> &reference_m,
                            bool allow_reflection)
{
    if (map_m.size() != reference_m.size()) {
        throw std::invalid_argument("alignedErrors: " + std::to_string(map_m.size()) + " map positions but " +
                                    std::to_string(reference_m.size()) +
                                    " reference positions (the paired form takes one of each per node)");
    }
    AlignedErrors aligned;
    if (map_m.empty()) {
        return aligned;
    }
    aligned.fit = fitRigid(map_m, reference_m, allow_reflection);
    aligned.rmse_m = aligned.fit.rms_error_m;
    aligned.worst_m = 0.0;
    aligned.error_m.reserve(map_m.size());
    for (size_t i = 0; i < map_m.size(); ++i) {
        const double error_m = (aligned.fit.apply(map_m[i]) - reference_m[i]).norm();
        aligned.error_m.push_back(error_m);
        aligned.worst_m = std::max(aligned.worst_m, error_m);
    }
    return aligned;
}

} // namespace cdro::engine
