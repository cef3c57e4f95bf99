/*
 * sog_layout.h: the fixed-point SoG snapshot, a compact and portable image of the filter
 * state, used for checkpoints (--resume) and for streaming the state to viewers.
 *
 * File (all little-endian; records defined in sog_layout.def, scales and bounds there too):
 *   "CDSG"                          4-byte magic
 *   SOG_HEADER                      counts of what follows
 *   SOG_NODE        x node_count
 *   { SOG_PAIR, SOG_COMPONENT x pair.component_count } x pair_count
 *   { u16 tag != 0, u32 length, length bytes } x any   extensions (engine state beyond the
 *                                                      SoG layout); readers skip unknown tags
 *   u16 0                           end of extensions
 *   u32 CRC-32/ISO-HDLC of every byte before it
 *
 * Writing goes through a caller-supplied sink (a file, a socket, a memory buffer); reading
 * works on a complete snapshot in memory and checks the CRC before anything is trusted.
 */
#ifndef CDRO_SOG_LAYOUT_H
#define CDRO_SOG_LAYOUT_H

#include <stddef.h>
#include <stdint.h>

#include "cdro/layout_kinds.h"
#include "cdro/sog_layout.def"
#include "cdro/result.h"

#ifdef __cplusplus
extern "C" {
#endif

#define CDRO_SOG_MAGIC "CDSG"
#define CDRO_SOG_MAGIC_SIZE 4U

CDRO_SOG_RECORD_LIST(CDRO_X_STRUCT)
CDRO_SOG_RECORD_LIST(CDRO_X_SIZES) /* CDRO_SOG_NODE_MAX_SIZE etc.; records are fixed-size */

/* ---- writing ----------------------------------------------------------------------------- */

/* The sink: writes len bytes, returns nonzero on success. */
typedef int (*cdro_sog_sink_fn)(void *context, const uint8_t *bytes, size_t len);

typedef struct cdro_sog_writer {
    cdro_sog_sink_fn sink;
    void *context;
    uint32_t crc_state; /* running CRC-32 of everything written */
    int failed;         /* a sink call failed; every later call fails too */
} cdro_sog_writer_t;

void cdro_sog_writer_init(cdro_sog_writer_t *writer, cdro_sog_sink_fn sink, void *context);

/* Each returns CDRO_OK, or CDRO_ERR_ARGUMENT once the sink has failed. The caller writes the
 * records in the file order above; the counts in the header must match what follows. */
cdro_result_t cdro_sog_write_header(cdro_sog_writer_t *writer, const cdro_sog_header_t *header);
cdro_result_t cdro_sog_write_node(cdro_sog_writer_t *writer, const cdro_sog_node_t *node);
cdro_result_t cdro_sog_write_pair(cdro_sog_writer_t *writer, const cdro_sog_pair_t *pair);
cdro_result_t cdro_sog_write_component(cdro_sog_writer_t *writer, const cdro_sog_component_t *component);
cdro_result_t cdro_sog_write_extension(cdro_sog_writer_t *writer, uint16_t tag, const uint8_t *bytes, uint32_t len);
cdro_result_t cdro_sog_write_end(cdro_sog_writer_t *writer); /* end tag and CRC-32 */

/* ---- reading ----------------------------------------------------------------------------- */

typedef struct cdro_sog_reader {
    const uint8_t *data;
    size_t len; /* bytes before the CRC trailer */
    size_t position;
} cdro_sog_reader_t;

/*
 * Checks magic, CRC-32, layout version and hash, and that the counts fit the bytes, then
 * reads the header. CDRO_ERR_TYPE: not a snapshot; CDRO_ERR_CRC: corrupt or cut short;
 * CDRO_ERR_VERSION: another layout; CDRO_ERR_LENGTH: counts do not fit.
 */
cdro_result_t cdro_sog_reader_init(cdro_sog_reader_t *reader, const uint8_t *data, size_t len,
                                   cdro_sog_header_t *header);

/* Each reads the next record; CDRO_ERR_LENGTH if the bytes run out. */
cdro_result_t cdro_sog_read_node(cdro_sog_reader_t *reader, cdro_sog_node_t *node);
cdro_result_t cdro_sog_read_pair(cdro_sog_reader_t *reader, cdro_sog_pair_t *pair);
cdro_result_t cdro_sog_read_component(cdro_sog_reader_t *reader, cdro_sog_component_t *component);

/* Reads the next extension: CDRO_OK with *tag != 0 and its bytes, or CDRO_OK with *tag == 0 at
 * the end marker (then the snapshot has been read completely). */
cdro_result_t cdro_sog_read_extension(cdro_sog_reader_t *reader, uint16_t *tag, const uint8_t **bytes, uint32_t *len);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_SOG_LAYOUT_H */
