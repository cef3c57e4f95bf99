/*
 * libFuzzer target for every decoder of untrusted bytes in common/: the streaming frame
 * decoder, the one-chunk decoder, the capture-file reader and the SoG snapshot reader.
 * Besides "no out-of-bounds access, no UB" (ASan + UBSan), it checks the invariants of the
 * security model in docs/protocol.md:
 *   - every chunk that ends is either one good frame or one counted rejection;
 *   - every accepted frame re-encodes to exactly the bytes it came from (nothing is guessed);
 *   - the capture reader's records and skipped bytes account for the whole input;
 *   - the snapshot reader never reads past the bytes it was given.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "cdro/capture.h"
#include "cdro/frames.h"
#include "cdro/sog_layout.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define CHECK(condition)    \
    do {                    \
        if (!(condition)) { \
            abort();        \
        }                   \
    } while (0)

static uint32_t rejected(const cdro_decoder_counters_t *c)
{
    return c->cobs_errors + c->short_errors + c->crc_errors + c->version_errors + c->type_errors + c->length_errors +
           c->value_errors + c->too_long_errors;
}

static void fuzz_stream(const uint8_t *data, size_t size)
{
    cdro_decoder_t decoder;
    uint32_t chunks_ended = 0;
    size_t i;
    cdro_decoder_init(&decoder);
    for (i = 0; i < size; ++i) {
        cdro_frame_t frame;
        const cdro_result_t result = cdro_decoder_push(&decoder, data[i], &frame);
        if (result == CDRO_PENDING) {
            continue;
        }
        ++chunks_ended;
        if (result == CDRO_OK) {
            uint8_t encoded[CDRO_MAX_ENCODED_FRAME];
            const size_t n = cdro_frame_encode(&frame, encoded, sizeof encoded);
            CHECK(n == (size_t)decoder.last_chunk_len + 1U);
            CHECK(memcmp(encoded, decoder.chunk, decoder.last_chunk_len) == 0);
        }
    }
    CHECK(decoder.counters.frames_ok + rejected(&decoder.counters) == chunks_ended);
}

static void fuzz_capture(const uint8_t *data, size_t size)
{
    cdro_capture_header_t header;
    size_t offset = 0;
    size_t accounted;
    if (cdro_capture_header_decode(data, size, &header, &offset) != CDRO_OK) {
        offset = 0; /* read the bytes as records anyway */
    }
    accounted = offset;
    while (offset < size) {
        cdro_capture_record_t record;
        size_t skipped = 0;
        size_t consumed = 0;
        if (cdro_capture_next_record(data + offset, size - offset, &record, &skipped, &consumed) != CDRO_OK) {
            accounted += size - offset;
            break;
        }
        CHECK(record.data >= data && record.data + record.data_len <= data + size);
        CHECK(consumed == CDRO_CAPTURE_RECORD_OVERHEAD + (size_t)record.data_len);
        offset += skipped + consumed;
        accounted += skipped + consumed;
    }
    CHECK(accounted == size);
}

static void fuzz_snapshot(const uint8_t *data, size_t size)
{
    cdro_sog_reader_t reader;
    cdro_sog_header_t header;
    uint32_t p;
    uint32_t c;
    uint16_t n;
    if (cdro_sog_reader_init(&reader, data, size, &header) != CDRO_OK) {
        return;
    }
    for (n = 0; n < header.node_count; ++n) {
        cdro_sog_node_t node;
        if (cdro_sog_read_node(&reader, &node) != CDRO_OK) {
            return;
        }
    }
    for (p = 0; p < header.pair_count; ++p) {
        cdro_sog_pair_t pair;
        if (cdro_sog_read_pair(&reader, &pair) != CDRO_OK) {
            return;
        }
        for (c = 0; c < pair.component_count; ++c) {
            cdro_sog_component_t component;
            if (cdro_sog_read_component(&reader, &component) != CDRO_OK) {
                return;
            }
        }
    }
    for (;;) {
        uint16_t tag;
        const uint8_t *bytes;
        uint32_t len;
        if (cdro_sog_read_extension(&reader, &tag, &bytes, &len) != CDRO_OK || tag == 0U) {
            return;
        }
        CHECK(bytes >= data && bytes + len <= data + size);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    cdro_frame_t frame;
    fuzz_stream(data, size);
    if (cdro_frame_decode(data, size, &frame) == CDRO_OK) {
        (void)cdro_frame_validate(&frame);
    }
    fuzz_capture(data, size);
    fuzz_snapshot(data, size);
    return 0;
}
