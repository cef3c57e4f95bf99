#include "cdro/cobs.h"

size_t cdro_cobs_encode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap)
{
    size_t read_index = 0;
    size_t write_index = 1; /* dst[0] is reserved for the first code byte */
    size_t code_index = 0;
    uint8_t code = 1;

    if (dst_cap < 1U) {
        return 0;
    }
    while (read_index < len) {
        if (src[read_index] == 0U) {
            dst[code_index] = code;
            code = 1;
            code_index = write_index++;
            if (code_index >= dst_cap) {
                return 0;
            }
            ++read_index;
        } else {
            if (write_index >= dst_cap) {
                return 0;
            }
            dst[write_index++] = src[read_index++];
            ++code;
            if (code == 0xFFU) {
                dst[code_index] = code;
                code = 1;
                if (read_index == len) {
                    /* A full block ends the input: no further code byte is needed. */
                    return write_index;
                }
                code_index = write_index++;
                if (code_index >= dst_cap) {
                    return 0;
                }
            }
        }
    }
    dst[code_index] = code;
    return write_index;
}

long cdro_cobs_decode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap)
{
    size_t read_index = 0;
    size_t write_index = 0;

    if (len == 0U) {
        return -1;
    }
    while (read_index < len) {
        const uint8_t code = src[read_index];
        uint8_t i;
        if (code == 0U) {
            return -1;
        }
        if ((size_t)code - 1U > len - read_index - 1U) {
            return -1; /* the block claims more bytes than remain */
        }
        ++read_index;
        for (i = 1; i < code; ++i) {
            const uint8_t byte = src[read_index++];
            if (byte == 0U || write_index >= dst_cap) {
                return -1;
            }
            dst[write_index++] = byte;
        }
        if (code != 0xFFU && read_index < len) {
            if (write_index >= dst_cap) {
                return -1;
            }
            dst[write_index++] = 0U;
        }
    }
    return (long)write_index;
}
