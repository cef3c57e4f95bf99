#include "cdro/fixed.h"

#include <math.h>

/* Rounds half away from zero and saturates to [lo, hi]; NaN maps to 0. */
static double round_clamp(double value, double lo, double hi)
{
    if (isnan(value)) {
        return 0.0;
    }
    value = (value >= 0.0) ? floor(value + 0.5) : ceil(value - 0.5);
    if (value < lo) {
        return lo;
    }
    if (value > hi) {
        return hi;
    }
    return value;
}

cdro_mm_t cdro_fixed_mm_from_m(double metres)
{
    return (cdro_mm_t)round_clamp(metres * 1000.0, -2147483648.0, 2147483647.0);
}

double cdro_fixed_mm_to_m(cdro_mm_t millimetres) { return (double)millimetres / 1000.0; }

cdro_um_t cdro_fixed_um_from_m(double metres) { return (cdro_um_t)round_clamp(metres * 1.0e6, 0.0, 4294967295.0); }

double cdro_fixed_um_to_m(cdro_um_t micrometres) { return (double)micrometres / 1.0e6; }

cdro_q15_t cdro_fixed_q15_from(double value) { return (cdro_q15_t)round_clamp(value * 32767.0, -32767.0, 32767.0); }

double cdro_fixed_q15_to(cdro_q15_t q15) { return (double)q15 / 32767.0; }

cdro_q16_t cdro_fixed_q16_from(double value) { return (cdro_q16_t)round_clamp(value * 65535.0, 0.0, 65535.0); }

double cdro_fixed_q16_to(cdro_q16_t q16) { return (double)q16 / 65535.0; }

static double non_negative(double value) { return (value > 0.0 && isfinite(value)) ? value : 0.0; }

cdro_fixed_covariance_t cdro_fixed_covariance_from(double var_x_m2, double cov_xy_m2, double var_y_m2)
{
    cdro_fixed_covariance_t fixed;
    const double std_x = sqrt(non_negative(var_x_m2));
    const double std_y = sqrt(non_negative(var_y_m2));
    const double denominator = std_x * std_y;
    fixed.std_x_um = cdro_fixed_um_from_m(std_x);
    fixed.std_y_um = cdro_fixed_um_from_m(std_y);
    fixed.correlation_q15 = (denominator > 0.0) ? cdro_fixed_q15_from(cov_xy_m2 / denominator) : 0;
    return fixed;
}

void cdro_fixed_covariance_to(cdro_fixed_covariance_t fixed, double *var_x_m2, double *cov_xy_m2, double *var_y_m2)
{
    const double std_x = cdro_fixed_um_to_m(fixed.std_x_um);
    const double std_y = cdro_fixed_um_to_m(fixed.std_y_um);
    *var_x_m2 = std_x * std_x;
    *var_y_m2 = std_y * std_y;
    *cov_xy_m2 = cdro_fixed_q15_to(fixed.correlation_q15) * std_x * std_y;
}
