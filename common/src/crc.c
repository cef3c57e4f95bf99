#include "cdro/crc.h"

uint16_t cdro_crc16_update(uint16_t crc, const uint8_t *data, size_t len)
{
    size_t i;
    for (i = 0; i < len; ++i) {
        uint8_t bit;
        crc = (uint16_t)(crc ^ (uint16_t)((uint16_t)data[i] << 8));
        for (bit = 0; bit < 8U; ++bit) {
            const uint16_t shifted = (uint16_t)(crc << 1);
            crc = (crc & 0x8000U) ? (uint16_t)(shifted ^ 0x1021U) : shifted;
        }
    }
    return crc;
}

uint16_t cdro_crc16(const uint8_t *data, size_t len) { return cdro_crc16_update(CDRO_CRC16_INIT, data, len); }

uint32_t cdro_crc32_update(uint32_t state, const uint8_t *data, size_t len)
{
    size_t i;
    for (i = 0; i < len; ++i) {
        uint8_t bit;
        state ^= data[i];
        for (bit = 0; bit < 8U; ++bit) {
            state = (state & 1UL) ? ((state >> 1) ^ 0xEDB88320UL) : (state >> 1);
        }
    }
    return state;
}

uint32_t cdro_crc32_final(uint32_t state) { return state ^ 0xFFFFFFFFUL; }

uint32_t cdro_crc32(const uint8_t *data, size_t len)
{
    return cdro_crc32_final(cdro_crc32_update(CDRO_CRC32_INIT, data, len));
}
