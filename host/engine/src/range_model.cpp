#include "cdro/engine/range_model.hpp"

#include <cmath>

namespace cdro::engine {

RangePrediction predictRange(const Vector2 &point_m, const Vector2 &center_m, double height_difference_m, double scale,
                             double offset_m)
{
    RangePrediction prediction;
    const Vector2 offset = point_m - center_m;
    prediction.distance_m = std::sqrt(offset.squaredNorm() + height_difference_m * height_difference_m);
    prediction.range_m = scale * prediction.distance_m + offset_m;
    prediction.jacobian_scale = prediction.distance_m;
    if (prediction.distance_m < kSingularDistanceM) {
        prediction.singular = true;
        return prediction;
    }
    const Eigen::RowVector2d unit = (offset / prediction.distance_m).transpose();
    prediction.jacobian_point = scale * unit;
    prediction.jacobian_center = -scale * unit;
    return prediction;
}

RangePrediction3 predictRange(const Vector3 &point_m, const Vector3 &center_m)
{
    RangePrediction3 prediction;
    const Vector3 offset = point_m - center_m;
    prediction.range_m = offset.norm();
    if (prediction.range_m < kSingularDistanceM) {
        prediction.singular = true;
        return prediction;
    }
    prediction.jacobian_point = (offset / prediction.range_m).transpose();
    return prediction;
}

double projectRange(double range_m, double height_difference_m, bool *clamped)
{
    const double squared = range_m * range_m - height_difference_m * height_difference_m;
    if (squared < 0.0) {
        *clamped = true;
        return 0.0;
    }
    *clamped = false;
    return std::sqrt(squared);
}

} // namespace cdro::engine
