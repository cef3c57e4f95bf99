/*
 * capture.h: the capture-file format. A capture is what the host received (and sent) on the
 * serial link, byte for byte, with the host's clock, and (format version 2) the robot's
 * odometry messages it accepted: replaying it reproduces a run exactly.
 *
 * File = header, then records, back to back. All integers little-endian. The fixed fields and
 * the constants are defined once, in capture_layout.def (CAPTURE_HEAD, CAPTURE_RECORD_HEAD),
 * which also generates the Python codec's table; the offsets below follow from it.
 *
 * Header (23 + n bytes, or 25 + n + m with a context):
 *   0   8  magic "CDROCAP" followed by 0x00
 *   8   u16 format version: 1 or 2 (CDRO_CAPTURE_FORMAT_VERSION; see "Versions" below)
 *   10  u16 header size in bytes, CRC included (readers skip bytes they do not know)
 *   12  i64 creation time, us since the Unix epoch (UTC)
 *   20  u8  n, length of the source description
 *   21  n   source, UTF-8, not terminated (e.g. "serial:/dev/ttyACM0@115200")
 *   21+n    (optional) the run's context: u16 m, then m bytes, UTF-8: what the writer needs to
 *           replay the run to the same result (cdro-hostd: JSON, docs/service.md "Capture and
 *           replay"). Present when the header is longer than 23 + n bytes. An addition to the
 *           header's layout, not a new version: a reader that does not know it skips it (the
 *           header size says where the records start), so every reader of versions 1 and 2
 *           reads such a file.
 *   size-2 u16 CRC-16/CCITT-FALSE of every header byte before it
 *
 * Record (14 + n bytes):
 *   0   u8  marker 0xC5
 *   1   u8  flags: CDRO_CAPTURE_FLAG_*; other bits reserved, written 0, ignored on read
 *   2   u16 n, number of data bytes (<= CDRO_CAPTURE_MAX_DATA)
 *   4   i64 host time, us since the Unix epoch, when the chunk's delimiter was received
 *           (or the frame was sent, or the odometry message was received)
 *   12  n   data: one chunk exactly as on the wire, i.e. the COBS bytes between two 0x00
 *           delimiters, without the delimiter; valid frames and rejected garbage alike.
 *           With CDRO_CAPTURE_FLAG_ODOMETRY: one accepted odometry message as normalised
 *           JSON (UTF-8, one object, no newline), after conversion to a step:
 *           {"t":<s since the epoch>,"distance_m":<m>,"dheading_rad":<rad>,"source":"<where>"}
 *           With CDRO_CAPTURE_FLAG_HOST_EVENT: something the host's estimator did on its own
 *           timing between two frames, which a replay repeats after the same frame, as the
 *           estimator defines it (cdro-hostd: 'S' and the engine's ranges taken when the solve
 *           started, u64 little endian: a global solve's map adopted once its worker thread
 *           was done).
 *   12+n u16 CRC-16/CCITT-FALSE of bytes [0, 12+n)
 *
 * Each record is self-delimiting (length) and checked (CRC), and is written with a single
 * write(): a file cut short by power loss or kill -9 loses at most its last record, which
 * readers report as truncated. A corrupt record is skipped by scanning for the next marker
 * whose record checks out.
 *
 * Versions. 1: device chunks and host frames. 2: adds CDRO_CAPTURE_FLAG_ODOMETRY. A version-1
 * reader ignores flag bits it does not know, so it would feed an odometry record's JSON to its
 * frame decoder as if the device had sent it; that is why files that can hold such records
 * say 2, which a version-1 reader refuses as newer. Readers of version 2 read version-1 files
 * unchanged (they never have the bit set). 3: adds CDRO_CAPTURE_FLAG_HOST_EVENT, for the same
 * reason a new version. The header's layout is the same in all three.
 */
#ifndef CDRO_CAPTURE_H
#define CDRO_CAPTURE_H

#include <stddef.h>
#include <stdint.h>

#include "cdro/capture_layout.def"
#include "cdro/layout_kinds.h"
#include "cdro/result.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The constants, CAPTURE_HEAD and CAPTURE_RECORD_HEAD (cdro_capture_head_t,
 * cdro_capture_record_head_t, CDRO_CAPTURE_HEAD_MAX_SIZE etc.) come from capture_layout.def. */
CDRO_CAPTURE_RECORD_LIST(CDRO_X_STRUCT)
CDRO_CAPTURE_RECORD_LIST(CDRO_X_SIZES)

typedef struct cdro_capture_header {
    uint16_t format_version;              /* decode: the file's; encode: 0 = CDRO_CAPTURE_FORMAT_VERSION */
    int64_t created_unix_us;              /* us since the Unix epoch */
    uint8_t source_len;                   /* bytes in source */
    char source[CDRO_CAPTURE_MAX_SOURCE]; /* not terminated */
    uint16_t context_len;                 /* bytes in context; 0 = none */
    const uint8_t *context;               /* encode: read from here; decode: points into the input (NULL if none) */
} cdro_capture_header_t;

typedef struct cdro_capture_record {
    uint8_t flags;        /* CDRO_CAPTURE_FLAG_* */
    int64_t host_time_us; /* us since the Unix epoch */
    uint16_t data_len;    /* bytes */
    const uint8_t *data;  /* encode: read from here; decode: points into the input */
} cdro_capture_record_t;

/*
 * Encodes the header into out with header->format_version (0 = the newest; an older version
 * is for tests and converters), and its context when context_len > 0. Returns its size, or 0
 * if out_cap is too small, the version is not one this build knows, or the context is longer
 * than CDRO_CAPTURE_MAX_CONTEXT.
 */
size_t cdro_capture_header_encode(const cdro_capture_header_t *header, uint8_t *out, size_t out_cap);

/*
 * Decodes a header from the start of a file. Returns CDRO_OK and sets *consumed;
 * CDRO_PENDING if len is too short to hold it; CDRO_ERR_TYPE for a wrong magic (not a
 * capture); CDRO_ERR_VERSION for a newer format version; CDRO_ERR_LENGTH for an inconsistent
 * size; CDRO_ERR_CRC for a corrupt header.
 */
cdro_result_t cdro_capture_header_decode(const uint8_t *in, size_t len, cdro_capture_header_t *out, size_t *consumed);

/* Encodes one record into out. Returns its size, or 0 if out_cap is too small or data_len too large. */
size_t cdro_capture_record_encode(const cdro_capture_record_t *record, uint8_t *out, size_t out_cap);

/*
 * Decodes the record at in[0]. Returns CDRO_OK and sets *consumed (out->data points into in);
 * CDRO_PENDING if the bytes end inside the record (at the end of a file: the file was cut
 * short and this is its truncated last record); CDRO_ERR_TYPE if in[0] is not the marker;
 * CDRO_ERR_LENGTH if the length field is impossible; CDRO_ERR_CRC if corrupt. After an error
 * other than CDRO_PENDING, a reader skips one byte and tries again (resynchronisation).
 */
cdro_result_t cdro_capture_record_decode(const uint8_t *in, size_t len, cdro_capture_record_t *out, size_t *consumed);

/*
 * The reading policy, shared by every reader: finds the next good record in in[0, len),
 * skipping corrupt bytes. Returns CDRO_OK with *out, *skipped (bytes before the record, to be
 * counted as corrupt) and *consumed (the record's size). Returns CDRO_PENDING when no complete
 * good record remains: then in[0, len) is either the start of an incomplete record (more bytes
 * may come, or at the end of a file it is a truncated last record) or corrupt bytes.
 * A record whose length field claims more bytes than remain is only taken for a truncated
 * tail if no good record follows it.
 */
cdro_result_t cdro_capture_next_record(const uint8_t *in, size_t len, cdro_capture_record_t *out, size_t *skipped,
                                       size_t *consumed);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_CAPTURE_H */
