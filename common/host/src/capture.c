#include "cdro/capture.h"

#include <string.h>

#include "cdro/crc.h"
#include "cdro/wire.h"
#include "layout_codec.h"

CDRO_CAPTURE_RECORD_LIST(CDRO_X_ENCODER)
CDRO_CAPTURE_RECORD_LIST(CDRO_X_DECODER)

/* The sizes capture_layout.def states for the readers that only see its constants (Python,
 * the docs) must be the sums of its records. */
typedef char cdro_capture_header_fixed_agrees
    [(CDRO_CAPTURE_HEADER_FIXED == CDRO_CAPTURE_MAGIC_SIZE + CDRO_CAPTURE_HEAD_MAX_SIZE + 2U) ? 1 : -1];
typedef char
    cdro_capture_record_overhead_agrees[(CDRO_CAPTURE_RECORD_OVERHEAD == CDRO_CAPTURE_RECORD_HEAD_MAX_SIZE + 2U) ? 1
                                                                                                                 : -1];
typedef char cdro_capture_magic_agrees[(sizeof CDRO_CAPTURE_MAGIC == CDRO_CAPTURE_MAGIC_SIZE) ? 1 : -1];
typedef char cdro_capture_max_context_agrees
    [(CDRO_CAPTURE_MAX_CONTEXT == 65535U - CDRO_CAPTURE_HEADER_FIXED - CDRO_CAPTURE_MAX_SOURCE - 2U) ? 1 : -1];

/* Appends n bytes (n may be 0, src then may be NULL); returns the position after them. */
static uint8_t *put_bytes(uint8_t *p, const void *src, size_t n)
{
    if (n > 0U) {
        memcpy(p, src, n);
    }
    return p + n;
}

/* Both the header and a record end in the CRC-16 of every byte before it. */
static void put_crc(uint8_t *start, uint8_t *end) { (void)cdro_put_u16(end, cdro_crc16(start, (size_t)(end - start))); }

size_t cdro_capture_header_encode(const cdro_capture_header_t *header, uint8_t *out, size_t out_cap)
{
    const size_t context_size = header->context_len > 0U ? 2U + (size_t)header->context_len : 0U;
    const size_t size = CDRO_CAPTURE_HEADER_FIXED + header->source_len + context_size;
    const uint16_t version =
        header->format_version == 0U ? (uint16_t)CDRO_CAPTURE_FORMAT_VERSION : header->format_version;
    uint8_t *p = out;
    if (out_cap < size || version > CDRO_CAPTURE_FORMAT_VERSION || header->context_len > CDRO_CAPTURE_MAX_CONTEXT ||
        (header->context_len > 0U && header->context == NULL)) {
        return 0;
    }
    cdro_capture_head_t head;
    head.format_version = version;
    head.header_size = (uint16_t)size;
    head.created_unix_us = header->created_unix_us;
    head.source_len = header->source_len;
    p = put_bytes(p, CDRO_CAPTURE_MAGIC, CDRO_CAPTURE_MAGIC_SIZE); /* includes the 0x00 */
    p += encode_capture_head(&head, p);
    p = put_bytes(p, header->source, header->source_len);
    if (header->context_len > 0U) {
        p = put_bytes(cdro_put_u16(p, header->context_len), header->context, header->context_len);
    }
    put_crc(out, p);
    return size;
}

cdro_result_t cdro_capture_header_decode(const uint8_t *in, size_t len, cdro_capture_header_t *out, size_t *consumed)
{
    size_t size;
    size_t covered;
    cdro_capture_head_t head;
    if (len < CDRO_CAPTURE_HEADER_FIXED) {
        return (len >= CDRO_CAPTURE_MAGIC_SIZE && memcmp(in, CDRO_CAPTURE_MAGIC, CDRO_CAPTURE_MAGIC_SIZE) != 0)
                   ? CDRO_ERR_TYPE
                   : CDRO_PENDING;
    }
    if (memcmp(in, CDRO_CAPTURE_MAGIC, CDRO_CAPTURE_MAGIC_SIZE) != 0) {
        return CDRO_ERR_TYPE;
    }
    memset(out, 0, sizeof(*out));
    /* Cannot fail: the bytes are there (HEADER_FIXED covers the magic and the head). */
    (void)decode_capture_head(in + CDRO_CAPTURE_MAGIC_SIZE, CDRO_CAPTURE_HEAD_MAX_SIZE, &head);
    out->format_version = head.format_version;
    if (out->format_version == 0U || out->format_version > CDRO_CAPTURE_FORMAT_VERSION) {
        return CDRO_ERR_VERSION;
    }
    size = head.header_size;
    out->source_len = head.source_len;
    covered = CDRO_CAPTURE_HEADER_FIXED - 2U + out->source_len; /* bytes under the CRC */
    if (size < covered + 2U) {
        return CDRO_ERR_LENGTH;
    }
    if (len < size) {
        return CDRO_PENDING;
    }
    /* The CRC sits at the end of the header; a newer minor layout may put fields before it. */
    if (cdro_crc16(in, size - 2U) != cdro_get_u16(in + size - 2U)) {
        return CDRO_ERR_CRC;
    }
    out->created_unix_us = head.created_unix_us;
    memcpy(out->source, in + CDRO_CAPTURE_MAGIC_SIZE + CDRO_CAPTURE_HEAD_MAX_SIZE, out->source_len);
    /* Bytes between the source and the CRC: the context, when they hold one whole (otherwise a
       layout this build does not know: skipped). */
    if (size - 2U - covered >= 2U) {
        const uint16_t context_len = cdro_get_u16(in + covered);
        if (context_len > 0U && (size_t)context_len <= size - 2U - covered - 2U) {
            out->context_len = context_len;
            out->context = in + covered + 2U;
        }
    }
    *consumed = size;
    return CDRO_OK;
}

size_t cdro_capture_record_encode(const cdro_capture_record_t *record, uint8_t *out, size_t out_cap)
{
    const size_t size = CDRO_CAPTURE_RECORD_OVERHEAD + (size_t)record->data_len;
    cdro_capture_record_head_t head;
    uint8_t *p = out;
    if (record->data_len > CDRO_CAPTURE_MAX_DATA || out_cap < size) {
        return 0;
    }
    head.marker = (uint8_t)CDRO_CAPTURE_RECORD_MARKER;
    head.flags = record->flags;
    head.data_len = record->data_len;
    head.host_time_us = record->host_time_us;
    p += encode_capture_record_head(&head, p);
    put_crc(out, put_bytes(p, record->data, record->data_len));
    return size;
}

cdro_result_t cdro_capture_record_decode(const uint8_t *in, size_t len, cdro_capture_record_t *out, size_t *consumed)
{
    size_t size;
    cdro_capture_record_head_t head;
    if (len < 1U) {
        return CDRO_PENDING;
    }
    if (in[0] != CDRO_CAPTURE_RECORD_MARKER) {
        return CDRO_ERR_TYPE;
    }
    if (len < CDRO_CAPTURE_RECORD_HEAD_MAX_SIZE) {
        return CDRO_PENDING;
    }
    /* Cannot fail: the head's bytes are there. */
    (void)decode_capture_record_head(in, CDRO_CAPTURE_RECORD_HEAD_MAX_SIZE, &head);
    if (head.data_len > CDRO_CAPTURE_MAX_DATA) {
        return CDRO_ERR_LENGTH;
    }
    size = CDRO_CAPTURE_RECORD_OVERHEAD + (size_t)head.data_len;
    if (len < size) {
        return CDRO_PENDING;
    }
    if (cdro_crc16(in, size - 2U) != cdro_get_u16(in + size - 2U)) {
        return CDRO_ERR_CRC;
    }
    out->flags = head.flags;
    out->data_len = head.data_len;
    out->host_time_us = head.host_time_us;
    out->data = in + CDRO_CAPTURE_RECORD_HEAD_MAX_SIZE;
    *consumed = size;
    return CDRO_OK;
}

cdro_result_t cdro_capture_next_record(const uint8_t *in, size_t len, cdro_capture_record_t *out, size_t *skipped,
                                       size_t *consumed)
{
    size_t offset;
    for (offset = 0; offset < len; ++offset) {
        if (in[offset] == CDRO_CAPTURE_RECORD_MARKER &&
            cdro_capture_record_decode(in + offset, len - offset, out, consumed) == CDRO_OK) {
            *skipped = offset;
            return CDRO_OK;
        }
    }
    *skipped = 0;
    *consumed = 0;
    return CDRO_PENDING;
}
