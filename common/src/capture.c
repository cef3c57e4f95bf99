#include "cdro/capture.h"

#include <string.h>

#include "cdro/crc.h"
#include "cdro/wire.h"

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
    memcpy(p, CDRO_CAPTURE_MAGIC, CDRO_CAPTURE_MAGIC_SIZE); /* includes the 0x00 */
    p += CDRO_CAPTURE_MAGIC_SIZE;
    p = cdro_put_u16(p, version);
    p = cdro_put_u16(p, (uint16_t)size);
    p = cdro_put_i64(p, header->created_unix_us);
    p = cdro_put_u8(p, header->source_len);
    memcpy(p, header->source, header->source_len);
    p += header->source_len;
    if (header->context_len > 0U) {
        p = cdro_put_u16(p, header->context_len);
        memcpy(p, header->context, header->context_len);
        p += header->context_len;
    }
    (void)cdro_put_u16(p, cdro_crc16(out, (size_t)(p - out)));
    return size;
}

cdro_result_t cdro_capture_header_decode(const uint8_t *in, size_t len, cdro_capture_header_t *out,
                                         size_t *consumed)
{
    size_t size;
    size_t covered;
    if (len < CDRO_CAPTURE_HEADER_FIXED) {
        return (len >= CDRO_CAPTURE_MAGIC_SIZE && memcmp(in, CDRO_CAPTURE_MAGIC, CDRO_CAPTURE_MAGIC_SIZE) != 0)
                   ? CDRO_ERR_TYPE
                   : CDRO_PENDING;
    }
    if (memcmp(in, CDRO_CAPTURE_MAGIC, CDRO_CAPTURE_MAGIC_SIZE) != 0) {
        return CDRO_ERR_TYPE;
    }
    memset(out, 0, sizeof(*out));
    out->format_version = cdro_get_u16(in + 8);
    if (out->format_version == 0U || out->format_version > CDRO_CAPTURE_FORMAT_VERSION) {
        return CDRO_ERR_VERSION;
    }
    size = cdro_get_u16(in + 10);
    out->source_len = in[20];
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
    out->created_unix_us = cdro_get_i64(in + 12);
    memcpy(out->source, in + 21, out->source_len);
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
    uint8_t *p = out;
    if (record->data_len > CDRO_CAPTURE_MAX_DATA || out_cap < size) {
        return 0;
    }
    p = cdro_put_u8(p, (uint8_t)CDRO_CAPTURE_RECORD_MARKER);
    p = cdro_put_u8(p, record->flags);
    p = cdro_put_u16(p, record->data_len);
    p = cdro_put_i64(p, record->host_time_us);
    if (record->data_len > 0U) {
        memcpy(p, record->data, record->data_len);
    }
    p += record->data_len;
    (void)cdro_put_u16(p, cdro_crc16(out, (size_t)(p - out)));
    return size;
}

cdro_result_t cdro_capture_record_decode(const uint8_t *in, size_t len, cdro_capture_record_t *out,
                                         size_t *consumed)
{
    size_t size;
    if (len < 1U) {
        return CDRO_PENDING;
    }
    if (in[0] != CDRO_CAPTURE_RECORD_MARKER) {
        return CDRO_ERR_TYPE;
    }
    if (len < 4U) {
        return CDRO_PENDING;
    }
    out->flags = in[1];
    out->data_len = cdro_get_u16(in + 2);
    if (out->data_len > CDRO_CAPTURE_MAX_DATA) {
        return CDRO_ERR_LENGTH;
    }
    size = CDRO_CAPTURE_RECORD_OVERHEAD + (size_t)out->data_len;
    if (len < size) {
        return CDRO_PENDING;
    }
    if (cdro_crc16(in, size - 2U) != cdro_get_u16(in + size - 2U)) {
        return CDRO_ERR_CRC;
    }
    out->host_time_us = cdro_get_i64(in + 4);
    out->data = in + 12;
    *consumed = size;
    return CDRO_OK;
}

cdro_result_t cdro_capture_next_record(const uint8_t *in, size_t len, cdro_capture_record_t *out,
                                       size_t *skipped, size_t *consumed)
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
