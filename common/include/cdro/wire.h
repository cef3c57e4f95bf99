/*
 * wire.h: little-endian put/get helpers. Every multi-byte field on the wire, in capture files
 * and in SoG snapshots goes through these; no struct is ever cast onto bytes.
 *
 * put_*: writes at p, returns p advanced past the field. The caller guarantees the room.
 * get_*: reads at p. The caller guarantees the bytes are there.
 */
#ifndef CDRO_WIRE_H
#define CDRO_WIRE_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

static inline uint8_t *cdro_put_u8(uint8_t *p, uint8_t v)
{
    p[0] = v;
    return p + 1;
}

static inline uint8_t *cdro_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFU);
    p[1] = (uint8_t)(v >> 8);
    return p + 2;
}

static inline uint8_t *cdro_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v & 0xFFUL);
    p[1] = (uint8_t)((v >> 8) & 0xFFUL);
    p[2] = (uint8_t)((v >> 16) & 0xFFUL);
    p[3] = (uint8_t)(v >> 24);
    return p + 4;
}

static inline uint8_t *cdro_put_u64(uint8_t *p, uint64_t v)
{
    p = cdro_put_u32(p, (uint32_t)(v & 0xFFFFFFFFULL));
    return cdro_put_u32(p, (uint32_t)(v >> 32));
}

/* Signed values travel as two's complement; the casts are value-preserving modulo 2^n. */
static inline uint8_t *cdro_put_i16(uint8_t *p, int16_t v) { return cdro_put_u16(p, (uint16_t)v); }
static inline uint8_t *cdro_put_i32(uint8_t *p, int32_t v) { return cdro_put_u32(p, (uint32_t)v); }
static inline uint8_t *cdro_put_i64(uint8_t *p, int64_t v) { return cdro_put_u64(p, (uint64_t)v); }

static inline uint8_t cdro_get_u8(const uint8_t *p) { return p[0]; }

static inline uint16_t cdro_get_u16(const uint8_t *p)
{
    return (uint16_t)((uint16_t)p[0] | (uint16_t)((uint16_t)p[1] << 8));
}

static inline uint32_t cdro_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static inline uint64_t cdro_get_u64(const uint8_t *p)
{
    return (uint64_t)cdro_get_u32(p) | ((uint64_t)cdro_get_u32(p + 4) << 32);
}

/* Two's complement back to signed without implementation-defined conversions. */
static inline int16_t cdro_get_i16(const uint8_t *p)
{
    const uint16_t u = cdro_get_u16(p);
    return (u <= 0x7FFFU) ? (int16_t)u : (int16_t)(-(int16_t)(uint16_t)(~u) - 1);
}

static inline int32_t cdro_get_i32(const uint8_t *p)
{
    const uint32_t u = cdro_get_u32(p);
    return (u <= 0x7FFFFFFFUL) ? (int32_t)u : (int32_t)(-(int32_t)(uint32_t)(~u) - 1);
}

static inline int64_t cdro_get_i64(const uint8_t *p)
{
    const uint64_t u = cdro_get_u64(p);
    return (u <= 0x7FFFFFFFFFFFFFFFULL) ? (int64_t)u : (int64_t)(-(int64_t)(uint64_t)(~u) - 1);
}

#ifdef __cplusplus
}
#endif

#endif /* CDRO_WIRE_H */
