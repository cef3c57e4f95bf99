"""The Python decoder against tests/golden/bounds_cases.json, the edges of every value range of
frame_layout.def; tests/common/test_bounds.cpp holds the C decoder to the same table."""
import json
import subprocess
import sys

import pytest

from cdro_tools import codec


@pytest.fixture(scope="module")
def cases(golden_dir):
    return json.loads((golden_dir / "bounds_cases.json").read_text())["cases"]


def verdict(chunk_hex: str) -> tuple[str, codec.Frame | None]:
    try:
        frame = codec.decode_frame(bytes.fromhex(chunk_hex))
        codec.validate_frame(frame)
    except codec.FrameError as error:
        return str(error.result), error.frame
    return "ok", frame


def test_committed_table_is_up_to_date(golden_dir):
    generated = subprocess.run([sys.executable, str(golden_dir / "make_bounds_cases.py")],
                               check=True, capture_output=True, text=True).stdout
    assert (golden_dir / "bounds_cases.json").read_text() == generated, (
        "tests/golden/bounds_cases.json is stale (a range of frame_layout.def changed?): run "
        "`.venv/bin/python tests/golden/make_bounds_cases.py > tests/golden/bounds_cases.json`")


def test_every_edge_gets_its_verdict(cases):
    wrong = []
    for case in cases:
        result, frame = verdict(case["chunk"])
        if result != case["result"]:
            wrong.append(f"{case['name']}: {result}, expected {case['result']}")
        elif "fields" in case:
            assert frame is not None and frame.fields == case["fields"], case["name"]
    assert not wrong, "\n".join(wrong)


def test_the_stream_decoder_agrees(cases):
    decoder = codec.StreamDecoder()
    stream = b"".join(bytes.fromhex(case["chunk"]) + b"\x00" for case in cases)
    results = [str(event.result) for event in decoder.feed(stream)]
    assert results == [case["result"] for case in cases]

