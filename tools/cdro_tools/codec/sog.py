"""Fixed-point SoG snapshots, the Python twin of common/include/cdro/sog_layout.h.

Records come from layout.py (generated from sog_layout.def); the file structure (magic,
header, nodes, pairs with their components, extensions, end tag, CRC-32) is documented in
sog_layout.h and docs/protocol.md. The extension tags and the service's block come from
checkpoint_layout.def (checkpoint_layout.h in C).
"""
from __future__ import annotations

import dataclasses
import struct

from .checksums import crc32
from .frames import SIZES, FrameError, pack_fields, unpack_fields
from .layout import CHECKPOINT_RECORDS, CONSTANTS, SOG_RECORDS

MAGIC = b"CDSG"
LAYOUT_VERSION = CONSTANTS["CDRO_SOG_LAYOUT_VERSION"]
LAYOUT_HASH = CONSTANTS["CDRO_SOG_LAYOUT_HASH"]
RECORD_SIZES = {name: sum(SIZES[f["kind"]] for f in spec["fields"]) for name, spec in SOG_RECORDS.items()}
TAG_ENGINE = CONSTANTS["CDRO_CHECKPOINT_TAG_ENGINE"]       # cdro-hostd's engine block
TAG_MOVEMENT = CONSTANTS["CDRO_CHECKPOINT_TAG_MOVEMENT"]   # cdro-hostd's movement stage
TAG_FLIGHT = CONSTANTS["CDRO_CHECKPOINT_TAG_FLIGHT"]       # cdro-hostd's 3D tracks
TAG_OUTPUT_FRAME = CONSTANTS["CDRO_CHECKPOINT_TAG_OUTPUT_FRAME"]  # cdro-hostd's output frame offset
TAG_SERVICE = CONSTANTS["CDRO_CHECKPOINT_TAG_SERVICE"]     # SERVICE_INFO
SERVICE_INFO_VERSION = CONSTANTS["CDRO_CHECKPOINT_SERVICE_INFO_VERSION"]
_SERVICE_INFO = CHECKPOINT_RECORDS["SERVICE_INFO"]["fields"]
SERVICE_INFO_SIZE = sum(SIZES[f["kind"]] for f in _SERVICE_INFO)


class SogError(ValueError):
    """Not a snapshot, corrupt, another layout, or counts that do not fit."""


@dataclasses.dataclass
class SogPair:
    fields: dict                   # SOG_PAIR fields except component_count (taken from components)
    components: list[dict]         # SOG_COMPONENT fields


@dataclasses.dataclass
class SogSnapshot:
    header: dict                   # SOG_HEADER fields; counts and layout fields are filled on encode
    nodes: list[dict]              # SOG_NODE fields
    pairs: list[SogPair]
    extensions: list[tuple[int, bytes]] = dataclasses.field(default_factory=list)


def _pack(record: str, values: dict) -> bytes:
    return pack_fields(SOG_RECORDS[record]["fields"], values)


def encode_sog(snapshot: SogSnapshot) -> bytes:
    header = dict(snapshot.header)
    header.update(layout_version=LAYOUT_VERSION, layout_hash=LAYOUT_HASH, node_count=len(snapshot.nodes),
                  pair_count=len(snapshot.pairs),
                  component_count=sum(len(p.components) for p in snapshot.pairs))
    header.setdefault("flags", 0)
    out = bytearray(MAGIC + _pack("SOG_HEADER", header))
    for node in snapshot.nodes:
        out += _pack("SOG_NODE", node)
    for pair in snapshot.pairs:
        out += _pack("SOG_PAIR", dict(pair.fields, component_count=len(pair.components)))
        for component in pair.components:
            out += _pack("SOG_COMPONENT", component)
    for tag, blob in snapshot.extensions:
        if tag == 0:
            raise ValueError("extension tag 0 is the end marker")
        out += struct.pack("<HI", tag, len(blob)) + blob
    out += struct.pack("<H", 0)
    out += struct.pack("<I", crc32(bytes(out)))
    return bytes(out)


def decode_sog(data: bytes) -> SogSnapshot:
    if data[:4] != MAGIC:
        raise SogError("not a SoG snapshot (bad magic)")
    header_size = RECORD_SIZES["SOG_HEADER"]
    if len(data) < 4 + header_size + 2 + 4:
        raise SogError("snapshot cut short")
    body = data[:-4]
    (received,) = struct.unpack_from("<I", data, len(data) - 4)
    if crc32(body) != received:
        raise SogError("corrupt or cut short (CRC-32 mismatch)")
    try:
        header = unpack_fields(SOG_RECORDS["SOG_HEADER"]["fields"], body[4:4 + header_size])
    except FrameError as error:
        raise SogError(str(error)) from None
    if header["layout_version"] != LAYOUT_VERSION or header["layout_hash"] != LAYOUT_HASH:
        raise SogError(f"snapshot layout {header['layout_version']}/0x{header['layout_hash']:04X}, "
                       f"this build reads {LAYOUT_VERSION}/0x{LAYOUT_HASH:04X}")
    minimum = (4 + header_size + header["node_count"] * RECORD_SIZES["SOG_NODE"]
               + header["pair_count"] * RECORD_SIZES["SOG_PAIR"]
               + header["component_count"] * RECORD_SIZES["SOG_COMPONENT"] + 2)
    if minimum > len(body):
        raise SogError("counts in the header do not fit the snapshot")
    offset = 4 + header_size

    def take(record: str) -> dict:
        nonlocal offset
        size = RECORD_SIZES[record]
        if offset + size > len(body):
            raise SogError(f"snapshot ends inside a {record}")
        values = unpack_fields(SOG_RECORDS[record]["fields"], body[offset:offset + size])
        offset += size
        return values

    nodes = [take("SOG_NODE") for _ in range(header["node_count"])]
    pairs = []
    for _ in range(header["pair_count"]):
        fields = take("SOG_PAIR")
        count = fields.pop("component_count")
        pairs.append(SogPair(fields, [take("SOG_COMPONENT") for _ in range(count)]))
    extensions = []
    while True:
        if offset + 2 > len(body):
            raise SogError("snapshot ends before the end tag")
        (tag,) = struct.unpack_from("<H", body, offset)
        offset += 2
        if tag == 0:
            break
        if offset + 4 > len(body):
            raise SogError("extension header cut short")
        (length,) = struct.unpack_from("<I", body, offset)
        offset += 4
        if offset + length > len(body):
            raise SogError(f"extension 0x{tag:04X} claims {length} bytes")
        extensions.append((tag, bytes(body[offset:offset + length])))
        offset += length
    if offset != len(body):
        raise SogError(f"{len(body) - offset} bytes after the end tag")
    return SogSnapshot(header, nodes, pairs, extensions)


def encode_service_info(values: dict) -> bytes:
    """The block of tag TAG_SERVICE: run_start_unix_us, last_event_unix_us (us since the epoch),
    frames_delivered; the version is this build's."""
    return pack_fields(_SERVICE_INFO, dict(values, version=SERVICE_INFO_VERSION))


def decode_service_info(blob: bytes) -> dict:
    """The fields of a TAG_SERVICE block, as checkpoint_layout.h reads it: bytes after the block
    are ignored (a later version may append fields); another version is refused."""
    if len(blob) < SERVICE_INFO_SIZE:
        raise SogError(f"service block of {len(blob)} bytes, at least {SERVICE_INFO_SIZE}")
    values = unpack_fields(_SERVICE_INFO, blob[:SERVICE_INFO_SIZE])
    if values["version"] != SERVICE_INFO_VERSION:
        raise SogError(f"service block version {values['version']}, this build reads {SERVICE_INFO_VERSION}")
    return values
