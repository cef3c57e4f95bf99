#include "cdro/engine/scaled_range_model.hpp"

#include <cmath>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

ScaledRangePrediction predictScaledRange(const Vector2 &a_m, const Vector2 &b_m, double height_difference_m,
                                         double scale, double offset_m)
{
    ScaledRangePrediction prediction;
    const Vector2 offset = a_m - b_m;
    prediction.distance_m = std::sqrt(offset.squaredNorm() + height_difference_m * height_difference_m);
    prediction.range_m = scale * prediction.distance_m + offset_m;
    prediction.jacobian_scale = prediction.distance_m;
    if (prediction.distance_m < kSingularDistanceM) {
        prediction.singular = true;
        return prediction;
    }
    const Eigen::RowVector2d unit = (offset / prediction.distance_m).transpose();
    prediction.jacobian_a = scale * unit;
    prediction.jacobian_b = -scale * unit;
    return prediction;
}

} // namespace cdro::engine
