/*
 * layout_codec.h (private): generates field-by-field little-endian codecs from a layout table.
 *
 *   CDRO_X_ENCODER(NAME, name, id, doc) defines
 *       static size_t encode_<name>(const cdro_<name>_t *m, uint8_t *out)
 *     writing the fields in table order; returns the bytes written, 0 if an array count
 *     exceeds its maximum. out must hold CDRO_<NAME>_MAX_SIZE bytes.
 *   CDRO_X_DECODER(NAME, name, id, doc) defines
 *       static cdro_result_t decode_<name>(const uint8_t *in, size_t len, cdro_<name>_t *m)
 *     which reads exactly len bytes: CDRO_ERR_LENGTH if they are too few, too many, or an
 *     array count exceeds its maximum or the bytes left. Nothing is read out of bounds.
 *   CDRO_X_RANGE_CHECK(NAME, name, id, doc) defines
 *       static int ranges_ok_<name>(const cdro_<name>_t *m)
 *     which is 1 when every R field and every element of every A field lies in its range, else 0.
 */
#ifndef CDRO_LAYOUT_CODEC_H
#define CDRO_LAYOUT_CODEC_H

#include <stddef.h>
#include <string.h>

#include "cdro/layout_kinds.h"
#include "cdro/wire.h"

/* Put/get by kind name, so that the X-macros can paste KIND. */
#define cdro_put_U8 cdro_put_u8
#define cdro_put_U16 cdro_put_u16
#define cdro_put_U32 cdro_put_u32
#define cdro_put_U64 cdro_put_u64
#define cdro_put_I16 cdro_put_i16
#define cdro_put_I32 cdro_put_i32
#define cdro_put_I64 cdro_put_i64
#define cdro_get_U8 cdro_get_u8
#define cdro_get_U16 cdro_get_u16
#define cdro_get_U32 cdro_get_u32
#define cdro_get_U64 cdro_get_u64
#define cdro_get_I16 cdro_get_i16
#define cdro_get_I32 cdro_get_i32
#define cdro_get_I64 cdro_get_i64

#define CDRO_X_PUT(KIND, field, unit, doc) p = cdro_put_##KIND(p, m->field);
#define CDRO_X_PUT_RANGED(KIND, field, unit, lo, hi, doc) CDRO_X_PUT(KIND, field, unit, doc)
#define CDRO_X_PUT_ARRAY(KIND, field, max, unit, lo, hi, doc) \
    if (m->field##_count > (max)) {                           \
        return 0;                                             \
    }                                                         \
    p = cdro_put_u8(p, m->field##_count);                     \
    for (i = 0; i < m->field##_count; ++i) {                  \
        p = cdro_put_##KIND(p, m->field[i]);                  \
    }
#define CDRO_X_ENCODER(NAME, name, id, doc)                                                           \
    static size_t encode_##name(const cdro_##name##_t *m, uint8_t *out)                               \
    {                                                                                                 \
        uint8_t *p = out;                                                                             \
        uint8_t i = 0;                                                                                \
        (void)i;                                                                                      \
        CDRO_FIELDS_##NAME(CDRO_X_PUT, CDRO_X_PUT_RANGED, CDRO_X_PUT_ARRAY) return (size_t)(p - out); \
    }

#define CDRO_X_GET(KIND, field, unit, doc) \
    if (remaining < CDRO_SIZE_##KIND) {    \
        return CDRO_ERR_LENGTH;            \
    }                                      \
    m->field = cdro_get_##KIND(p);         \
    p += CDRO_SIZE_##KIND;                 \
    remaining -= CDRO_SIZE_##KIND;
#define CDRO_X_GET_RANGED(KIND, field, unit, lo, hi, doc) CDRO_X_GET(KIND, field, unit, doc)
#define CDRO_X_GET_ARRAY(KIND, field, max, unit, lo, hi, doc)                                  \
    if (remaining < 1U) {                                                                      \
        return CDRO_ERR_LENGTH;                                                                \
    }                                                                                          \
    m->field##_count = cdro_get_u8(p);                                                         \
    p += 1;                                                                                    \
    remaining -= 1U;                                                                           \
    if (m->field##_count > (max) || remaining < (size_t)m->field##_count * CDRO_SIZE_##KIND) { \
        return CDRO_ERR_LENGTH;                                                                \
    }                                                                                          \
    for (i = 0; i < m->field##_count; ++i) {                                                   \
        m->field[i] = cdro_get_##KIND(p);                                                      \
        p += CDRO_SIZE_##KIND;                                                                 \
    }                                                                                          \
    remaining -= (size_t)m->field##_count * CDRO_SIZE_##KIND;
#define CDRO_X_DECODER(NAME, name, id, doc)                                                          \
    static cdro_result_t decode_##name(const uint8_t *in, size_t len, cdro_##name##_t *m)            \
    {                                                                                                \
        const uint8_t *p = in;                                                                       \
        size_t remaining = len;                                                                      \
        uint8_t i = 0;                                                                               \
        (void)i;                                                                                     \
        (void)p;                                                                                     \
        memset(m, 0, sizeof(*m));                                                                    \
        CDRO_FIELDS_##NAME(CDRO_X_GET, CDRO_X_GET_RANGED, CDRO_X_GET_ARRAY) return (remaining == 0U) \
            ? CDRO_OK                                                                                \
            : CDRO_ERR_LENGTH;                                                                       \
    }

/*
 * A function per kind converts the bounds to the field's type, so that a bound the type cannot
 * pass (0 for an unsigned field, 0xFFFF for a u16) folds away instead of being an always-true
 * comparison (-Wtype-limits); a bound the type cannot hold fails to compile (-Woverflow).
 */
static inline int cdro_in_range_U8(uint8_t value, uint8_t lo, uint8_t hi) { return value >= lo && value <= hi; }
static inline int cdro_in_range_U16(uint16_t value, uint16_t lo, uint16_t hi) { return value >= lo && value <= hi; }
static inline int cdro_in_range_U32(uint32_t value, uint32_t lo, uint32_t hi) { return value >= lo && value <= hi; }
static inline int cdro_in_range_I16(int16_t value, int16_t lo, int16_t hi) { return value >= lo && value <= hi; }
static inline int cdro_in_range_I32(int32_t value, int32_t lo, int32_t hi) { return value >= lo && value <= hi; }

#define CDRO_X_CHECK_ANY(KIND, field, unit, doc)
#define CDRO_X_CHECK_RANGE(KIND, field, unit, lo, hi, doc) \
    if (!cdro_in_range_##KIND(m->field, (lo), (hi))) {     \
        return 0;                                          \
    }
#define CDRO_X_CHECK_ARRAY(KIND, field, max, unit, lo, hi, doc) \
    for (i = 0; i < m->field##_count; ++i) {                    \
        if (!cdro_in_range_##KIND(m->field[i], (lo), (hi))) {   \
            return 0;                                           \
        }                                                       \
    }
#define CDRO_X_RANGE_CHECK(NAME, name, id, doc)                                                \
    static int ranges_ok_##name(const cdro_##name##_t *m)                                      \
    {                                                                                          \
        uint8_t i = 0;                                                                         \
        (void)i;                                                                               \
        (void)m;                                                                               \
        CDRO_FIELDS_##NAME(CDRO_X_CHECK_ANY, CDRO_X_CHECK_RANGE, CDRO_X_CHECK_ARRAY) return 1; \
    }

#endif /* CDRO_LAYOUT_CODEC_H */
