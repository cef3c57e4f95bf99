"""Capture files, the Python twin of common/include/cdro/capture.h (layout documented there
and in docs/protocol.md): a checked header, then self-delimiting checked records, one per
chunk received (or frame sent, or, from format version 2, odometry message accepted, or, from
version 3, host event of the estimator). A file cut short loses at most its last record. Files
of versions 1 and 2 read unchanged.

The fixed fields (CAPTURE_HEAD, CAPTURE_RECORD_HEAD) and the constants come from layout.py,
generated from common/include/cdro/capture_layout.def, the table the C codec expands."""
from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import struct
import time

from .checksums import crc16
from .frames import record_struct
from .layout import CAPTURE_RECORDS, CONSTANTS, STRINGS

MAGIC = STRINGS["CDRO_CAPTURE_MAGIC"].encode("ascii") + b"\x00"
FORMAT_VERSION = CONSTANTS["CDRO_CAPTURE_FORMAT_VERSION"]  # the newest version read and written; 1 is still read
LAYOUT_HASH = CONSTANTS["CDRO_CAPTURE_LAYOUT_HASH"]
HEADER_FIXED = CONSTANTS["CDRO_CAPTURE_HEADER_FIXED"]      # bytes: magic, CAPTURE_HEAD, CRC
MAX_SOURCE = CONSTANTS["CDRO_CAPTURE_MAX_SOURCE"]
MAX_CONTEXT = CONSTANTS["CDRO_CAPTURE_MAX_CONTEXT"]         # bytes of the header's context at most
RECORD_MARKER = CONSTANTS["CDRO_CAPTURE_RECORD_MARKER"]
RECORD_OVERHEAD = CONSTANTS["CDRO_CAPTURE_RECORD_OVERHEAD"]  # bytes: CAPTURE_RECORD_HEAD and the CRC
MAX_DATA = CONSTANTS["CDRO_CAPTURE_MAX_DATA"]
FLAG_TO_DEVICE = CONSTANTS["CDRO_CAPTURE_FLAG_TO_DEVICE"]
FLAG_TRUNCATED = CONSTANTS["CDRO_CAPTURE_FLAG_TRUNCATED"]
FLAG_ODOMETRY = CONSTANTS["CDRO_CAPTURE_FLAG_ODOMETRY"]  # version 2: the data is an odometry message (JSON)
FLAG_HOST_EVENT = CONSTANTS["CDRO_CAPTURE_FLAG_HOST_EVENT"]  # version 3: what the estimator did on its own timing

# Fields in table order: (format_version, header_size, created_unix_us, source_len) and
# (marker, flags, data_len, host_time_us); the names are checked below.
_HEAD = record_struct(CAPTURE_RECORDS["CAPTURE_HEAD"]["fields"])
_RECORD_HEAD = record_struct(CAPTURE_RECORDS["CAPTURE_RECORD_HEAD"]["fields"])
HEAD_SIZE = _HEAD.size
RECORD_HEAD_SIZE = _RECORD_HEAD.size
assert [f["name"] for f in CAPTURE_RECORDS["CAPTURE_HEAD"]["fields"]] == [
    "format_version", "header_size", "created_unix_us", "source_len"], "capture_layout.def: CAPTURE_HEAD changed"
assert [f["name"] for f in CAPTURE_RECORDS["CAPTURE_RECORD_HEAD"]["fields"]] == [
    "marker", "flags", "data_len", "host_time_us"], "capture_layout.def: CAPTURE_RECORD_HEAD changed"
assert len(MAGIC) + HEAD_SIZE + 2 == HEADER_FIXED and RECORD_HEAD_SIZE + 2 == RECORD_OVERHEAD, \
    "capture_layout.def: the stated sizes disagree with its records"


class CaptureError(ValueError):
    """Not a capture file, an unsupported version, or a corrupt header."""


@dataclasses.dataclass
class CaptureHeader:
    created_unix_us: int           # us since the Unix epoch
    source: str                    # e.g. "serial:/dev/ttyACM0@115200"
    format_version: int = FORMAT_VERSION
    context: bytes = b""           # the run's context (cdro-hostd: JSON); b"" = none. An addition
                                   # to the header's layout read by every version (capture.h)


@dataclasses.dataclass
class CaptureRecord:
    host_time_us: int              # us since the Unix epoch
    data: bytes                    # one chunk as on the wire, without the 0x00 delimiter
                                   # (with FLAG_ODOMETRY: the message as normalised JSON)
    flags: int = 0

    @property
    def to_device(self) -> bool:
        return bool(self.flags & FLAG_TO_DEVICE)

    @property
    def truncated(self) -> bool:
        return bool(self.flags & FLAG_TRUNCATED)

    @property
    def odometry(self) -> bool:
        """An odometry message the service accepted, not bytes of the serial link."""
        return bool(self.flags & FLAG_ODOMETRY)

    @property
    def host_event(self) -> bool:
        """Something the host's estimator did between two frames, which a replay repeats in place
        (cdro-hostd: b"S" and the ranges taken when the adopted solve started, u64 little endian)."""
        return bool(self.flags & FLAG_HOST_EVENT)

    @property
    def device(self) -> bool:
        """A chunk received from the device (not sent to it, not odometry, not a host event)."""
        return not self.flags & (FLAG_TO_DEVICE | FLAG_ODOMETRY | FLAG_HOST_EVENT)

    def odometry_message(self) -> dict:
        """The odometry record's message: {"t", "distance_m", "dheading_rad", "source"}."""
        if not self.odometry:
            raise ValueError("not an odometry record")
        return json.loads(self.data.decode("utf-8"))


def encode_header(header: CaptureHeader) -> bytes:
    """With header.format_version (an older one only for tests and converters)."""
    source = header.source.encode("utf-8")
    if len(source) > MAX_SOURCE:
        raise ValueError(f"source description is {len(source)} bytes, at most {MAX_SOURCE}")
    if not 1 <= header.format_version <= FORMAT_VERSION:
        raise ValueError(f"capture format version {header.format_version} is not 1..{FORMAT_VERSION}")
    if len(header.context) > MAX_CONTEXT:
        raise ValueError(f"context is {len(header.context)} bytes, at most {MAX_CONTEXT}")
    context = struct.pack("<H", len(header.context)) + header.context if header.context else b""
    head = _HEAD.pack(header.format_version, HEADER_FIXED + len(source) + len(context), header.created_unix_us,
                      len(source))
    body = MAGIC + head + source + context
    return body + struct.pack("<H", crc16(body))


def decode_header(data: bytes) -> tuple[CaptureHeader, int]:
    """Returns the header and its size in bytes."""
    if len(data) < len(MAGIC) or data[:len(MAGIC)] != MAGIC:
        raise CaptureError("not a CDRO capture file (bad magic)")
    if len(data) < HEADER_FIXED:
        raise CaptureError("file ends inside the header")
    version, size, created, source_len = _HEAD.unpack_from(data, len(MAGIC))
    if version == 0 or version > FORMAT_VERSION:
        raise CaptureError(f"capture format version {version}; this build reads up to {FORMAT_VERSION}")
    if size < HEADER_FIXED + source_len:
        raise CaptureError(f"inconsistent header size {size}")
    if len(data) < size:
        raise CaptureError("file ends inside the header")
    (received,) = struct.unpack_from("<H", data, size - 2)
    if crc16(data[:size - 2]) != received:
        raise CaptureError("corrupt header (CRC mismatch)")
    start = len(MAGIC) + HEAD_SIZE
    source = data[start:start + source_len].decode("utf-8", errors="replace")
    # Between the source and the CRC: the context, when the bytes hold one whole (else a layout
    # this build does not know: skipped, as every reader does).
    covered = HEADER_FIXED - 2 + source_len
    context = b""
    if size - 2 - covered >= 2:
        (context_len,) = struct.unpack_from("<H", data, covered)
        if 0 < context_len <= size - 2 - covered - 2:
            context = bytes(data[covered + 2:covered + 2 + context_len])
    return CaptureHeader(created, source, version, context), size


def encode_record(record: CaptureRecord) -> bytes:
    if len(record.data) > MAX_DATA:
        raise ValueError(f"record data is {len(record.data)} bytes, at most {MAX_DATA}")
    body = _RECORD_HEAD.pack(RECORD_MARKER, record.flags, len(record.data), record.host_time_us) + record.data
    return body + struct.pack("<H", crc16(body))


def _decode_record_at(data: bytes, offset: int) -> tuple[CaptureRecord, int] | None:
    """The record at data[offset] if it is complete and checks out, else None."""
    if len(data) - offset < RECORD_OVERHEAD or data[offset] != RECORD_MARKER:
        return None
    _, flags, length, host_time = _RECORD_HEAD.unpack_from(data, offset)
    size = RECORD_OVERHEAD + length
    if length > MAX_DATA or offset + size > len(data):
        return None
    (received,) = struct.unpack_from("<H", data, offset + size - 2)
    if crc16(data[offset:offset + size - 2]) != received:
        return None
    return CaptureRecord(host_time, bytes(data[offset + RECORD_HEAD_SIZE:offset + size - 2]), flags), size


@dataclasses.dataclass
class CaptureContents:
    header: CaptureHeader
    records: list[CaptureRecord]
    corrupt_bytes: int = 0         # bytes skipped between good records
    truncated_tail_bytes: int = 0  # bytes after the last good record (a cut-short last record)


def parse_capture(data: bytes) -> CaptureContents:
    """The reading policy of cdro_capture_next_record: skip corrupt bytes to the next good record."""
    header, offset = decode_header(data)
    contents = CaptureContents(header, [])
    while offset < len(data):
        start = offset
        found = None
        while offset < len(data):
            found = _decode_record_at(data, offset)
            if found:
                break
            offset = data.find(bytes([RECORD_MARKER]), offset + 1)
            if offset < 0:
                offset = len(data)
        if not found:
            contents.truncated_tail_bytes = len(data) - start
            break
        contents.corrupt_bytes += offset - start
        record, size = found
        contents.records.append(record)
        offset += size
    return contents


def read_capture(path: str | os.PathLike) -> CaptureContents:
    return parse_capture(pathlib.Path(path).read_bytes())


class CaptureWriter:
    """Appends records with one os.write() each, so a kill -9 loses at most the last record."""

    def __init__(self, path: str | os.PathLike, source: str, created_unix_us: int | None = None):
        self.path = pathlib.Path(path)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        created = created_unix_us if created_unix_us is not None else time.time_ns() // 1000
        self.bytes_written = 0
        self.records_written = 0
        self._write(encode_header(CaptureHeader(created, source)))

    def _write(self, blob: bytes) -> None:
        view = memoryview(blob)
        while view:
            written = os.write(self._fd, view)
            view = view[written:]
        self.bytes_written += len(blob)

    def write(self, record: CaptureRecord) -> None:
        """Writes one record; data longer than MAX_DATA is cut and flagged truncated."""
        if len(record.data) > MAX_DATA:
            record = CaptureRecord(record.host_time_us, record.data[:MAX_DATA], record.flags | FLAG_TRUNCATED)
        self._write(encode_record(record))
        self.records_written += 1

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> "CaptureWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
