"""The Python layout table is generated from common/'s .def files and must not drift."""
import json

from cdro_tools import codegen
from cdro_tools.codec import layout


def test_committed_layout_is_up_to_date(repo_root):
    expected = codegen.generate(repo_root / "common" / "include")
    committed = (repo_root / "tools" / "cdro_tools" / "codec" / "layout.py").read_text()
    assert committed == expected, ("tools/cdro_tools/codec/layout.py is stale: run "
                                   "`.venv/bin/python -m cdro_tools.codegen common/include > "
                                   "tools/cdro_tools/codec/layout.py`")


def test_layout_hashes_match_the_committed_constants():
    assert layout.FRAME_LAYOUT_HASH_COMPUTED == layout.CONSTANTS["CDRO_LAYOUT_HASH"]
    assert layout.SOG_LAYOUT_HASH_COMPUTED == layout.CONSTANTS["CDRO_SOG_LAYOUT_HASH"]


def test_each_version_has_exactly_one_layout(golden_dir):
    history = json.loads((golden_dir / "layout_history.json").read_text())
    frames = history["frames"][str(layout.CONSTANTS["CDRO_PROTOCOL_VERSION"])]
    sog = history["sog"][str(layout.CONSTANTS["CDRO_SOG_LAYOUT_VERSION"])]
    assert int(frames, 16) == layout.CONSTANTS["CDRO_LAYOUT_HASH"]
    assert int(sog, 16) == layout.CONSTANTS["CDRO_SOG_LAYOUT_HASH"]


def test_protocol_doc_tables_are_up_to_date(repo_root):
    doc = repo_root / "docs" / "protocol.md"
    text = doc.read_text()
    begin, end = text.index(codegen.DOC_BEGIN), text.index(codegen.DOC_END) + len(codegen.DOC_END)
    assert text[begin:end] == codegen.protocol_tables(repo_root / "common" / "include"), (
        "docs/protocol.md is stale: run "
        "`.venv/bin/python -m cdro_tools.codegen common/include --docs docs/protocol.md`")
