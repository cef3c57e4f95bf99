/*
 * layout_kinds.h: the field kinds of the layout tables (frame_layout.def, sog_layout.def) and
 * the X-macros that turn a table into C structs and size constants. The codecs that read and
 * write the fields one by one are generated in common/src/layout_codec.h.
 */
#ifndef CDRO_LAYOUT_KINDS_H
#define CDRO_LAYOUT_KINDS_H

#include <stdint.h>

#define CDRO_CTYPE_U8 uint8_t
#define CDRO_CTYPE_U16 uint16_t
#define CDRO_CTYPE_U32 uint32_t
#define CDRO_CTYPE_U64 uint64_t
#define CDRO_CTYPE_I16 int16_t
#define CDRO_CTYPE_I32 int32_t
#define CDRO_CTYPE_I64 int64_t
#define CDRO_CTYPE_F64 double /* host-side tables only (checkpoint_layout.def's blocks) */
#define CDRO_SIZE_U8 1
#define CDRO_SIZE_U16 2
#define CDRO_SIZE_U32 4
#define CDRO_SIZE_U64 8
#define CDRO_SIZE_I16 2
#define CDRO_SIZE_I32 4
#define CDRO_SIZE_I64 8
#define CDRO_SIZE_F64 8

/* A table's fields come in three shapes (F any value, R a range, A an array; see the grammar in
 * frame_layout.def). Expansions that care about the layout only forward R to their F. */

/* typedef struct cdro_<name> { fields } cdro_<name>_t; arrays carry <field>_count. */
#define CDRO_X_MEMBER(KIND, field, unit, doc) CDRO_CTYPE_##KIND field;
#define CDRO_X_RANGED_MEMBER(KIND, field, unit, lo, hi, doc) CDRO_X_MEMBER(KIND, field, unit, doc)
#define CDRO_X_ARRAY_MEMBER(KIND, field, max, unit, lo, hi, doc) \
    uint8_t field##_count;                                       \
    CDRO_CTYPE_##KIND field[max];
#define CDRO_X_STRUCT(NAME, name, id, doc)                                           \
    typedef struct cdro_##name {                                                     \
        CDRO_FIELDS_##NAME(CDRO_X_MEMBER, CDRO_X_RANGED_MEMBER, CDRO_X_ARRAY_MEMBER) \
    } cdro_##name##_t;

/* CDRO_<NAME>_MIN_SIZE (arrays empty) and CDRO_<NAME>_MAX_SIZE, in bytes. */
#define CDRO_X_SIZE(KIND, field, unit, doc) +CDRO_SIZE_##KIND
#define CDRO_X_RANGED_SIZE(KIND, field, unit, lo, hi, doc) +CDRO_SIZE_##KIND
#define CDRO_X_ARRAY_MIN(KIND, field, max, unit, lo, hi, doc) +1
#define CDRO_X_ARRAY_MAX(KIND, field, max, unit, lo, hi, doc) +1 + (max)*CDRO_SIZE_##KIND
#define CDRO_X_SIZES(NAME, name, id, doc)                                                                 \
    enum {                                                                                                \
        CDRO_##NAME##_MIN_SIZE = 0 CDRO_FIELDS_##NAME(CDRO_X_SIZE, CDRO_X_RANGED_SIZE, CDRO_X_ARRAY_MIN), \
        CDRO_##NAME##_MAX_SIZE = 0 CDRO_FIELDS_##NAME(CDRO_X_SIZE, CDRO_X_RANGED_SIZE, CDRO_X_ARRAY_MAX)  \
    };

#endif /* CDRO_LAYOUT_KINDS_H */
