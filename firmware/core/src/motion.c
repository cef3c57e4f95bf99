/*
 * motion.c: the motion detector (see motion.h).
 */
#include "cdro_fw/motion.h"

#include <string.h>

/* Rounded integer square root: the n with |n - sqrt(value)| <= 0.5. */
static uint16_t isqrt_rounded(uint32_t value)
{
    uint32_t root = 0;
    uint32_t bit = 1UL << 30;
    uint32_t rest = value;
    while (bit > rest) {
        bit >>= 2;
    }
    while (bit != 0U) {
        if (rest >= root + bit) {
            rest -= root + bit;
            root = (root >> 1) + bit;
        } else {
            root >>= 1;
        }
        bit >>= 2;
    }
    /* root = floor(sqrt(value)); round up when value > root^2 + root, i.e. sqrt > root + 0.5. */
    if (rest > root) {
        ++root;
    }
    return (uint16_t)root;
}

static uint32_t square(int16_t v)
{
    const int32_t w = v;
    return (uint32_t)(w * w);
}

uint16_t cdro_accel_norm_mg(const cdro_accel_t *accel)
{
    /* 3 x 32768^2 = 3.2e9 fits in 32 bits. */
    return isqrt_rounded(square(accel->x_mg) + square(accel->y_mg) + square(accel->z_mg));
}

void cdro_motion_detector_init(cdro_motion_detector_t *motion) { memset(motion, 0, sizeof(*motion)); }

uint8_t cdro_motion_detector_update(cdro_motion_detector_t *motion, const cdro_accel_t *accel)
{
    const uint16_t norm_mg = cdro_accel_norm_mg(accel);
    const uint16_t deviation_mg =
        norm_mg >= CDRO_FW_ONE_G_MG ? (uint16_t)(norm_mg - CDRO_FW_ONE_G_MG) : (uint16_t)(CDRO_FW_ONE_G_MG - norm_mg);
    uint16_t window_mg = 0;
    uint8_t i;
    const uint8_t was_moving = motion->moving;

    motion->norm_mg = norm_mg;
    motion->deviation_mg[motion->next] = deviation_mg;
    motion->next = (uint8_t)((motion->next + 1U) % CDRO_FW_MOTION_WINDOW);
    for (i = 0; i < CDRO_FW_MOTION_WINDOW; ++i) {
        /* Slots not yet filled hold 0 (init), which never raises the maximum. */
        if (motion->deviation_mg[i] > window_mg) {
            window_mg = motion->deviation_mg[i];
        }
    }
    motion->window_deviation_mg = window_mg;

    if (window_mg < CDRO_FW_STILL_BELOW_MG) {
        if (motion->still_count < CDRO_FW_STILL_SAMPLES) {
            ++motion->still_count;
        }
    } else {
        motion->still_count = 0;
    }
    if (!motion->moving && window_mg > CDRO_FW_MOVING_ABOVE_MG) {
        motion->moving = 1;
    } else if (motion->moving && motion->still_count >= CDRO_FW_STILL_SAMPLES) {
        motion->moving = 0;
    }
    return (uint8_t)(motion->moving != was_moving);
}
