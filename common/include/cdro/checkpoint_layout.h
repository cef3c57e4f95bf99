/*
 * checkpoint_layout.h: the service's extension block of a checkpoint (tag
 * CDRO_CHECKPOINT_TAG_SERVICE), generated from checkpoint_layout.def, which also holds every
 * extension tag. The checkpoint itself is a SoG snapshot (sog_layout.h).
 *
 * Host-side only. Both calls work on caller-owned memory, allocate nothing and cannot read or
 * write out of bounds.
 */
#ifndef CDRO_CHECKPOINT_LAYOUT_H
#define CDRO_CHECKPOINT_LAYOUT_H

#include <stddef.h>
#include <stdint.h>

#include "cdro/checkpoint_layout.def"
#include "cdro/layout_kinds.h"
#include "cdro/result.h"

#ifdef __cplusplus
extern "C" {
#endif

CDRO_CHECKPOINT_RECORD_LIST(CDRO_X_STRUCT) /* cdro_service_info_t */
CDRO_CHECKPOINT_RECORD_LIST(CDRO_X_SIZES)  /* CDRO_SERVICE_INFO_MAX_SIZE; the block is fixed-size */

/* Writes the block into out (CDRO_SERVICE_INFO_MAX_SIZE bytes) with version
 * CDRO_CHECKPOINT_SERVICE_INFO_VERSION, whatever info->version says; returns the bytes written. */
size_t cdro_service_info_encode(const cdro_service_info_t *info, uint8_t *out);

/* Reads a block of len bytes: CDRO_OK; CDRO_ERR_LENGTH if it is shorter than the block (bytes
 * after it are ignored: a later version may append fields); CDRO_ERR_VERSION for another version. */
cdro_result_t cdro_service_info_decode(const uint8_t *in, size_t len, cdro_service_info_t *out);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_CHECKPOINT_LAYOUT_H */
