/*
 * fixed.h: fixed-point types of the wire and snapshot formats, and their conversions.
 *
 * Conversions round to nearest and saturate at the type's range; they never overflow.
 *   cdro_mm_t       i32 millimetres         (positions)            error <= 0.5 mm
 *   cdro_um_t       u32 micrometres         (standard deviations)  error <= 0.5 um
 *   cdro_q15_t      i16, 32767 = 1.0        (correlations)         error <= 1.6e-5
 *   cdro_q16_t      u16, 65535 = 1.0        (weights in [0, 1])    error <= 7.7e-6
 * A 2x2 covariance travels as (std_x, std_y, correlation): decoding always gives a symmetric
 * positive semi-definite matrix, which a raw (xx, xy, yy) triple would not guarantee.
 *
 * On the AVR, double is 32 bits; the firmware does not use these conversions.
 */
#ifndef CDRO_FIXED_H
#define CDRO_FIXED_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef int32_t cdro_mm_t;
typedef uint32_t cdro_um_t;
typedef int16_t cdro_q15_t;
typedef uint16_t cdro_q16_t;

cdro_mm_t cdro_fixed_mm_from_m(double metres);
double cdro_fixed_mm_to_m(cdro_mm_t millimetres);

cdro_um_t cdro_fixed_um_from_m(double metres); /* negative input gives 0 */
double cdro_fixed_um_to_m(cdro_um_t micrometres);

cdro_q15_t cdro_fixed_q15_from(double value); /* clamps to [-1, 1] */
double cdro_fixed_q15_to(cdro_q15_t q15);

cdro_q16_t cdro_fixed_q16_from(double value); /* clamps to [0, 1] */
double cdro_fixed_q16_to(cdro_q16_t q16);

/* A 2x2 covariance (m^2) to (std_x, std_y, correlation) and back. Non-finite or negative
 * variances are treated as 0; |correlation| is clamped to 1. */
typedef struct cdro_fixed_covariance {
    cdro_um_t std_x_um;
    cdro_um_t std_y_um;
    cdro_q15_t correlation_q15;
} cdro_fixed_covariance_t;

cdro_fixed_covariance_t cdro_fixed_covariance_from(double var_x_m2, double cov_xy_m2, double var_y_m2);
void cdro_fixed_covariance_to(cdro_fixed_covariance_t fixed, double *var_x_m2, double *cov_xy_m2, double *var_y_m2);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_FIXED_H */
