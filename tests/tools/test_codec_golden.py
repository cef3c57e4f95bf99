"""The Python codec against tests/golden/vectors.json (the C tests check the same file)."""
import json
import math
import random

import pytest

from cdro_tools import codec
from cdro_tools.codec import capture_file, cobs, fixed


@pytest.fixture(scope="module")
def vectors(golden_dir):
    return json.loads((golden_dir / "vectors.json").read_text())


def test_checksum_check_values(vectors):
    for v in vectors["checksums"]["crc16_ccitt_false"]:
        assert codec.crc16(v["ascii"].encode()) == v["crc"]
    for v in vectors["checksums"]["crc32_iso_hdlc"]:
        assert codec.crc32(v["ascii"].encode()) == v["crc"]
    assert codec.crc16(b"123456789") == 0x29B1


def test_crc_incremental_equals_one_shot():
    seed = 20261122
    print(f"seed {seed}")
    rng = random.Random(seed)
    for _ in range(100):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(300)))
        crc16, crc32, offset = codec.checksums.CRC16_INIT, 0, 0
        while offset < len(data):
            step = rng.randrange(17)
            crc16 = codec.crc16(data[offset:offset + step], crc16)
            crc32 = codec.crc32(data[offset:offset + step], crc32)
            offset += step
        assert crc16 == codec.crc16(data)
        assert crc32 == codec.crc32(data)


def test_cobs_golden(vectors):
    for v in vectors["cobs"]:
        decoded, encoded = bytes.fromhex(v["decoded"]), bytes.fromhex(v["encoded"])
        assert cobs.cobs_encode(decoded) == encoded, v["name"]
        assert cobs.cobs_decode(encoded) == decoded, v["name"]


def test_cobs_rejects_invalid():
    for bad in [b"", b"\x05\x01\x02", b"\x03\x00\x01", b"\x00"]:
        with pytest.raises(cobs.CobsError):
            cobs.cobs_decode(bad)


def test_frames_encode_and_decode_golden(vectors):
    for v in vectors["frames"]:
        frame = codec.Frame(v["type"], v["sequence"], v["fields"])
        assert codec.encode_frame(frame).hex() == v["bytes"], v["name"]
        decoded = codec.decode_frame(bytes.fromhex(v["bytes"])[:-1])
        assert (decoded.type, decoded.sequence, decoded.fields) == (v["type"], v["sequence"], v["fields"]), v["name"]
        codec.validate_frame(decoded)


def test_rejections_golden(vectors):
    for v in vectors["decode_errors"]:
        with pytest.raises(codec.FrameError) as caught:
            codec.validate_frame(codec.decode_frame(bytes.fromhex(v["chunk"])))
        assert str(caught.value.result) == v["result"], v["name"]
        if "type" in v:
            frame = caught.value.frame
            assert (frame.version, frame.type_id, frame.sequence) == (v["version"], v["type"], v["sequence"]), v["name"]


def test_stream_golden(vectors):
    decoder = codec.StreamDecoder()
    data = bytes.fromhex(vectors["stream"]["bytes"])
    results = [str(e.result) for e in decoder.feed(data)]
    assert results == vectors["stream"]["results"]
    assert decoder.counters == vectors["stream"]["counters"]


def test_stream_byte_at_a_time_equals_one_shot(vectors):
    data = bytes.fromhex(vectors["stream"]["bytes"])
    decoder = codec.StreamDecoder()
    results = [str(e.result) for i in range(len(data)) for e in decoder.feed(data[i:i + 1])]
    assert results == vectors["stream"]["results"]
    assert decoder.counters == vectors["stream"]["counters"]


def test_capture_golden(vectors):
    v = vectors["capture"]
    header = codec.CaptureHeader(v["header"]["created_unix_us"], v["header"]["source"])
    records = [codec.CaptureRecord(r["host_time_us"], bytes.fromhex(r["data"]), r["flags"]) for r in v["records"]]
    blob = capture_file.encode_header(header) + b"".join(capture_file.encode_record(r) for r in records)
    assert blob.hex() == v["bytes"]
    contents = codec.parse_capture(blob)
    assert contents.header == header
    assert contents.records == records
    assert (contents.corrupt_bytes, contents.truncated_tail_bytes) == (0, 0)
    cut = codec.parse_capture(bytes.fromhex(v["cut_short"]["bytes"]))
    assert len(cut.records) == v["cut_short"]["records"]
    assert cut.truncated_tail_bytes == v["cut_short"]["truncated_tail_bytes"]
    corrupt = codec.parse_capture(bytes.fromhex(v["corrupt_middle"]["bytes"]))
    assert len(corrupt.records) == v["corrupt_middle"]["records"]
    assert corrupt.corrupt_bytes == v["corrupt_middle"]["corrupt_bytes"]


def test_capture_golden_odometry_record(vectors):
    v = vectors["capture"]
    contents = codec.parse_capture(bytes.fromhex(v["bytes"]))
    assert contents.header.format_version == v["header"]["format_version"] == capture_file.FORMAT_VERSION == 3
    index = v["odometry"]["record"]
    record = contents.records[index]
    assert record.odometry and not record.device and not record.to_device
    assert record.odometry_message() == v["odometry"]["message"]
    assert [r.odometry for r in contents.records].count(True) == 1
    event = contents.records[v["host_event"]["record"]]
    assert event.host_event and not event.device and not event.odometry
    assert event.data.hex() == v["host_event"]["data"]
    assert [r.host_event for r in contents.records].count(True) == 1
    assert [i for i, r in enumerate(contents.records) if r.device] == [0, 3, 5]
    with pytest.raises(ValueError):
        contents.records[0].odometry_message()


@pytest.mark.parametrize("name, version", [("capture_v1", 1), ("capture_v2", 2)])
def test_capture_older_versions_still_read_and_encode(vectors, name, version):
    v = vectors[name]
    contents = codec.parse_capture(bytes.fromhex(v["bytes"]))
    assert contents.header.format_version == version
    assert [(r.host_time_us, r.flags, r.data.hex()) for r in contents.records] == [
        (r["host_time_us"], r["flags"], r["data"]) for r in v["records"]]
    assert not any(r.host_event for r in contents.records)
    assert any(r.odometry for r in contents.records) == (version == 2)
    header = codec.CaptureHeader(v["header"]["created_unix_us"], v["header"]["source"], format_version=version)
    blob = capture_file.encode_header(header) + b"".join(capture_file.encode_record(r) for r in contents.records)
    assert blob.hex() == v["bytes"]


def test_capture_header_with_a_context_reads_and_encodes(vectors):
    v = vectors["capture_context"]
    contents = codec.parse_capture(bytes.fromhex(v["bytes"]))
    assert contents.header.context.hex() == v["header"]["context"]
    assert contents.header.format_version == v["header"]["format_version"]
    assert [(r.host_time_us, r.flags, r.data.hex()) for r in contents.records] == [
        (r["host_time_us"], r["flags"], r["data"]) for r in v["records"]]
    header = codec.CaptureHeader(v["header"]["created_unix_us"], v["header"]["source"],
                                 context=bytes.fromhex(v["header"]["context"]))
    assert len(capture_file.encode_header(header)) == v["header"]["size"]
    blob = capture_file.encode_header(header) + b"".join(capture_file.encode_record(r) for r in contents.records)
    assert blob.hex() == v["bytes"]


def test_capture_refuses_newer_versions(vectors):
    data = bytearray.fromhex(vectors["capture"]["bytes"])
    data[8] = capture_file.FORMAT_VERSION + 1
    with pytest.raises(codec.CaptureError, match=f"version {capture_file.FORMAT_VERSION + 1}"):
        codec.parse_capture(bytes(data))
    with pytest.raises(ValueError):
        capture_file.encode_header(codec.CaptureHeader(0, "x", format_version=capture_file.FORMAT_VERSION + 1))


def test_capture_writer_writes_what_the_reader_reads(tmp_path, vectors):
    path = tmp_path / "run.cdrocap"
    frames = [bytes.fromhex(v["bytes"])[:-1] for v in vectors["frames"]]
    with codec.CaptureWriter(path, "test", created_unix_us=1) as writer:
        for i, chunk in enumerate(frames):
            writer.write(codec.CaptureRecord(1000 + i, chunk))
        writer.write(codec.CaptureRecord(5000, b"\x55" * 5000))
    contents = codec.read_capture(path)
    assert [r.data for r in contents.records[:-1]] == frames
    assert contents.records[-1].truncated and len(contents.records[-1].data) == capture_file.MAX_DATA


def test_capture_rejects_foreign_files():
    with pytest.raises(codec.CaptureError):
        codec.parse_capture(b"PK\x03\x04 not a capture")


def test_sog_golden(vectors):
    v = vectors["sog"]
    snapshot = codec.SogSnapshot(v["header"], v["nodes"],
                                 [codec.SogPair(p["fields"], p["components"]) for p in v["pairs"]],
                                 [(e["tag"], bytes.fromhex(e["data"])) for e in v["extensions"]])
    blob = codec.encode_sog(snapshot)
    assert blob.hex() == v["bytes"]
    back = codec.decode_sog(blob)
    assert back.nodes == v["nodes"]
    assert [(p.fields, p.components) for p in back.pairs] == [(p["fields"], p["components"]) for p in v["pairs"]]
    assert back.extensions == snapshot.extensions
    with pytest.raises(codec.SogError):
        codec.decode_sog(blob[:-1])
    corrupt = bytearray(blob)
    corrupt[40] ^= 4
    with pytest.raises(codec.SogError):
        codec.decode_sog(bytes(corrupt))


def test_fixed_golden(vectors):
    v = vectors["fixed"]
    for name, function in [("mm_from_m", fixed.mm_from_m), ("um_from_m", fixed.um_from_m),
                           ("q15_from", fixed.q15_from), ("q16_from", fixed.q16_from)]:
        for case in v[name]:
            assert function(float(case["in"])) == case["out"], (name, case)
    for case in v["covariance_from"]:
        assert list(fixed.covariance_from(*case["in"])) == case["out"]


def test_fixed_bounds():
    for i in range(2000):
        metres = -1000 + i * 0.9973
        assert abs(fixed.mm_to_m(fixed.mm_from_m(metres)) - metres) <= 0.0005 + 1e-12
    assert fixed.mm_from_m(math.nan) == 0
