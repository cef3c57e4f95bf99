/*
 * cobs.h: Consistent Overhead Byte Stuffing (Cheshire & Baker, 1999).
 *
 * The encoded bytes never contain 0x00, so 0x00 delimits frames on the serial line and a
 * receiver that lost sync resynchronises at the next 0x00. Overhead: at most one byte per 254
 * bytes, plus one. This is the common variant without a trailing 0x01 after a full 254-byte
 * block (the Wikipedia examples are our golden vectors).
 *
 * Buffers are owned by the caller; no call allocates. Each call is O(len).
 */
#ifndef CDRO_COBS_H
#define CDRO_COBS_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Worst-case encoded size of len input bytes (without the 0x00 delimiter). */
#define CDRO_COBS_MAX_ENCODED(len) ((len) + ((len) / 254U) + 1U)

/*
 * Encodes len bytes from src into dst (capacity dst_cap), without the trailing delimiter.
 * Returns the encoded length, or 0 if dst is too small (an encoding is never empty).
 */
size_t cdro_cobs_encode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap);

/*
 * Decodes len COBS bytes (the delimiter excluded) from src into dst (capacity dst_cap).
 * Returns the decoded length (>= 0), or -1 when src is not a valid encoding (a 0x00 inside,
 * a code byte pointing past the end, empty input) or dst is too small.
 * src and dst may be the same buffer (decoding never writes ahead of reading).
 */
long cdro_cobs_decode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_COBS_H */
