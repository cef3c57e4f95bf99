/*
 * motion.h: moving/still detection from accelerometer samples (docs/protocol.md, "Motion").
 *
 * The norm of each sample (rounded to the nearest mg) is compared with 1 g; the deviation is
 * the largest |norm - 1000 mg| over the last CDRO_FW_MOTION_WINDOW samples (fewer until the
 * window has filled). A still node becomes moving when the deviation exceeds
 * CDRO_FW_MOVING_ABOVE_MG; a moving node becomes still when the deviation stays below
 * CDRO_FW_STILL_BELOW_MG for CDRO_FW_STILL_SAMPLES consecutive samples. Pure integer code, no
 * clock: the caller decides when to sample.
 */
#ifndef CDRO_FW_MOTION_H
#define CDRO_FW_MOTION_H

#include <stdint.h>

#include "cdro_fw/config.h"
#include "cdro_fw/pozyx.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct cdro_motion_detector {
    uint16_t deviation_mg[CDRO_FW_MOTION_WINDOW]; /* mg, |norm - 1 g| of the last samples */
    uint8_t next;                                 /* index of the oldest sample in deviation_mg */
    uint8_t still_count;                          /* consecutive samples with the deviation below the still threshold */
    uint8_t moving;                               /* 1 = moving */
    uint16_t norm_mg;                             /* mg, norm of the last sample */
    uint16_t window_deviation_mg;                 /* mg, the deviation that decided the state */
} cdro_motion_detector_t;

void cdro_motion_detector_init(cdro_motion_detector_t *motion);

/* Adds one sample; returns 1 if the moving/still state changed, else 0. */
uint8_t cdro_motion_detector_update(cdro_motion_detector_t *motion, const cdro_accel_t *accel);

/* Norm of an acceleration in mg, rounded to the nearest mg (0 .. 56756). */
uint16_t cdro_accel_norm_mg(const cdro_accel_t *accel);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_FW_MOTION_H */
