/*
 * frames.h: the CDRO serial protocol between the firmware and the host.
 *
 * On the wire, one frame is
 *     COBS( header | payload | crc16 ) 0x00
 * with the header
 *     offset 0  u8   protocol version (CDRO_PROTOCOL_VERSION)
 *     offset 1  u8   frame type (cdro_frame_type_t)
 *     offset 2  u16  sequence number, per sender, wrapping
 *     offset 4  u8   payload length in bytes (<= CDRO_MAX_PAYLOAD)
 * and the CRC-16/CCITT-FALSE of header and payload, little-endian. All multi-byte fields are
 * little-endian. The payload layouts are defined once, in frame_layout.def; docs/protocol.md
 * documents them as byte-offset tables.
 *
 * Error model: functions return cdro_result_t; 0 is success, CDRO_PENDING (> 0) means "feed
 * more bytes", negative values are distinct rejections. No call allocates; buffers belong to
 * the caller. Decoding is safe on any input bytes (see docs/protocol.md, "Security model").
 */
#ifndef CDRO_FRAMES_H
#define CDRO_FRAMES_H

#include <stddef.h>
#include <stdint.h>

#include "cdro/cobs.h"
#include "cdro/result.h"
#include "cdro/frame_layout.def"
#include "cdro/layout_kinds.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- frame types ---------------------------------------------------------------------- */

#define CDRO_X_TYPE_ENUM(NAME, name, id, doc) CDRO_FRAME_##NAME = id,
typedef enum cdro_frame_type {
    CDRO_FRAME_LIST(CDRO_X_TYPE_ENUM) CDRO_EMPTY_FRAME_LIST(CDRO_X_TYPE_ENUM) CDRO_FRAME_TYPE_NONE = 0
} cdro_frame_type_t;
#undef CDRO_X_TYPE_ENUM

/* Name of a frame type ("RANGE"), or NULL if unknown. */
const char *cdro_frame_type_name(uint8_t type);

/* ---- payload structs, one per non-empty frame type ------------------------------------ */

CDRO_FRAME_LIST(CDRO_X_STRUCT)

/* Payload sizes in bytes: CDRO_<NAME>_MIN_SIZE (arrays empty) and CDRO_<NAME>_MAX_SIZE. */
CDRO_FRAME_LIST(CDRO_X_SIZES)

/* ---- a whole frame ---------------------------------------------------------------------- */

#define CDRO_X_UNION_MEMBER(NAME, name, id, doc) cdro_##name##_t name;
typedef struct cdro_frame {
    uint8_t version;   /* protocol version from the header (set by the decoder; the encoder
                          always writes CDRO_PROTOCOL_VERSION) */
    uint8_t type;      /* cdro_frame_type_t */
    uint16_t sequence; /* per sender, wrapping */
    union {
        CDRO_FRAME_LIST(CDRO_X_UNION_MEMBER)
    } as; /* the member named after `type`; unused for empty frames */
} cdro_frame_t;
#undef CDRO_X_UNION_MEMBER

/* Largest raw frame (header + payload + CRC) and its largest encoding with the delimiter. */
#define CDRO_MAX_RAW_FRAME (CDRO_HEADER_SIZE + CDRO_MAX_PAYLOAD + CDRO_CRC_SIZE)
#define CDRO_MAX_ENCODED_FRAME (CDRO_COBS_MAX_ENCODED(CDRO_MAX_RAW_FRAME) + 1U)

/*
 * Encodes frame (type, sequence, and the payload member for its type) into out: COBS bytes
 * followed by the 0x00 delimiter. Returns the number of bytes written, or 0 if out_cap is too
 * small, the type is unknown, or an array count exceeds its maximum. Never reads frame->version.
 */
size_t cdro_frame_encode(const cdro_frame_t *frame, uint8_t *out, size_t out_cap);

/*
 * Decodes one chunk: the COBS bytes between two delimiters, without the 0x00. Checks, in
 * order: length (TOO_LONG), COBS, SHORT, CRC, VERSION, length field (LENGTH), TYPE, and the
 * type's layout (LENGTH). Once the CRC has passed, out->version, type and sequence are set
 * even when a later check fails, so that the receiver can name what it rejected. Does not
 * check field values: see cdro_frame_validate.
 */
cdro_result_t cdro_frame_decode(const uint8_t *chunk, size_t len, cdro_frame_t *out);

/*
 * Checks a decoded frame's fields against their documented ranges (docs/protocol.md):
 * CDRO_OK or CDRO_ERR_VALUE.
 */
cdro_result_t cdro_frame_validate(const cdro_frame_t *frame);

/* ---- streaming decoder with resynchronisation ----------------------------------------- */

typedef struct cdro_decoder_counters {
    uint32_t frames_ok; /* decoded and validated */
    uint32_t cobs_errors;
    uint32_t short_errors;
    uint32_t crc_errors;
    uint32_t version_errors;
    uint32_t type_errors;
    uint32_t length_errors;
    uint32_t value_errors;
    uint32_t too_long_errors;
    uint32_t bytes_discarded; /* bytes of every rejected chunk, delimiters excluded */
} cdro_decoder_counters_t;

typedef struct cdro_decoder {
    uint8_t chunk[CDRO_MAX_ENCODED_FRAME]; /* bytes since the last delimiter */
    uint8_t chunk_len;                     /* bytes held in chunk */
    uint8_t overflowed;                    /* the current chunk outgrew chunk: drop until 0x00 */
    uint8_t last_chunk_len;                /* length of the chunk that just ended (see push) */
    uint32_t overflow_len;                 /* bytes of the current overlong chunk */
    cdro_decoder_counters_t counters;
} cdro_decoder_t;

void cdro_decoder_init(cdro_decoder_t *decoder);

/*
 * Feeds one received byte. Returns
 *   CDRO_PENDING  while no chunk has ended (also for empty chunks: repeated 0x00 are allowed);
 *   CDRO_OK       a frame was decoded and validated into *out;
 *   < 0           the chunk that just ended was rejected and counted; the decoder is already
 *                 resynchronised. For CDRO_ERR_VALUE, *out holds the decoded frame so that the
 *                 caller can report it; it must not be used as data.
 * When the return is not CDRO_PENDING, decoder->chunk[0 .. last_chunk_len) still holds the
 * chunk's bytes until the next call (for capture files); for CDRO_ERR_TOO_LONG only its first
 * bytes are kept.
 */
cdro_result_t cdro_decoder_push(cdro_decoder_t *decoder, uint8_t byte, cdro_frame_t *out);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_FRAMES_H */
