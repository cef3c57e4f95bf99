#include "cdro/engine/range_model.hpp"

#include <cmath>

namespace cdro::engine {

RangePrediction predictRange(const Vector2 &point_m, const Vector2 &center_m)
{
    RangePrediction prediction;
    const Vector2 offset = point_m - center_m;
    prediction.range_m = offset.norm();
    if (prediction.range_m < kSingularDistanceM) {
        prediction.singular = true;
        return prediction;
    }
    const Vector2 unit = offset / prediction.range_m;
    prediction.jacobian_point = unit.transpose();
    prediction.jacobian_center = -unit.transpose();
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
