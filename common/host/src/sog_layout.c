#include "cdro/sog_layout.h"

#include <stdint.h>
#include <string.h>

#include "cdro/crc.h"
#include "layout_codec.h"

CDRO_SOG_RECORD_LIST(CDRO_X_ENCODER)
CDRO_SOG_RECORD_LIST(CDRO_X_DECODER)

void cdro_sog_writer_init(cdro_sog_writer_t *writer, cdro_sog_sink_fn sink, void *context)
{
    writer->sink = sink;
    writer->context = context;
    writer->crc_state = CDRO_CRC32_INIT;
    writer->failed = 0;
}

static cdro_result_t emit(cdro_sog_writer_t *writer, const uint8_t *bytes, size_t len)
{
    if (writer->failed || !writer->sink(writer->context, bytes, len)) {
        writer->failed = 1;
        return CDRO_ERR_ARGUMENT;
    }
    writer->crc_state = cdro_crc32_update(writer->crc_state, bytes, len);
    return CDRO_OK;
}

cdro_result_t cdro_sog_write_header(cdro_sog_writer_t *writer, const cdro_sog_header_t *header)
{
    uint8_t buffer[CDRO_SOG_MAGIC_SIZE + CDRO_SOG_HEADER_MAX_SIZE];
    /* The magic is 4 bytes on the wire, without the string's terminator. */
    memcpy(buffer, CDRO_SOG_MAGIC, CDRO_SOG_MAGIC_SIZE); /* NOLINT(bugprone-not-null-terminated-result) */
    return emit(writer, buffer, CDRO_SOG_MAGIC_SIZE + encode_sog_header(header, buffer + CDRO_SOG_MAGIC_SIZE));
}

cdro_result_t cdro_sog_write_node(cdro_sog_writer_t *writer, const cdro_sog_node_t *node)
{
    uint8_t buffer[CDRO_SOG_NODE_MAX_SIZE];
    return emit(writer, buffer, encode_sog_node(node, buffer));
}

cdro_result_t cdro_sog_write_pair(cdro_sog_writer_t *writer, const cdro_sog_pair_t *pair)
{
    uint8_t buffer[CDRO_SOG_PAIR_MAX_SIZE];
    return emit(writer, buffer, encode_sog_pair(pair, buffer));
}

cdro_result_t cdro_sog_write_component(cdro_sog_writer_t *writer, const cdro_sog_component_t *component)
{
    uint8_t buffer[CDRO_SOG_COMPONENT_MAX_SIZE];
    return emit(writer, buffer, encode_sog_component(component, buffer));
}

cdro_result_t cdro_sog_write_extension(cdro_sog_writer_t *writer, uint16_t tag, const uint8_t *bytes, uint32_t len)
{
    uint8_t prefix[6];
    cdro_result_t status;
    if (tag == 0U) {
        return CDRO_ERR_ARGUMENT; /* 0 is the end marker */
    }
#if SIZE_MAX < UINT32_MAX
    if (len > SIZE_MAX) {
        return CDRO_ERR_ARGUMENT; /* on the AVR size_t is 16 bits */
    }
#endif
    (void)cdro_put_u32(cdro_put_u16(prefix, tag), len);
    status = emit(writer, prefix, sizeof prefix);
    if (status == CDRO_OK && len > 0U) {
        status = emit(writer, bytes, (size_t)len);
    }
    return status;
}

cdro_result_t cdro_sog_write_end(cdro_sog_writer_t *writer)
{
    uint8_t end_tag[2];
    uint8_t trailer[4];
    cdro_result_t status;
    (void)cdro_put_u16(end_tag, 0U);
    status = emit(writer, end_tag, sizeof end_tag);
    if (status != CDRO_OK) {
        return status;
    }
    (void)cdro_put_u32(trailer, cdro_crc32_final(writer->crc_state));
    if (!writer->sink(writer->context, trailer, sizeof trailer)) {
        writer->failed = 1;
        return CDRO_ERR_ARGUMENT;
    }
    return CDRO_OK;
}

cdro_result_t cdro_sog_reader_init(cdro_sog_reader_t *reader, const uint8_t *data, size_t len,
                                   cdro_sog_header_t *header)
{
    size_t body_len;
    uint64_t minimum;
    cdro_result_t status;

    if (len < CDRO_SOG_MAGIC_SIZE || memcmp(data, CDRO_SOG_MAGIC, CDRO_SOG_MAGIC_SIZE) != 0) {
        return CDRO_ERR_TYPE;
    }
    if (len < CDRO_SOG_MAGIC_SIZE + CDRO_SOG_HEADER_MAX_SIZE + 2U + 4U) {
        return CDRO_ERR_CRC; /* cut short */
    }
    body_len = len - 4U;
    if (cdro_crc32(data, body_len) != cdro_get_u32(data + body_len)) {
        return CDRO_ERR_CRC;
    }
    status = decode_sog_header(data + CDRO_SOG_MAGIC_SIZE, CDRO_SOG_HEADER_MAX_SIZE, header);
    if (status != CDRO_OK) {
        return status;
    }
    if (header->layout_version != CDRO_SOG_LAYOUT_VERSION || header->layout_hash != CDRO_SOG_LAYOUT_HASH) {
        return CDRO_ERR_VERSION;
    }
    minimum = (uint64_t)CDRO_SOG_MAGIC_SIZE + CDRO_SOG_HEADER_MAX_SIZE +
              (uint64_t)header->node_count * CDRO_SOG_NODE_MAX_SIZE +
              (uint64_t)header->pair_count * CDRO_SOG_PAIR_MAX_SIZE +
              (uint64_t)header->component_count * CDRO_SOG_COMPONENT_MAX_SIZE + 2U;
    if (minimum > body_len) {
        return CDRO_ERR_LENGTH;
    }
    reader->data = data;
    reader->len = body_len;
    reader->position = CDRO_SOG_MAGIC_SIZE + CDRO_SOG_HEADER_MAX_SIZE;
    return CDRO_OK;
}

/* Reads one fixed-size record at the reader's position into *out. */
#define CDRO_READ_RECORD(NAME, name, out)                                  \
    if (reader->len - reader->position < (size_t)CDRO_##NAME##_MAX_SIZE) { \
        return CDRO_ERR_LENGTH;                                            \
    }                                                                      \
    reader->position += CDRO_##NAME##_MAX_SIZE;                            \
    return decode_##name(reader->data + reader->position - CDRO_##NAME##_MAX_SIZE, CDRO_##NAME##_MAX_SIZE, out);

cdro_result_t cdro_sog_read_node(cdro_sog_reader_t *reader,
                                 cdro_sog_node_t *node){CDRO_READ_RECORD(SOG_NODE, sog_node, node)}

cdro_result_t
    cdro_sog_read_pair(cdro_sog_reader_t *reader, cdro_sog_pair_t *pair){CDRO_READ_RECORD(SOG_PAIR, sog_pair, pair)}

cdro_result_t cdro_sog_read_component(cdro_sog_reader_t *reader, cdro_sog_component_t *component){
    CDRO_READ_RECORD(SOG_COMPONENT, sog_component, component)}

cdro_result_t cdro_sog_read_extension(cdro_sog_reader_t *reader, uint16_t *tag, const uint8_t **bytes, uint32_t *len)
{
    const size_t remaining = reader->len - reader->position;
    if (remaining < 2U) {
        return CDRO_ERR_LENGTH;
    }
    *tag = cdro_get_u16(reader->data + reader->position);
    if (*tag == 0U) {
        reader->position += 2U;
        *bytes = NULL;
        *len = 0;
        return (reader->position == reader->len) ? CDRO_OK : CDRO_ERR_LENGTH;
    }
    if (remaining < 6U) {
        return CDRO_ERR_LENGTH;
    }
    *len = cdro_get_u32(reader->data + reader->position + 2U);
    if ((uint64_t)*len > (uint64_t)(remaining - 6U)) {
        return CDRO_ERR_LENGTH;
    }
    *bytes = reader->data + reader->position + 6U;
    reader->position += 6U + (size_t)*len;
    return CDRO_OK;
}
