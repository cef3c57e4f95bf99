"""Writes tests/golden/vectors.json: the golden vectors that the C tests (tests/common) and the
Python tests (tests/tools) both check, field by field and byte by byte.

Run it only after a deliberate layout change (with a new protocol version):
    .venv/bin/python tests/golden/make_vectors.py > tests/golden/vectors.json
The checksum and COBS vectors are external facts (the CRC catalogue's check values and the
COBS examples of the Wikipedia article) and are written here by hand, not computed.
"""
from __future__ import annotations

import json
import pathlib
import struct
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "tools"))

from cdro_tools.codec import (CaptureHeader, CaptureRecord, Frame, SogPair, SogSnapshot,  # noqa: E402
                              FrameError, StreamDecoder, crc16, decode_frame, encode_frame, encode_sog,
                              validate_frame)
from cdro_tools.codec import capture_file, cobs  # noqa: E402
from cdro_tools.codec import fixed  # noqa: E402
from cdro_tools.codec import CONSTANTS as C  # noqa: E402

C_MAX_NODES = 20
V = C["CDRO_PROTOCOL_VERSION"]   # the version every good vector carries


def hexs(data: bytes) -> str:
    return data.hex()


def checksum_vectors() -> dict:
    return {
        "crc16_ccitt_false": [
            {"ascii": "123456789", "crc": 0x29B1},
            {"ascii": "", "crc": 0xFFFF},
        ],
        "crc32_iso_hdlc": [
            {"ascii": "123456789", "crc": 0xCBF43926},
            {"ascii": "", "crc": 0x00000000},
        ],
    }


def cobs_vectors() -> list[dict]:
    ramp_254 = bytes(range(1, 255))          # 01..FE, 254 non-zero bytes
    ramp_255 = bytes(range(1, 256))          # 01..FF
    vectors = [
        ("empty", b"", b"\x01"),
        ("one zero", b"\x00", b"\x01\x01"),
        ("two zeros", b"\x00\x00", b"\x01\x01\x01"),
        ("zero in the middle", b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        ("no zeros", b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
        ("trailing zeros", b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
        ("254 non-zero bytes", ramp_254, b"\xff" + ramp_254),
        ("zero then 254 non-zero", b"\x00" + ramp_254, b"\x01\xff" + ramp_254),
        ("255 non-zero bytes", ramp_255, b"\xff" + ramp_254 + b"\x02\xff"),
        ("254 non-zero then zero", ramp_254 + b"\x00", b"\xff" + ramp_254 + b"\x01\x01"),
        ("all zeros (8)", bytes(8), b"\x01" * 9),
    ]
    for name, decoded, encoded in vectors:
        assert cobs.cobs_encode(decoded) == encoded, name  # the Python codec agrees with the facts
    return [{"name": n, "decoded": hexs(d), "encoded": hexs(e)} for n, d, e in vectors]


FRAMES = [
    ("hello", Frame("HELLO", 0, {"device_time_ms": 1234, "firmware_version": 0x0102, "protocol_version": V,
                                 "layout_hash": C["CDRO_LAYOUT_HASH"], "node_id": 0x6069, "capabilities": 0x3F,
                                 "pozyx_firmware": 0x12, "max_nodes": 12, "reset_cause": 0x01, "pozyx_tries": 3})),
    ("range direct", Frame("RANGE", 7, {"device_time_ms": 50123, "from_id": 0x6069, "to_id": 0x6A11,
                                        "distance_mm": 4235, "rss_dbm": -79, "flags": 0})),
    ("range remote, retry, extremes", Frame("RANGE", 0xFFFF, {"device_time_ms": 0xFFFFFFFF, "from_id": 0xFFFE,
                                                             "to_id": 1, "distance_mm": 200000,
                                                             "rss_dbm": -32768, "flags": 0x03})),
    ("motion moving", Frame("MOTION", 300, {"device_time_ms": 987654, "node_id": 0x6A11, "moving": 1,
                                            "accel_norm_mg": 1187, "deviation_mg": 164, "reason": 0})),
    ("status", Frame("STATUS", 42, {"uptime_ms": 3600000, "ranges_ok_direct": 100000, "ranges_ok_remote": 54321,
                                    "ranges_failed_direct": 17, "ranges_failed_remote": 230, "retries": 198,
                                    "bus_errors": 2, "timeouts": 31, "frames_sent": 160000, "frames_dropped": 5,
                                    "commands_rejected": 1, "longest_loop_us": 61234, "free_ram_bytes": 412,
                                    "running": 1, "node_count": 6, "bus_recoveries": 2})),
    ("node list empty", Frame("NODE_LIST", 3, {"source": 0, "node_ids": []})),
    ("node list full", Frame("NODE_LIST", 4, {"source": 1, "node_ids": [0x6000 + i for i in range(C_MAX_NODES)]})),
    ("ack ping", Frame("ACK", 9, {"acked_type": 0x45, "acked_sequence": 77, "value": 0xDEADBEEF})),
    ("nack", Frame("NACK", 10, {"nacked_type": 0x42, "nacked_sequence": 78, "reason": 2})),
    ("error", Frame("ERROR", 11, {"device_time_ms": 5000, "code": 5, "detail": 0x11, "node_id": 0x6A11})),
    ("set nodes", Frame("SET_NODES", 1, {"node_ids": [0x6069, 0x6A11, 0x6A22]})),
    ("set schedule", Frame("SET_SCHEDULE", 2, {"slot_period_ms": 25, "mode": 1, "motion_poll_ms": 200,
                                               "moving_boost": 3, "status_period_ms": 1000, "max_retries": 2})),
    ("start", Frame("START", 3)),
    ("stop", Frame("STOP", 4)),
    ("ping", Frame("PING", 5, {"nonce": 0xDEADBEEF})),
    ("hello request", Frame("HELLO_REQUEST", 6)),
    ("sequence zero bytes", Frame("RANGE", 0x0100, {"device_time_ms": 0, "from_id": 0x0100, "to_id": 0x0200,
                                                   "distance_mm": 0, "rss_dbm": 0, "flags": 0})),
    ("node info", Frame("NODE_INFO", 12, {"node_id": 0x6A11, "result": 0, "pozyx_firmware": 0x11, "uwb_channel": 5,
                                          "uwb_rates": 0x80, "uwb_plen": 0x08, "uwb_gain": 23, "range_protocol": 1,
                                          "mismatch": 0x10})),
    ("diag", Frame("DIAG", 13, {"item": 2, "status": 0, "node_id": 0x6A11, "value_a": 4, "value_b": 8123,
                                "value_c": 0xFFFFFFFF})),
    ("set uwb", Frame("SET_UWB", 7, {"uwb_channel": 2, "uwb_rates": 0x42, "uwb_plen": 0x34, "uwb_gain": 67,
                                     "range_protocol": 0})),
    ("diagnose", Frame("DIAGNOSE", 8)),
]


def raw_frame(version: int, type_id: int, sequence: int, payload: bytes, length: int | None = None,
              crc_ok: bool = True) -> bytes:
    """A hand-built raw frame, for the decoder's rejection vectors."""
    body = struct.pack("<BBHB", version, type_id, sequence, len(payload) if length is None else length) + payload
    crc = crc16(body) ^ (0 if crc_ok else 0x0001)
    return body + struct.pack("<H", crc)


def python_result(chunk_hex: str) -> str:
    """What the Python decoder says of a chunk (checked against each declared result)."""
    try:
        validate_frame(decode_frame(bytes.fromhex(chunk_hex)))
    except FrameError as error:
        return str(error.result)
    return "ok"


def decode_error_vectors() -> list[dict]:
    good = encode_frame(FRAMES[1][1])[:-1]     # the "range direct" chunk
    flipped = bytearray(good)
    flipped[6] ^= 0x10
    range_payload = struct.pack("<IHHIhB", 1, 0x10, 0x10, 1000, -50, 0)   # from == to
    too_far = struct.pack("<IHHIhB", 1, 0x10, 0x11, 200001, -50, 0)
    vectors = [
        {"name": "code byte runs past the end", "chunk": "050102", "result": "cobs"},
        {"name": "shorter than header and CRC", "chunk": hexs(cobs.cobs_encode(b"\x01\x02\x03")), "result": "short"},
        {"name": "one bit flipped", "chunk": hexs(bytes(flipped)), "result": "crc"},
        {"name": "wrong CRC", "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x43, 1, b"", crc_ok=False))),
         "result": "crc"},
        {"name": f"protocol version {V - 1} (the layout before)",
         "chunk": hexs(cobs.cobs_encode(raw_frame(V - 1, 0x43, 1, b""))),
         "result": "version", "version": V - 1, "type": 0x43, "sequence": 1},
        {"name": "set uwb on channel 6",
         "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x47, 7, bytes([6, 0x80, 0x08, 20, 0])))),
         "result": "value", "version": V, "type": 0x47, "sequence": 7},
        {"name": "unknown type 0x7E", "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x7E, 513, b"\x01"))),
         "result": "type", "version": V, "type": 0x7E, "sequence": 513},
        {"name": "length field disagrees",
         "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x45, 2, b"\x01\x02\x03\x04", 5))),
         "result": "length", "version": V, "type": 0x45, "sequence": 2},
        {"name": "payload too short for PING", "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x45, 2, b"\x01\x02\x03"))),
         "result": "length", "version": V, "type": 0x45, "sequence": 2},
        {"name": "payload on START", "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x43, 2, b"\x00"))),
         "result": "length", "version": V, "type": 0x43, "sequence": 2},
        {"name": "array count above maximum",
         "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x41, 3, bytes([21]) + bytes(range(1, 43))))),
         "result": "length", "version": V, "type": 0x41, "sequence": 3},
        {"name": "array count beyond the bytes",
         "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x41, 3, bytes([3, 1, 0, 2, 0])))),
         "result": "length", "version": V, "type": 0x41, "sequence": 3},
        {"name": "too long without delimiter", "chunk": "11" * 73, "result": "too_long"},
        {"name": "range to itself", "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x02, 4, range_payload))),
         "result": "value", "version": V, "type": 0x02, "sequence": 4},
        {"name": "range beyond 200 m", "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x02, 4, too_far))),
         "result": "value", "version": V, "type": 0x02, "sequence": 4},
        {"name": "set nodes with a duplicate",
         "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x41, 5, bytes([2, 7, 0, 7, 0])))),
         "result": "value", "version": V, "type": 0x41, "sequence": 5},
        {"name": "schedule boost 0",
         "chunk": hexs(cobs.cobs_encode(raw_frame(V, 0x42, 6, struct.pack("<HBHBHB", 25, 1, 200, 0, 1000, 2)))),
         "result": "value", "version": V, "type": 0x42, "sequence": 6},
    ]
    for vector in vectors:
        assert python_result(vector["chunk"]) == vector["result"], vector["name"]
    return vectors


def stream_vector() -> dict:
    """Garbage, frames cut in half, repeated delimiters and an overlong run, in one byte stream."""
    frames = [encode_frame(f) for _, f in FRAMES[:5]]
    stream = bytearray()
    stream += b"\x00\x00"                      # leading delimiters: ignored
    stream += b"\x13\x37\xfe"                  # garbage before the first delimiter
    stream += b"\x00"
    stream += frames[0]
    stream += frames[1][:7]                    # a frame cut in half ...
    stream += frames[2]                        # ... runs into the next one
    stream += bytes([0x42] * 200) + b"\x00"    # an overlong run
    stream += frames[3]
    flipped = bytearray(frames[4])
    flipped[10] ^= 0x01
    stream += flipped
    stream += frames[4]
    stream += frames[1][:5]                    # a tail that never ends
    decoder = StreamDecoder()
    results = [str(event.result) for event in decoder.feed(bytes(stream))]
    return {"bytes": hexs(bytes(stream)), "results": results, "counters": decoder.counters}


# An odometry record's data as cdro-hostd writes it (host/service/src/odometry_intake.cpp,
# normaliseOdometry): compact JSON, keys in this order, shortest round-trip numbers.
ODOMETRY_RECORD = b'{"t":1795046400.225,"distance_m":0.012,"dheading_rad":-0.001,"source":"udp:127.0.0.1:40000"}'


# A host event as cdro-hostd writes it (host/hostd/src/engine_adapter.cpp): a global solve adopted
# between frames, "S" and the engine's ranges taken when that solve started (u64, little endian).
HOST_EVENT_RECORD = b"S" + (1234).to_bytes(8, "little")


def capture_vector() -> dict:
    """Format version 3: device chunks, a host frame, an odometry record, a host event."""
    header = CaptureHeader(created_unix_us=1795046400123456, source="serial:/dev/ttyACM0@115200")
    records = [
        CaptureRecord(1795046400200000, encode_frame(FRAMES[0][1])[:-1]),
        CaptureRecord(1795046400210000, encode_frame(FRAMES[11][1])[:-1], capture_file.FLAG_TO_DEVICE),
        CaptureRecord(1795046400230000, ODOMETRY_RECORD, capture_file.FLAG_ODOMETRY),
        CaptureRecord(1795046400250000, b"\x13\x37"),
        CaptureRecord(1795046400250000, HOST_EVENT_RECORD, capture_file.FLAG_HOST_EVENT),
        CaptureRecord(1795046400260000, b"", 0),
    ]
    blob = capture_file.encode_header(header) + b"".join(capture_file.encode_record(r) for r in records)
    first_record = len(capture_file.encode_header(header))
    second_record = first_record + len(capture_file.encode_record(records[0]))
    corrupt = bytearray(blob)
    corrupt[second_record + 5] ^= 0xFF       # damage the second record's time field
    return {
        "header": {"created_unix_us": header.created_unix_us, "source": header.source,
                   "format_version": capture_file.FORMAT_VERSION},
        "records": [{"host_time_us": r.host_time_us, "flags": r.flags, "data": hexs(r.data)} for r in records],
        "odometry": {"record": 2, "message": {"t": 1795046400.225, "distance_m": 0.012, "dheading_rad": -0.001,
                                              "source": "udp:127.0.0.1:40000"}},
        "host_event": {"record": 4, "data": hexs(HOST_EVENT_RECORD)},
        "bytes": hexs(blob),
        "cut_short": {"bytes": hexs(blob[:-3]), "records": len(records) - 1, "truncated_tail_bytes": 11},
        "corrupt_middle": {"bytes": hexs(bytes(corrupt)), "records": len(records) - 1,
                           "corrupt_bytes": len(capture_file.encode_record(records[1]))},
    }


def capture_v1_vector() -> dict:
    """A format-version-1 file (before odometry records): every reader must still read it."""
    header = CaptureHeader(created_unix_us=1795046400123456, source="serial:/dev/ttyACM0@115200", format_version=1)
    records = [
        CaptureRecord(1795046400200000, encode_frame(FRAMES[0][1])[:-1]),
        CaptureRecord(1795046400210000, encode_frame(FRAMES[11][1])[:-1], capture_file.FLAG_TO_DEVICE),
        CaptureRecord(1795046400250000, b"\x13\x37"),
        CaptureRecord(1795046400260000, b"", 0),
    ]
    blob = capture_file.encode_header(header) + b"".join(capture_file.encode_record(r) for r in records)
    return {
        "header": {"created_unix_us": header.created_unix_us, "source": header.source, "format_version": 1},
        "records": [{"host_time_us": r.host_time_us, "flags": r.flags, "data": hexs(r.data)} for r in records],
        "bytes": hexs(blob),
    }


def capture_v2_vector() -> dict:
    """A format-version-2 file (odometry, before host events): every reader must still read it."""
    header = CaptureHeader(created_unix_us=1795046400123456, source="serial:/dev/ttyACM0@115200", format_version=2)
    records = [
        CaptureRecord(1795046400200000, encode_frame(FRAMES[0][1])[:-1]),
        CaptureRecord(1795046400230000, ODOMETRY_RECORD, capture_file.FLAG_ODOMETRY),
        CaptureRecord(1795046400250000, b"\x13\x37"),
    ]
    blob = capture_file.encode_header(header) + b"".join(capture_file.encode_record(r) for r in records)
    return {
        "header": {"created_unix_us": header.created_unix_us, "source": header.source, "format_version": 2},
        "records": [{"host_time_us": r.host_time_us, "flags": r.flags, "data": hexs(r.data)} for r in records],
        "bytes": hexs(blob),
    }


def capture_context_vector() -> dict:
    """A header that carries the run's context (an addition to the header's layout, read by every
    version): cdro-hostd records there what the map depends on (docs/service.md)."""
    context = b'{"heights":[[24577,0.8]],"fixed":[],"settings":"engine:\\n  range: {}\\n"}'
    header = CaptureHeader(created_unix_us=1795046400123456, source="serial:/dev/ttyACM0@115200", context=context)
    records = [CaptureRecord(1795046400200000, encode_frame(FRAMES[0][1])[:-1])]
    blob = capture_file.encode_header(header) + b"".join(capture_file.encode_record(r) for r in records)
    return {
        "header": {"created_unix_us": header.created_unix_us, "source": header.source,
                   "format_version": capture_file.FORMAT_VERSION, "context": hexs(context),
                   "size": len(capture_file.encode_header(header))},
        "records": [{"host_time_us": r.host_time_us, "flags": r.flags, "data": hexs(r.data)} for r in records],
        "bytes": hexs(blob),
    }


def sog_vector() -> dict:
    snapshot = SogSnapshot(
        header={"created_unix_us": 1795046400123456, "ranges_processed": 1205, "flags": 0},
        nodes=[
            {"id": 1, "flags": 0x13, "x_mm": 0, "y_mm": 0, "z_mm": 4218, "std_x_um": 0, "std_y_um": 0,
             "correlation_q15": 0, "average_x_mm": 0, "average_y_mm": 0, "merge_count": 0},
            {"id": 9, "flags": 0x03, "x_mm": 8246, "y_mm": -1250, "z_mm": -2147483648, "std_x_um": 120000,
             "std_y_um": 4294967295, "correlation_q15": -32767, "average_x_mm": 8240, "average_y_mm": -1244,
             "merge_count": 65535},
        ],
        pairs=[SogPair({"center_id": 1, "target_id": 9, "last_range_mm": 8246, "range_count": 4},
                       [{"x_mm": 8246, "y_mm": 0, "std_x_um": 100000, "std_y_um": 300000, "correlation_q15": 0,
                         "weight_q16": 65535},
                        {"x_mm": -8246, "y_mm": 1, "std_x_um": 100000, "std_y_um": 300000,
                         "correlation_q15": 16384, "weight_q16": 0}])],
        extensions=[(0x0101, b"engine-state")],
    )
    blob = encode_sog(snapshot)
    return {"nodes": snapshot.nodes, "pairs": [{"fields": p.fields, "components": p.components}
                                                for p in snapshot.pairs],
            "header": {"created_unix_us": 1795046400123456, "ranges_processed": 1205, "flags": 0},
            "extensions": [{"tag": t, "data": hexs(d)} for t, d in snapshot.extensions],
            "bytes": hexs(blob)}


def fixed_vectors() -> dict:
    # Inputs are binary fractions so that the scaled value is exact and the rounding is tested.
    cases_mm = [0.0625, -0.0625, 1.0, -2.5e-4, 3000000.0, -3000000.0, float("nan")]
    cases_um = [0.0000005, 1.5e-6, -1.0, 5000.0]
    cases_q15 = [1.0, -1.0, 0.5, 2.0, -3.0, 0.25]
    cases_q16 = [1.0, 0.0, 0.5, -0.1, 1.7, 2 ** -17]
    return {
        "mm_from_m": [{"in": repr(v), "out": fixed.mm_from_m(v)} for v in cases_mm],
        "um_from_m": [{"in": repr(v), "out": fixed.um_from_m(v)} for v in cases_um],
        "q15_from": [{"in": repr(v), "out": fixed.q15_from(v)} for v in cases_q15],
        "q16_from": [{"in": repr(v), "out": fixed.q16_from(v)} for v in cases_q16],
        "covariance_from": [
            {"in": [4.0, 1.0, 1.0], "out": list(fixed.covariance_from(4.0, 1.0, 1.0))},
            {"in": [0.01, 0.0, 0.04], "out": list(fixed.covariance_from(0.01, 0.0, 0.04))},
            {"in": [-1.0, 0.5, 1.0], "out": list(fixed.covariance_from(-1.0, 0.5, 1.0))},
            {"in": [1.0, 2.0, 1.0], "out": list(fixed.covariance_from(1.0, 2.0, 1.0))},
        ],
    }


def main() -> None:
    vectors = {
        "about": "Golden vectors for the C and Python codecs; see tests/golden/make_vectors.py.",
        "checksums": checksum_vectors(),
        "cobs": cobs_vectors(),
        "frames": [{"name": n, "type": f.type, "sequence": f.sequence, "fields": f.fields,
                    "bytes": hexs(encode_frame(f))} for n, f in FRAMES],
        "decode_errors": decode_error_vectors(),
        "stream": stream_vector(),
        "capture": capture_vector(),
        "capture_v1": capture_v1_vector(),
        "capture_v2": capture_v2_vector(),
        "capture_context": capture_context_vector(),
        "sog": sog_vector(),
        "fixed": fixed_vectors(),
    }
    json.dump(vectors, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
