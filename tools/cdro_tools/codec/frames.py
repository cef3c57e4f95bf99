"""Frames of the CDRO serial protocol: the Python twin of common/include/cdro/frames.h.

Layouts come from layout.py, generated from common/'s frame_layout.def; nothing here restates
a field. The checks, their order and the result names are the C decoder's, and the golden
vectors in tests/golden/ hold both implementations to the same bytes.
"""
from __future__ import annotations

import dataclasses
import enum
import struct
from typing import Any, Iterator

from .checksums import crc16
from .cobs import CobsError, cobs_decode, cobs_encode, max_encoded_size
from .layout import CONSTANTS, FRAME_TYPES

C = CONSTANTS
PROTOCOL_VERSION = C["CDRO_PROTOCOL_VERSION"]
LAYOUT_HASH = C["CDRO_LAYOUT_HASH"]
HEADER_SIZE = C["CDRO_HEADER_SIZE"]
CRC_SIZE = C["CDRO_CRC_SIZE"]
MAX_PAYLOAD = C["CDRO_MAX_PAYLOAD"]
MAX_RAW_FRAME = HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE
MAX_ENCODED_FRAME = max_encoded_size(MAX_RAW_FRAME) + 1  # with the delimiter

TYPE_IDS = {name: spec["id"] for name, spec in FRAME_TYPES.items()}
TYPE_NAMES = {spec["id"]: name for name, spec in FRAME_TYPES.items()}

_STRUCT = {"U8": "<B", "U16": "<H", "U32": "<I", "U64": "<Q", "I16": "<h", "I32": "<i", "I64": "<q"}
SIZES = {kind: struct.calcsize(fmt) for kind, fmt in _STRUCT.items()}


def record_struct(spec_fields: list[dict]) -> struct.Struct:
    """A fixed-size table (no arrays) as one struct.Struct, fields in table order: for records
    read by the million (capture files), where unpack_fields' per-field work would show."""
    if any("max" in field for field in spec_fields):
        raise ValueError("record_struct: a table with an array has no fixed size")
    return struct.Struct("<" + "".join(_STRUCT[field["kind"]][1:] for field in spec_fields))


class Result(enum.IntEnum):
    """cdro_result_t; str() gives cdro_result_name()."""

    PENDING = 1
    OK = 0
    ARGUMENT = -1
    COBS = -2
    SHORT = -3
    CRC = -4
    VERSION = -5
    TYPE = -6
    LENGTH = -7
    TOO_LONG = -8
    VALUE = -9

    def __str__(self) -> str:
        return self.name.lower()


@dataclasses.dataclass
class Frame:
    """One frame: its type name ("RANGE"), sequence number and payload fields by name.

    Array fields are lists. For a frame rejected after its CRC passed, type may be an
    unknown id written as "0x7E".
    """

    type: str
    sequence: int = 0
    fields: dict[str, Any] = dataclasses.field(default_factory=dict)
    version: int = PROTOCOL_VERSION

    @property
    def type_id(self) -> int:
        return TYPE_IDS[self.type] if self.type in TYPE_IDS else int(self.type, 16)

    def __getitem__(self, name: str) -> Any:
        return self.fields[name]


class FrameError(ValueError):
    """A rejected chunk: result says why; frame holds what could be read (after the CRC)."""

    def __init__(self, result: Result, message: str, frame: Frame | None = None):
        super().__init__(f"{result}: {message}")
        self.result = result
        self.frame = frame


# ---- payloads, field by field -------------------------------------------------------------

def pack_fields(spec_fields: list[dict], values: dict[str, Any]) -> bytes:
    """Packs fields in table order. Shared with the SoG snapshot records."""
    out = bytearray()
    for field in spec_fields:
        name, kind = field["name"], field["kind"]
        if name not in values:
            raise ValueError(f"missing field {name}")
        try:
            if "max" in field:
                items = list(values[name])
                if len(items) > field["max"]:
                    raise ValueError(f"{name}: {len(items)} elements, at most {field['max']}")
                out += struct.pack("<B", len(items))
                for item in items:
                    out += struct.pack(_STRUCT[kind], item)
            else:
                out += struct.pack(_STRUCT[kind], values[name])
        except struct.error as error:
            raise ValueError(f"{name}: {values[name]!r} does not fit {kind}") from error
    unknown = set(values) - {f["name"] for f in spec_fields}
    if unknown:
        raise ValueError(f"unknown fields {sorted(unknown)}")
    return bytes(out)


def unpack_fields(spec_fields: list[dict], payload: bytes) -> dict[str, Any]:
    """Unpacks exactly len(payload) bytes; raises FrameError(LENGTH) otherwise."""
    values: dict[str, Any] = {}
    offset = 0
    for field in spec_fields:
        name, kind = field["name"], field["kind"]
        size = SIZES[kind]
        if "max" in field:
            if offset + 1 > len(payload):
                raise FrameError(Result.LENGTH, f"{name}: count missing")
            count = payload[offset]
            offset += 1
            if count > field["max"] or offset + count * size > len(payload):
                raise FrameError(Result.LENGTH, f"{name}: count {count} does not fit")
            values[name] = [struct.unpack_from(_STRUCT[kind], payload, offset + i * size)[0] for i in range(count)]
            offset += count * size
        else:
            if offset + size > len(payload):
                raise FrameError(Result.LENGTH, f"{name}: payload ends early")
            values[name] = struct.unpack_from(_STRUCT[kind], payload, offset)[0]
            offset += size
    if offset != len(payload):
        raise FrameError(Result.LENGTH, f"{len(payload) - offset} bytes after the last field")
    return values


# ---- whole frames ---------------------------------------------------------------------------

def encode_frame(frame: Frame) -> bytes:
    """COBS bytes of header, payload and CRC, followed by the 0x00 delimiter."""
    if frame.type not in FRAME_TYPES:
        raise ValueError(f"unknown frame type {frame.type}")
    payload = pack_fields(FRAME_TYPES[frame.type]["fields"], frame.fields)
    raw = struct.pack("<BBHB", PROTOCOL_VERSION, TYPE_IDS[frame.type], frame.sequence & 0xFFFF, len(payload)) + payload
    raw += struct.pack("<H", crc16(raw))
    return cobs_encode(raw) + b"\x00"


def decode_frame(chunk: bytes) -> Frame:
    """Decodes one chunk (the COBS bytes between delimiters), checks as the C decoder does."""
    if len(chunk) > MAX_ENCODED_FRAME - 1:
        raise FrameError(Result.TOO_LONG, f"{len(chunk)} bytes without a delimiter")
    try:
        raw = cobs_decode(chunk)
    except CobsError as error:
        raise FrameError(Result.COBS, str(error)) from error
    if len(raw) > MAX_RAW_FRAME:
        raise FrameError(Result.COBS, f"{len(raw)} bytes decoded, at most {MAX_RAW_FRAME}")
    if len(raw) < HEADER_SIZE + CRC_SIZE:
        raise FrameError(Result.SHORT, f"{len(raw)} bytes")
    (received,) = struct.unpack_from("<H", raw, len(raw) - CRC_SIZE)
    computed = crc16(raw[:-CRC_SIZE])
    if computed != received:
        raise FrameError(Result.CRC, f"received 0x{received:04X}, computed 0x{computed:04X}")
    version, type_id, sequence, length = struct.unpack_from("<BBHB", raw, 0)
    frame = Frame(type=TYPE_NAMES.get(type_id, f"0x{type_id:02X}"), sequence=sequence, version=version)
    if version != PROTOCOL_VERSION:
        raise FrameError(Result.VERSION, f"protocol version {version}, this build speaks {PROTOCOL_VERSION}", frame)
    payload = raw[HEADER_SIZE:-CRC_SIZE]
    if length != len(payload):
        raise FrameError(Result.LENGTH, f"length field {length}, payload {len(payload)} bytes", frame)
    if type_id not in TYPE_NAMES:
        raise FrameError(Result.TYPE, f"unknown frame type 0x{type_id:02X}", frame)
    try:
        frame.fields = unpack_fields(FRAME_TYPES[frame.type]["fields"], payload)
    except FrameError as error:
        raise FrameError(error.result, f"{frame.type}: {error}", frame) from None
    return frame


# UWB_PLEN codes (register facts 2.4): 64, 128, 256, 512, 1024, 1536, 2048, 4096 symbols.
UWB_PREAMBLE_CODES = (0x04, 0x14, 0x24, 0x34, 0x08, 0x18, 0x28, 0x0C)


def _range_problem(spec_fields: list[dict], values: dict[str, Any]) -> str | None:
    """The first value outside its declared range (layout.py, from frame_layout.def), or None."""
    for field in spec_fields:
        if "range" not in field:
            continue
        lo, hi = field["range"]
        items = values[field["name"]] if "max" in field else [values[field["name"]]]
        for item in items:
            if not lo <= item <= hi:
                unit = f" {field['unit']}" if field["unit"] else ""
                return f"{field['name']} {item}{unit} outside {lo}..{hi}"
    return None


def _other_rule_problem(t: str, f: dict[str, Any]) -> str | None:
    """The rules that are not one field's range, so frame_layout.def cannot declare them:
    between two fields, across an array's elements, and on the bit fields and code sets of
    SET_UWB. The one place for them in Python; other_rules_ok in common/src/frames.c has their
    C twin."""
    if t == "RANGE" and f["from_id"] == f["to_id"]:
        return f"from_id and to_id both {f['from_id']}"
    if t in ("NODE_LIST", "SET_NODES") and len(set(f["node_ids"])) != len(f["node_ids"]):
        return f"node_ids {f['node_ids']} hold an id twice"
    if t == "SET_UWB":
        if f["uwb_channel"] == 6:
            return "uwb_channel 6 does not exist"
        if (f["uwb_rates"] & 0x3F) > 2 or not 1 <= (f["uwb_rates"] >> 6) <= 2:
            return f"uwb_rates 0x{f['uwb_rates']:02X}: bitrate above 2 or PRF not 1..2"
        if f["uwb_plen"] not in UWB_PREAMBLE_CODES:
            return f"uwb_plen 0x{f['uwb_plen']:02X} is no preamble code"
    return None


def validate_frame(frame: Frame) -> None:
    """The value ranges of frame_layout.def and the rules beside them; raises FrameError(VALUE)."""
    if frame.type not in FRAME_TYPES:
        raise FrameError(Result.TYPE, f"unknown frame type {frame.type}", frame)
    problem = (_range_problem(FRAME_TYPES[frame.type]["fields"], frame.fields)
               or _other_rule_problem(frame.type, frame.fields))
    if problem:
        raise FrameError(Result.VALUE, f"{frame.type}: {problem}", frame)


# ---- streaming, with resynchronisation --------------------------------------------------------

COUNTER_NAMES = ("frames_ok", "cobs_errors", "short_errors", "crc_errors", "version_errors", "type_errors",
                 "length_errors", "value_errors", "too_long_errors", "bytes_discarded")
_COUNTER_OF = {Result.COBS: "cobs_errors", Result.SHORT: "short_errors", Result.CRC: "crc_errors",
               Result.VERSION: "version_errors", Result.TYPE: "type_errors", Result.LENGTH: "length_errors",
               Result.VALUE: "value_errors", Result.TOO_LONG: "too_long_errors"}


@dataclasses.dataclass
class DecodeEvent:
    """One chunk that ended: result OK with a frame, or the rejection (frame may be partial)."""

    result: Result
    frame: Frame | None
    chunk: bytes          # the chunk's bytes (for TOO_LONG, the first MAX_ENCODED_FRAME of them)
    chunk_length: int     # the chunk's full length in bytes
    message: str = ""


class StreamDecoder:
    """Byte-stream decoder with the C decoder's rules and counters (cdro_decoder_t)."""

    def __init__(self) -> None:
        self.counters = dict.fromkeys(COUNTER_NAMES, 0)
        self._chunk = bytearray()
        self._overflow_length = 0

    def feed(self, data: bytes) -> Iterator[DecodeEvent]:
        """Yields one event per chunk that ends in data; empty chunks yield nothing."""
        start = 0
        while start <= len(data):
            end = data.find(b"\x00", start)
            if end < 0:
                self._append(data[start:])
                return
            self._append(data[start:end])
            start = end + 1
            event = self._finish_chunk()
            if event is not None:
                yield event

    def _append(self, part: bytes) -> None:
        if self._overflow_length:
            self._overflow_length += len(part)
            return
        room = MAX_ENCODED_FRAME - len(self._chunk)
        if len(part) > room:
            self._chunk += part[:room]
            self._overflow_length = len(self._chunk) + len(part) - room
        else:
            self._chunk += part

    def _finish_chunk(self) -> DecodeEvent | None:
        chunk = bytes(self._chunk)
        overflow = self._overflow_length
        self._chunk.clear()
        self._overflow_length = 0
        if overflow:
            self.counters["too_long_errors"] += 1
            self.counters["bytes_discarded"] += overflow
            return DecodeEvent(Result.TOO_LONG, None, chunk, overflow, f"{overflow} bytes without a delimiter")
        if not chunk:
            return None
        try:
            frame = decode_frame(chunk)
            validate_frame(frame)
        except FrameError as error:
            self.counters[_COUNTER_OF[error.result]] += 1
            self.counters["bytes_discarded"] += len(chunk)
            return DecodeEvent(error.result, error.frame, chunk, len(chunk), str(error))
        self.counters["frames_ok"] += 1
        return DecodeEvent(Result.OK, frame, chunk, len(chunk))
