/*
 * link.h: the framed serial link of the firmware: frames out through common/'s encoder,
 * host bytes in through common/'s streaming decoder.
 *
 * The serial port is a seam too (cdro_serial_ops_t): the Arduino binding maps it to
 * HardwareSerial, the tests to a byte buffer. A frame is written only when the transmit buffer
 * can take all of it at once (tx_free), so sending never waits for the UART: a frame that does
 * not fit is dropped and counted, and its sequence number is spent, so the host sees the gap.
 */
#ifndef CDRO_FW_LINK_H
#define CDRO_FW_LINK_H

#include <stdint.h>

#include "cdro/frames.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct cdro_serial_ops {
    /* Bytes the transmit buffer takes now without waiting. */
    uint16_t (*tx_free)(void *user);
    /* Queues length bytes; only called with length <= tx_free(). */
    void (*tx_write)(void *user, const uint8_t *data, uint8_t length);
    /* The next received byte, or -1 when none is waiting. */
    int16_t (*rx_read)(void *user);
} cdro_serial_ops_t;

typedef struct cdro_link {
    const cdro_serial_ops_t *ops;
    void *user;
    uint16_t sequence;           /* sequence number of the next frame */
    uint16_t dropped_unreported; /* frames dropped since the last ERROR TX_OVERFLOW (saturating) */
    uint32_t frames_sent;        /* count of frames written */
    uint32_t frames_dropped;     /* count of frames dropped: transmit buffer full */
    cdro_decoder_t decoder;      /* host bytes to frames */
} cdro_link_t;

void cdro_link_init(cdro_link_t *link, const cdro_serial_ops_t *ops, void *user);

/* Sets frame->sequence, encodes and writes it, or drops it if the transmit buffer cannot take
 * it whole. Returns 1 if written, 0 if dropped. */
uint8_t cdro_link_send(cdro_link_t *link, cdro_frame_t *frame);

/* Writes one 0x00 (ends any partial frame the host holds) if there is room. */
void cdro_link_send_delimiter(cdro_link_t *link);

/* Feeds received bytes to the decoder until a chunk ends, no byte is waiting, or *budget
 * bytes have been read (decremented per byte). Returns what cdro_decoder_push returned for
 * the last byte: CDRO_PENDING if no chunk ended, CDRO_OK with *out decoded and validated, or
 * a rejection (< 0; after a good CRC, out->version/type/sequence name the rejected frame). */
cdro_result_t cdro_link_receive(cdro_link_t *link, cdro_frame_t *out, uint8_t *budget);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_FW_LINK_H */
