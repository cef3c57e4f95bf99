"""The CDRO codec in Python: frames, capture files and SoG snapshots, generated from and tested
against common/ (tests/golden/vectors.json holds both implementations to the same bytes)."""
from .capture_file import (CaptureContents, CaptureError, CaptureHeader, CaptureRecord, CaptureWriter,
                           parse_capture, read_capture)
from .checksums import crc16, crc32
from .cobs import CobsError, cobs_decode, cobs_encode
from .frames import (LAYOUT_HASH, PROTOCOL_VERSION, DecodeEvent, Frame, FrameError, Result, StreamDecoder,
                     decode_frame, encode_frame, validate_frame)
from .layout import CONSTANTS, FRAME_TYPES
from .sog import SogError, SogPair, SogSnapshot, decode_sog, encode_sog

__all__ = [
    "CONSTANTS", "FRAME_TYPES", "LAYOUT_HASH", "PROTOCOL_VERSION",
    "CaptureContents", "CaptureError", "CaptureHeader", "CaptureRecord", "CaptureWriter", "parse_capture",
    "read_capture", "crc16", "crc32", "CobsError", "cobs_decode", "cobs_encode", "DecodeEvent", "Frame",
    "FrameError", "Result", "StreamDecoder", "decode_frame", "encode_frame", "validate_frame", "SogError",
    "SogPair", "SogSnapshot", "decode_sog", "encode_sog",
]
