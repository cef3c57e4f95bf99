/*
 * crc.h: the two checksums of the project.
 *
 * CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0; check value of
 * "123456789" = 0x29B1): frames, capture-file headers and records.
 * CRC-32/ISO-HDLC (the zlib/Ethernet CRC; check value 0xCBF43926): SoG snapshots, which are
 * large enough that 16 bits would be a weak check.
 *
 * Both are incremental: feeding the bytes in any number of chunks gives the one-shot result.
 * Bitwise implementations, no tables: they cost no flash on the AVR and are fast enough for
 * the host's frame rates (see bench/).
 */
#ifndef CDRO_CRC_H
#define CDRO_CRC_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define CDRO_CRC16_INIT 0xFFFFU

/* Continues a CRC-16/CCITT-FALSE over len bytes. Start with CDRO_CRC16_INIT. */
uint16_t cdro_crc16_update(uint16_t crc, const uint8_t *data, size_t len);

/* One-shot CRC-16/CCITT-FALSE. */
uint16_t cdro_crc16(const uint8_t *data, size_t len);

#define CDRO_CRC32_INIT 0xFFFFFFFFUL

/* Continues a CRC-32 over len bytes. Start with CDRO_CRC32_INIT, finish with cdro_crc32_final. */
uint32_t cdro_crc32_update(uint32_t state, const uint8_t *data, size_t len);
uint32_t cdro_crc32_final(uint32_t state);

/* One-shot CRC-32/ISO-HDLC. */
uint32_t cdro_crc32(const uint8_t *data, size_t len);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_CRC_H */
