/*
 * layout_descriptor.h: the canonical text of the layout tables, from which the layout hashes
 * are computed (CRC-16/CCITT-FALSE of the ASCII text). The Python generator builds the same
 * text from the same .def files; tests/golden/layout_history.json pins one hash per version.
 *
 * Text: for every record in table order, "NAME ID{KIND field;KIND array[MAX];...}" with ID
 * and MAX spelled as their expanded tokens (e.g. "RANGE 0x02{U32 device_time_ms;...}"). Units
 * and value ranges are left out: the text, and so the hash, covers the bytes on the wire only.
 * Host-side only: the firmware sends the committed CDRO_LAYOUT_HASH constant, not this text.
 */
#ifndef CDRO_LAYOUT_DESCRIPTOR_H
#define CDRO_LAYOUT_DESCRIPTOR_H

#include "cdro/capture_layout.def"
#include "cdro/checkpoint_layout.def"
#include "cdro/frame_layout.def"
#include "cdro/sog_layout.def"

#define CDRO_STRINGIFY_(x) #x
#define CDRO_STRINGIFY(x) CDRO_STRINGIFY_(x)

#define CDRO_X_DESC_FIELD(KIND, field, unit, doc) #KIND " " #field ";"
#define CDRO_X_DESC_RANGED(KIND, field, unit, lo, hi, doc) #KIND " " #field ";"
#define CDRO_X_DESC_ARRAY(KIND, field, max, unit, lo, hi, doc) #KIND " " #field "[" CDRO_STRINGIFY(max) "];"
#define CDRO_X_DESC_RECORD(NAME, name, id, doc) \
#NAME " " #id "{" CDRO_FIELDS_##NAME(CDRO_X_DESC_FIELD, CDRO_X_DESC_RANGED, CDRO_X_DESC_ARRAY) "}"
#define CDRO_X_DESC_EMPTY(NAME, name, id, doc) #NAME " " #id "{}"
/* The checkpoint blocks' repeated records, vectors and square matrices (checkpoint_layout.def). */
#define CDRO_X_DESC_LIST(NAME, field, doc) "LIST " #NAME " " #field ";"
#define CDRO_X_DESC_VECTOR(KIND, field, unit, doc) #KIND " " #field "[];"
#define CDRO_X_DESC_SQUARE(KIND, field, of, unit, doc) #KIND " " #field "[" #of "*" #of "];"
#define CDRO_X_DESC_BLOCK_RECORD(NAME, name, id, doc)                                                    \
#NAME " " #id "{" CDRO_BLOCK_FIELDS_##NAME(CDRO_X_DESC_FIELD, CDRO_X_DESC_RANGED, CDRO_X_DESC_ARRAY, \
                                               CDRO_X_DESC_LIST, CDRO_X_DESC_VECTOR, CDRO_X_DESC_SQUARE) "}"

#define CDRO_FRAME_LAYOUT_DESCRIPTOR CDRO_FRAME_LIST(CDRO_X_DESC_RECORD) CDRO_EMPTY_FRAME_LIST(CDRO_X_DESC_EMPTY)
#define CDRO_SOG_LAYOUT_DESCRIPTOR CDRO_SOG_RECORD_LIST(CDRO_X_DESC_RECORD)
#define CDRO_CAPTURE_LAYOUT_DESCRIPTOR CDRO_CAPTURE_RECORD_LIST(CDRO_X_DESC_RECORD)
#define CDRO_CHECKPOINT_LAYOUT_DESCRIPTOR CDRO_CHECKPOINT_RECORD_LIST(CDRO_X_DESC_RECORD)
#define CDRO_CHECKPOINT_ENGINE_LAYOUT_DESCRIPTOR CDRO_CHECKPOINT_ENGINE_LIST(CDRO_X_DESC_BLOCK_RECORD)
#define CDRO_CHECKPOINT_MOVEMENT_LAYOUT_DESCRIPTOR CDRO_CHECKPOINT_MOVEMENT_LIST(CDRO_X_DESC_BLOCK_RECORD)
#define CDRO_CHECKPOINT_FLIGHT_LAYOUT_DESCRIPTOR CDRO_CHECKPOINT_FLIGHT_LIST(CDRO_X_DESC_BLOCK_RECORD)
#define CDRO_CHECKPOINT_OUTPUT_FRAME_LAYOUT_DESCRIPTOR CDRO_CHECKPOINT_OUTPUT_FRAME_LIST(CDRO_X_DESC_BLOCK_RECORD)

#endif /* CDRO_LAYOUT_DESCRIPTOR_H */
