"""The Python layout table is generated from common/'s .def files and must not drift."""
import json

import pytest

from cdro_tools import codegen
from cdro_tools.codec import capture_file, layout, sog


def test_committed_layout_is_up_to_date(repo_root):
    expected = codegen.generate(repo_root / "common" / "include")
    committed = (repo_root / "tools" / "cdro_tools" / "codec" / "layout.py").read_text()
    assert committed == expected, ("tools/cdro_tools/codec/layout.py is stale: run "
                                   "`.venv/bin/python -m cdro_tools.codegen common/include > "
                                   "tools/cdro_tools/codec/layout.py`")


def test_layout_hashes_match_the_committed_constants():
    assert layout.FRAME_LAYOUT_HASH_COMPUTED == layout.CONSTANTS["CDRO_LAYOUT_HASH"]
    assert layout.SOG_LAYOUT_HASH_COMPUTED == layout.CONSTANTS["CDRO_SOG_LAYOUT_HASH"]
    assert layout.CAPTURE_LAYOUT_HASH_COMPUTED == layout.CONSTANTS["CDRO_CAPTURE_LAYOUT_HASH"]
    assert layout.CHECKPOINT_LAYOUT_HASH_COMPUTED == layout.CONSTANTS["CDRO_CHECKPOINT_LAYOUT_HASH"]
    assert layout.CHECKPOINT_ENGINE_LAYOUT_HASH_COMPUTED == layout.CONSTANTS["CDRO_CHECKPOINT_ENGINE_LAYOUT_HASH"]
    assert layout.CHECKPOINT_MOVEMENT_LAYOUT_HASH_COMPUTED == layout.CONSTANTS["CDRO_CHECKPOINT_MOVEMENT_LAYOUT_HASH"]
    assert layout.CHECKPOINT_FLIGHT_LAYOUT_HASH_COMPUTED == layout.CONSTANTS["CDRO_CHECKPOINT_FLIGHT_LAYOUT_HASH"]
    assert (layout.CHECKPOINT_OUTPUT_FRAME_LAYOUT_HASH_COMPUTED
            == layout.CONSTANTS["CDRO_CHECKPOINT_OUTPUT_FRAME_LAYOUT_HASH"])


def test_each_version_has_exactly_one_layout(golden_dir):
    history = json.loads((golden_dir / "layout_history.json").read_text())
    frames = history["frames"][str(layout.CONSTANTS["CDRO_PROTOCOL_VERSION"])]
    sog = history["sog"][str(layout.CONSTANTS["CDRO_SOG_LAYOUT_VERSION"])]
    assert int(frames, 16) == layout.CONSTANTS["CDRO_LAYOUT_HASH"]
    assert int(sog, 16) == layout.CONSTANTS["CDRO_SOG_LAYOUT_HASH"]
    capture = history["capture"][str(layout.CONSTANTS["CDRO_CAPTURE_FORMAT_VERSION"])]
    assert int(capture, 16) == layout.CONSTANTS["CDRO_CAPTURE_LAYOUT_HASH"]
    checkpoint = history["checkpoint"][str(layout.CONSTANTS["CDRO_CHECKPOINT_SERVICE_INFO_VERSION"])]
    assert int(checkpoint, 16) == layout.CONSTANTS["CDRO_CHECKPOINT_LAYOUT_HASH"]
    for block in ("engine", "movement", "flight", "output_frame"):
        version = str(layout.CONSTANTS[f"CDRO_CHECKPOINT_{block.upper()}_VERSION"])
        pinned = history[f"checkpoint_{block}"][version]
        assert int(pinned, 16) == layout.CONSTANTS[f"CDRO_CHECKPOINT_{block.upper()}_LAYOUT_HASH"], block


def test_protocol_doc_tables_are_up_to_date(repo_root):
    doc = repo_root / "docs" / "protocol.md"
    text = doc.read_text()
    begin, end = text.index(codegen.DOC_BEGIN), text.index(codegen.DOC_END) + len(codegen.DOC_END)
    assert text[begin:end] == codegen.protocol_tables(repo_root / "common" / "include"), (
        "docs/protocol.md is stale: run "
        "`.venv/bin/python -m cdro_tools.codegen common/include --docs docs/protocol.md`")


def test_capture_codec_takes_its_constants_from_the_table():
    """capture_file.py restates no constant of capture_layout.def: each is the table's."""
    assert capture_file.MAGIC == layout.STRINGS["CDRO_CAPTURE_MAGIC"].encode("ascii") + b"\x00"
    assert len(capture_file.MAGIC) == layout.CONSTANTS["CDRO_CAPTURE_MAGIC_SIZE"]
    for name in ("FORMAT_VERSION", "LAYOUT_HASH", "HEADER_FIXED", "MAX_SOURCE", "RECORD_MARKER", "RECORD_OVERHEAD",
                 "MAX_DATA", "FLAG_TO_DEVICE", "FLAG_TRUNCATED", "FLAG_ODOMETRY"):
        assert getattr(capture_file, name) == layout.CONSTANTS[f"CDRO_CAPTURE_{name}"], name


def test_checkpoint_service_block_matches_the_golden_bytes(golden_dir):
    """The same vector the C codec checks (tests/common/test_checkpoint_layout.cpp)."""
    vector = json.loads((golden_dir / "checkpoint_service_info.json").read_text())
    assert vector["tag"] == sog.TAG_SERVICE
    blob = bytes.fromhex(vector["bytes"])
    assert sog.encode_service_info(vector["fields"]) == blob
    assert sog.decode_service_info(blob + b"\xab") == dict(vector["fields"], version=sog.SERVICE_INFO_VERSION)
    with pytest.raises(sog.SogError):
        sog.decode_service_info(blob[:-1])
    with pytest.raises(sog.SogError):
        sog.decode_service_info(bytes([sog.SERVICE_INFO_VERSION + 1]) + blob[1:])
