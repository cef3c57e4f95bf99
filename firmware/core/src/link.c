/*
 * link.c: framed serial link (see link.h).
 */
#include "cdro_fw/link.h"

#include <string.h>

void cdro_link_init(cdro_link_t *link, const cdro_serial_ops_t *ops, void *user)
{
    memset(link, 0, sizeof(*link));
    link->ops = ops;
    link->user = user;
    cdro_decoder_init(&link->decoder);
}

uint8_t cdro_link_send(cdro_link_t *link, cdro_frame_t *frame)
{
    uint8_t encoded[CDRO_MAX_ENCODED_FRAME];
    size_t length;
    frame->sequence = link->sequence++;
    length = cdro_frame_encode(frame, encoded, sizeof encoded);
    if (length == 0U || link->ops->tx_free(link->user) < length) {
        /* A full transmit buffer (or, never expected, a frame the encoder refused). */
        ++link->frames_dropped;
        if (link->dropped_unreported < 0xFFFFU) {
            ++link->dropped_unreported;
        }
        return 0;
    }
    link->ops->tx_write(link->user, encoded, (uint8_t)length);
    ++link->frames_sent;
    return 1;
}

void cdro_link_send_delimiter(cdro_link_t *link)
{
    static const uint8_t zero = 0;
    if (link->ops->tx_free(link->user) >= 1U) {
        link->ops->tx_write(link->user, &zero, 1);
    }
}

cdro_result_t cdro_link_receive(cdro_link_t *link, cdro_frame_t *out, uint8_t *budget)
{
    while (*budget > 0U) {
        cdro_result_t result;
        const int16_t byte = link->ops->rx_read(link->user);
        if (byte < 0) {
            break;
        }
        --*budget;
        result = cdro_decoder_push(&link->decoder, (uint8_t)byte, out);
        if (result != CDRO_PENDING) {
            return result;
        }
    }
    return CDRO_PENDING;
}
