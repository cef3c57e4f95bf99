#include "cdro/frames.h"

#include <string.h>

#include "cdro/crc.h"
#include "cdro/wire.h"
#include "layout_codec.h"

const char *cdro_result_name(int status)
{
    switch (status) {
    case CDRO_PENDING: return "pending";
    case CDRO_OK: return "ok";
    case CDRO_ERR_ARGUMENT: return "argument";
    case CDRO_ERR_COBS: return "cobs";
    case CDRO_ERR_SHORT: return "short";
    case CDRO_ERR_CRC: return "crc";
    case CDRO_ERR_VERSION: return "version";
    case CDRO_ERR_TYPE: return "type";
    case CDRO_ERR_LENGTH: return "length";
    case CDRO_ERR_TOO_LONG: return "too_long";
    case CDRO_ERR_VALUE: return "value";
    default: return "unknown";
    }
}

const char *cdro_frame_type_name(uint8_t type)
{
#define CDRO_X_NAME_CASE(NAME, name, id, doc) \
    case id: return #NAME;
    switch (type) {
        CDRO_FRAME_LIST(CDRO_X_NAME_CASE)
        CDRO_EMPTY_FRAME_LIST(CDRO_X_NAME_CASE)
    default: return NULL;
    }
#undef CDRO_X_NAME_CASE
}

/* ---- payload codecs, generated field by field from frame_layout.def -------------------- */

/*
 * CDRO_FRAMES_DEVICE_SIDE (the firmware image's build, where flash is short): the device only
 * sends device-to-host types and only takes host-to-device ones. Its encoder then refuses the
 * host-to-device types (returns 0), and its decoder checks a device-to-host frame's length
 * without decoding its fields: CDRO_ERR_TYPE if the length is that type's, else
 * CDRO_ERR_LENGTH, so that the device answers exactly as with the full decoder (UNKNOWN_TYPE
 * whatever the values, MALFORMED for a wrong length). Validation of device-to-host types is
 * left out (never reached). tests/common/test_device_codec.cpp checks it against the golden
 * vectors.
 */
#if defined(CDRO_FRAMES_DEVICE_SIDE)
#define CDRO_DEVICE_SIDE 1
#else
#define CDRO_DEVICE_SIDE 0
#endif
/* A device-to-host type whose fields the device-side decoder skips: fixed-size ones only (the
 * length of one with an array depends on its count). */
#define CDRO_SKIPPED_BY_DEVICE(NAME, id) \
    (CDRO_DEVICE_SIDE && (id) < 0x40 && CDRO_##NAME##_MIN_SIZE == CDRO_##NAME##_MAX_SIZE)

/* Every payload fits CDRO_MAX_PAYLOAD; checked here at compile time. */
#define CDRO_X_FITS(NAME, name, id, doc) \
    typedef char cdro_##name##_fits_payload[(CDRO_##NAME##_MAX_SIZE <= CDRO_MAX_PAYLOAD) ? 1 : -1];
CDRO_FRAME_LIST(CDRO_X_FITS)
#undef CDRO_X_FITS

CDRO_FRAME_LIST(CDRO_X_ENCODER)
CDRO_FRAME_LIST(CDRO_X_DECODER)

/* ---- whole frames ---------------------------------------------------------------------- */

size_t cdro_frame_encode(const cdro_frame_t *frame, uint8_t *out, size_t out_cap)
{
    uint8_t raw[CDRO_MAX_RAW_FRAME];
    uint8_t *const payload = raw + CDRO_HEADER_SIZE;
    size_t payload_len = 0;
    size_t encoded_len;
    uint16_t crc;

    if (frame == NULL || out == NULL) {
        return 0;
    }
    switch (frame->type) {
#define CDRO_X_ENCODE_CASE(NAME, name, id, doc)                \
    case id:                                                   \
        if (CDRO_DEVICE_SIDE && (id) >= 0x40) {                \
            return 0; /* a device never sends a host frame */  \
        }                                                      \
        payload_len = encode_##name(&frame->as.name, payload); \
        if (payload_len == 0U && CDRO_##NAME##_MIN_SIZE > 0) { \
            return 0;                                          \
        }                                                      \
        break;
#define CDRO_X_EMPTY_CASE(NAME, name, id, doc)  \
    case id:                                    \
        if (CDRO_DEVICE_SIDE && (id) >= 0x40) { \
            return 0;                           \
        }                                       \
        break;
        CDRO_FRAME_LIST(CDRO_X_ENCODE_CASE)
        CDRO_EMPTY_FRAME_LIST(CDRO_X_EMPTY_CASE)
#undef CDRO_X_ENCODE_CASE
#undef CDRO_X_EMPTY_CASE
    default: return 0;
    }
    raw[0] = CDRO_PROTOCOL_VERSION;
    raw[1] = frame->type;
    (void)cdro_put_u16(raw + 2, frame->sequence);
    raw[4] = (uint8_t)payload_len;
    crc = cdro_crc16(raw, CDRO_HEADER_SIZE + payload_len);
    (void)cdro_put_u16(payload + payload_len, crc);

    if (out_cap < 1U) {
        return 0;
    }
    encoded_len = cdro_cobs_encode(raw, CDRO_HEADER_SIZE + payload_len + CDRO_CRC_SIZE, out, out_cap - 1U);
    if (encoded_len == 0U) {
        return 0;
    }
    out[encoded_len] = 0x00U;
    return encoded_len + 1U;
}

cdro_result_t cdro_frame_decode(const uint8_t *chunk, size_t len, cdro_frame_t *out)
{
    uint8_t raw[CDRO_MAX_RAW_FRAME];
    long decoded;
    size_t raw_len;
    size_t payload_len;
    uint16_t crc_received;

    if (chunk == NULL || out == NULL) {
        return CDRO_ERR_ARGUMENT;
    }
    memset(out, 0, sizeof(*out));
    if (len > CDRO_MAX_ENCODED_FRAME - 1U) {
        return CDRO_ERR_TOO_LONG;
    }
    decoded = cdro_cobs_decode(chunk, len, raw, sizeof raw);
    if (decoded < 0) {
        return CDRO_ERR_COBS;
    }
    raw_len = (size_t)decoded;
    if (raw_len < CDRO_HEADER_SIZE + CDRO_CRC_SIZE) {
        return CDRO_ERR_SHORT;
    }
    crc_received = cdro_get_u16(raw + raw_len - CDRO_CRC_SIZE);
    if (cdro_crc16(raw, raw_len - CDRO_CRC_SIZE) != crc_received) {
        return CDRO_ERR_CRC;
    }
    out->version = raw[0];
    out->type = raw[1];
    out->sequence = cdro_get_u16(raw + 2);
    if (out->version != CDRO_PROTOCOL_VERSION) {
        return CDRO_ERR_VERSION;
    }
    payload_len = raw_len - CDRO_HEADER_SIZE - CDRO_CRC_SIZE;
    if (raw[4] != payload_len) {
        return CDRO_ERR_LENGTH;
    }
    switch (out->type) {
#define CDRO_X_DECODE_CASE(NAME, name, id, doc)                                             \
    case id:                                                                                \
        if (CDRO_SKIPPED_BY_DEVICE(NAME, id)) {                                             \
            return payload_len == CDRO_##NAME##_MAX_SIZE ? CDRO_ERR_TYPE : CDRO_ERR_LENGTH; \
        }                                                                                   \
        return decode_##name(raw + CDRO_HEADER_SIZE, payload_len, &out->as.name);
#define CDRO_X_EMPTY_CASE(NAME, name, id, doc) \
    case id: return (payload_len == 0U) ? CDRO_OK : CDRO_ERR_LENGTH;
        CDRO_FRAME_LIST(CDRO_X_DECODE_CASE)
        CDRO_EMPTY_FRAME_LIST(CDRO_X_EMPTY_CASE)
#undef CDRO_X_DECODE_CASE
#undef CDRO_X_EMPTY_CASE
    default: return CDRO_ERR_TYPE;
    }
}

/* ---- semantic validation ---------------------------------------------------------------- */

/* ranges_ok_<name>: the declared ranges of frame_layout.def, field by field (layout_codec.h). */
CDRO_FRAME_LIST(CDRO_X_RANGE_CHECK)

/* No id twice in one list (that each is non-zero is its range). */
static int ids_distinct(const uint16_t *ids, uint8_t count)
{
    uint8_t i;
    uint8_t j;
    for (i = 0; i < count; ++i) {
        for (j = 0; j < i; ++j) {
            if (ids[j] == ids[i]) {
                return 0;
            }
        }
    }
    return 1;
}

/*
 * The rules that are not one field's range, so frame_layout.def cannot declare them: between
 * two fields, across an array's elements, and on the bit fields and code sets of SET_UWB. The
 * one place for them in C; validate_frame in frames.py has their Python twin.
 */
static int other_rules_ok(const cdro_frame_t *frame)
{
    switch (frame->type) {
#if !CDRO_DEVICE_SIDE /* device-to-host types: refused by type before this on the device */
    case CDRO_FRAME_RANGE: return frame->as.range.from_id != frame->as.range.to_id;
    case CDRO_FRAME_NODE_LIST: return ids_distinct(frame->as.node_list.node_ids, frame->as.node_list.node_ids_count);
#endif
    case CDRO_FRAME_SET_NODES: return ids_distinct(frame->as.set_nodes.node_ids, frame->as.set_nodes.node_ids_count);
    case CDRO_FRAME_SET_UWB: {
        const cdro_set_uwb_t *u = &frame->as.set_uwb;
        const uint8_t bitrate = (uint8_t)(u->uwb_rates & 0x3FU);
        const uint8_t prf = (uint8_t)(u->uwb_rates >> 6);
        const uint8_t p = u->uwb_plen;
        return u->uwb_channel != 6U && bitrate <= 2U && prf >= 1U && prf <= 2U &&
               (p == 0x04U || p == 0x14U || p == 0x24U || p == 0x34U || p == 0x08U || p == 0x18U || p == 0x28U ||
                p == 0x0CU);
    }
    default: return 1;
    }
}

cdro_result_t cdro_frame_validate(const cdro_frame_t *frame)
{
    int ok = 1;
    if (frame == NULL) {
        return CDRO_ERR_ARGUMENT;
    }
    switch (frame->type) {
/* On the device, a device-to-host type is refused by type (the device NACKs it UNKNOWN_TYPE
 * whatever its values), and its checks compile to nothing. */
#define CDRO_X_VALIDATE_CASE(NAME, name, id, doc) \
    case id:                                      \
        if (CDRO_DEVICE_SIDE && (id) < 0x40) {    \
            return CDRO_ERR_TYPE;                 \
        }                                         \
        ok = ranges_ok_##name(&frame->as.name);   \
        break;
#define CDRO_X_EMPTY_CASE(NAME, name, id, doc) \
    case id:                                   \
        if (CDRO_DEVICE_SIDE && (id) < 0x40) { \
            return CDRO_ERR_TYPE;              \
        }                                      \
        break;
        CDRO_FRAME_LIST(CDRO_X_VALIDATE_CASE)
        CDRO_EMPTY_FRAME_LIST(CDRO_X_EMPTY_CASE)
#undef CDRO_X_VALIDATE_CASE
#undef CDRO_X_EMPTY_CASE
    default: return CDRO_ERR_TYPE;
    }
    return (ok && other_rules_ok(frame)) ? CDRO_OK : CDRO_ERR_VALUE;
}

/* ---- streaming decoder ------------------------------------------------------------------ */

void cdro_decoder_init(cdro_decoder_t *decoder) { memset(decoder, 0, sizeof(*decoder)); }

static void count_rejection(cdro_decoder_counters_t *c, cdro_result_t status)
{
    switch (status) {
    case CDRO_ERR_COBS: ++c->cobs_errors; break;
    case CDRO_ERR_SHORT: ++c->short_errors; break;
    case CDRO_ERR_CRC: ++c->crc_errors; break;
    case CDRO_ERR_VERSION: ++c->version_errors; break;
    case CDRO_ERR_TYPE: ++c->type_errors; break;
    case CDRO_ERR_LENGTH: ++c->length_errors; break;
    case CDRO_ERR_VALUE: ++c->value_errors; break;
    case CDRO_ERR_TOO_LONG: ++c->too_long_errors; break;
    case CDRO_PENDING:
    case CDRO_OK:
    case CDRO_ERR_ARGUMENT:
    default: break;
    }
}

cdro_result_t cdro_decoder_push(cdro_decoder_t *decoder, uint8_t byte, cdro_frame_t *out)
{
    cdro_result_t status;

    if (byte != 0x00U) {
        if (decoder->overflowed) {
            ++decoder->overflow_len;
        } else if (decoder->chunk_len < sizeof decoder->chunk) {
            decoder->chunk[decoder->chunk_len++] = byte;
        } else {
            /* Longer than any frame: keep what we have for the capture, drop the rest. */
            decoder->overflowed = 1U;
            decoder->overflow_len = (uint32_t)decoder->chunk_len + 1U;
        }
        return CDRO_PENDING;
    }

    /* A delimiter ends the chunk. */
    decoder->last_chunk_len = decoder->chunk_len;
    decoder->chunk_len = 0;
    if (decoder->overflowed) {
        decoder->overflowed = 0U;
        decoder->counters.bytes_discarded += decoder->overflow_len;
        ++decoder->counters.too_long_errors;
        return CDRO_ERR_TOO_LONG;
    }
    if (decoder->last_chunk_len == 0U) {
        return CDRO_PENDING; /* repeated delimiters are allowed and carry nothing */
    }
    status = cdro_frame_decode(decoder->chunk, decoder->last_chunk_len, out);
    if (status == CDRO_OK) {
        status = cdro_frame_validate(out);
    }
    if (status == CDRO_OK) {
        ++decoder->counters.frames_ok;
    } else {
        decoder->counters.bytes_discarded += decoder->last_chunk_len;
        count_rejection(&decoder->counters, status);
    }
    return status;
}
