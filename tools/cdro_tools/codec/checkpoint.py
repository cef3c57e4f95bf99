"""cdro-hostd's checkpoint blocks (tags TAG_ENGINE, TAG_MOVEMENT, TAG_FLIGHT and TAG_OUTPUT_FRAME)
as named fields.

The layouts are the tables CHECKPOINT_ENGINE_RECORDS, CHECKPOINT_MOVEMENT_RECORDS,
CHECKPOINT_FLIGHT_RECORDS and CHECKPOINT_OUTPUT_FRAME_RECORDS of layout.py, generated from
checkpoint_layout.def, whose C++ expansion (host/hostd/include/cdro/hostd/checkpoint_blocks.hpp)
cdro-hostd writes and reads. One walker serves every record: an L field is a list of dicts, a V
field a list of values, a Q field a list of rows, an A field (a u8 count) a list; doubles (F64)
come out exactly as written.
"""
from __future__ import annotations

import struct
from typing import Any

from .layout import (
    CHECKPOINT_ENGINE_RECORDS,
    CHECKPOINT_FLIGHT_RECORDS,
    CHECKPOINT_MOVEMENT_RECORDS,
    CHECKPOINT_OUTPUT_FRAME_RECORDS,
    CONSTANTS,
)
from .sog import SogError, SogSnapshot

TAG_ENGINE = CONSTANTS["CDRO_CHECKPOINT_TAG_ENGINE"]
TAG_MOVEMENT = CONSTANTS["CDRO_CHECKPOINT_TAG_MOVEMENT"]
ENGINE_VERSION = CONSTANTS["CDRO_CHECKPOINT_ENGINE_VERSION"]
MOVEMENT_VERSION = CONSTANTS["CDRO_CHECKPOINT_MOVEMENT_VERSION"]
TAG_FLIGHT = CONSTANTS["CDRO_CHECKPOINT_TAG_FLIGHT"]
FLIGHT_VERSION = CONSTANTS["CDRO_CHECKPOINT_FLIGHT_VERSION"]
TAG_OUTPUT_FRAME = CONSTANTS["CDRO_CHECKPOINT_TAG_OUTPUT_FRAME"]
OUTPUT_FRAME_VERSION = CONSTANTS["CDRO_CHECKPOINT_OUTPUT_FRAME_VERSION"]

_STRUCT = {"U8": "<B", "U16": "<H", "U32": "<I", "U64": "<Q", "I16": "<h", "I32": "<i", "I64": "<q", "F64": "<d"}
_COUNT = "<I"      # the count before an L or a V
_ARRAY_COUNT = "<B"  # the count before an A
# Far more than any block holds: a bigger count is damage, refused before it is read.
MAX_COUNT = CONSTANTS["CDRO_CHECKPOINT_MAX_LIST_COUNT"]


class _Reader:
    def __init__(self, blob: bytes, block: str):
        self.blob, self.block, self.offset = blob, block, 0

    def take(self, fmt: str, what: str) -> Any:
        size = struct.calcsize(fmt)
        if self.offset + size > len(self.blob):
            raise SogError(f"the {self.block} block is cut short in {what} (byte {self.offset} of {len(self.blob)})")
        (value,) = struct.unpack_from(fmt, self.blob, self.offset)
        self.offset += size
        return value

    def count(self, fmt: str, what: str) -> int:
        value = self.take(fmt, what)
        if value > MAX_COUNT:
            raise SogError(f"the {self.block} block gives {what} a count of {value}")
        return value


def _decode_record(records: dict, name: str, reader: _Reader) -> dict:
    values: dict[str, Any] = {}
    for field in records[name]["fields"]:
        what = f"{name}.{field['name']}"
        if "list" in field:
            count = reader.count(_COUNT, what)
            values[field["name"]] = [_decode_record(records, field["list"], reader) for _ in range(count)]
        elif "vector" in field:
            count = reader.count(_COUNT, what)
            values[field["name"]] = [reader.take(_STRUCT[field["kind"]], what) for _ in range(count)]
        elif "square_of" in field:
            n = len(values[field["square_of"]])
            values[field["name"]] = [[reader.take(_STRUCT[field["kind"]], what) for _ in range(n)] for _ in range(n)]
        elif "max" in field:
            count = reader.take(_ARRAY_COUNT, what)
            values[field["name"]] = [reader.take(_STRUCT[field["kind"]], what) for _ in range(count)]
        else:
            value = reader.take(_STRUCT[field["kind"]], what)
            if "range" in field and not field["range"][0] <= value <= field["range"][1]:
                raise SogError(f"the {reader.block} block's {what} is {value}, outside "
                               f"{field['range'][0]}..{field['range'][1]}")
            values[field["name"]] = value
    return values


def _encode_record(records: dict, name: str, values: dict, out: bytearray) -> None:
    for field in records[name]["fields"]:
        value = values[field["name"]]
        if "list" in field:
            out += struct.pack(_COUNT, len(value))
            for element in value:
                _encode_record(records, field["list"], element, out)
        elif "vector" in field or "max" in field:
            out += struct.pack(_COUNT if "vector" in field else _ARRAY_COUNT, len(value))
            for element in value:
                out += struct.pack(_STRUCT[field["kind"]], element)
        elif "square_of" in field:
            n = len(values[field["square_of"]])
            if len(value) != n or any(len(row) != n for row in value):
                raise ValueError(f"{name}.{field['name']} is not {n} by {n}")
            for row in value:
                for element in row:
                    out += struct.pack(_STRUCT[field["kind"]], element)
        else:
            out += struct.pack(_STRUCT[field["kind"]], value)


def _decode_block(records: dict, blob: bytes, block: str, version: int) -> dict:
    root = next(iter(records))  # the list's first record is the block
    if blob[:1] != bytes([version]):
        raise SogError(f"the {block} block is of version {blob[0] if blob else 'none'}, this build reads {version}")
    reader = _Reader(blob, block)
    values = _decode_record(records, root, reader)
    if reader.offset != len(blob):
        raise SogError(f"the {block} block has {len(blob) - reader.offset} bytes after its end")
    return values


def _encode_block(records: dict, name: str, values: dict) -> bytes:
    out = bytearray()
    _encode_record(records, name, values, out)
    return bytes(out)


def _extension_block(snapshot: SogSnapshot, tag: int, decode) -> dict | None:
    blob = dict(snapshot.extensions).get(tag)
    return None if blob is None else decode(blob)


def decode_engine_block(blob: bytes) -> dict:
    """The fields of a TAG_ENGINE block (ENGINE_BLOCK, its nodes ENGINE_NODE, links ENGINE_LINK)."""
    return _decode_block(CHECKPOINT_ENGINE_RECORDS, blob, "engine", ENGINE_VERSION)


def decode_movement_block(blob: bytes) -> dict:
    """The fields of a TAG_MOVEMENT block (MOVEMENT_BLOCK and the records it lists)."""
    return _decode_block(CHECKPOINT_MOVEMENT_RECORDS, blob, "movement", MOVEMENT_VERSION)


def decode_flight_block(blob: bytes) -> dict:
    """The fields of a TAG_FLIGHT block (FLIGHT_BLOCK, its nodes, bodies and anchors)."""
    return _decode_block(CHECKPOINT_FLIGHT_RECORDS, blob, "flight", FLIGHT_VERSION)


def decode_output_frame_block(blob: bytes) -> dict:
    """The fields of a TAG_OUTPUT_FRAME block (OUTPUT_FRAME_BLOCK: the output frame's offset)."""
    return _decode_block(CHECKPOINT_OUTPUT_FRAME_RECORDS, blob, "output frame", OUTPUT_FRAME_VERSION)


def encode_engine_block(values: dict) -> bytes:
    return _encode_block(CHECKPOINT_ENGINE_RECORDS, "ENGINE_BLOCK", values)


def encode_movement_block(values: dict) -> bytes:
    return _encode_block(CHECKPOINT_MOVEMENT_RECORDS, "MOVEMENT_BLOCK", values)


def engine_blocks(snapshot: SogSnapshot) -> tuple[dict, dict | None]:
    """A cdro-hostd checkpoint's engine block, and its movement block (None without a robot)."""
    blocks = dict(snapshot.extensions)
    if TAG_ENGINE not in blocks:
        raise SogError("the checkpoint has no engine block (tag 0x0001): not written by cdro-hostd")
    return decode_engine_block(blocks[TAG_ENGINE]), _extension_block(snapshot, TAG_MOVEMENT, decode_movement_block)


def encode_flight_block(values: dict) -> bytes:
    return _encode_block(CHECKPOINT_FLIGHT_RECORDS, "FLIGHT_BLOCK", values)


def flight_block(snapshot: SogSnapshot) -> dict | None:
    """A cdro-hostd checkpoint's 3D tracks (None when it tracked no node in 3D)."""
    return _extension_block(snapshot, TAG_FLIGHT, decode_flight_block)


def encode_output_frame_block(values: dict) -> bytes:
    return _encode_block(CHECKPOINT_OUTPUT_FRAME_RECORDS, "OUTPUT_FRAME_BLOCK", values)


def output_frame_block(snapshot: SogSnapshot) -> dict | None:
    """A cdro-hostd checkpoint's output frame offset (None: the frame triangle's own frame)."""
    return _extension_block(snapshot, TAG_OUTPUT_FRAME, decode_output_frame_block)
