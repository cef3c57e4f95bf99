"""checkpoint_layout.def's engine and movement tables read the bytes cdro-hostd wrote by hand
before the tables existed, name their fields, and write the same bytes again."""
import json

import pytest

from cdro_tools.codec import checkpoint, layout
from cdro_tools.codec.sog import SogError


@pytest.fixture(scope="module")
def golden(golden_dir):
    return json.loads((golden_dir / "checkpoint_engine_blocks.json").read_text())


def test_the_golden_engine_block_decodes_into_its_named_fields_and_encodes_to_the_same_bytes(golden):
    vector = golden["engine"]
    assert vector["tag"] == checkpoint.TAG_ENGINE
    blob = bytes.fromhex(vector["bytes"])
    block = checkpoint.decode_engine_block(blob)
    assert block["version"] == checkpoint.ENGINE_VERSION
    assert [node["id"] for node in block["nodes"]] == vector["node_ids"]
    assert len(block["links"]) == vector["link_count"]
    assert len(block["ring_update_counts"]) == vector["ring_count"]
    assert len(block["counters"]) == vector["counter_count"]
    first = block["links"][0]
    assert {key: first[key] for key in vector["first_link"]} == vector["first_link"]
    assert block["nodes"][0]["x_m"] == vector["first_node_x_m"]  # doubles exactly, not rounded
    ids = set(vector["node_ids"])
    assert all(link["a_id"] in ids and link["b_id"] in ids for link in block["links"])
    assert checkpoint.encode_engine_block(block) == blob


def test_the_golden_movement_block_decodes_into_its_named_fields_and_encodes_to_the_same_bytes(golden):
    vector = golden["movement"]
    assert vector["tag"] == checkpoint.TAG_MOVEMENT
    blob = bytes.fromhex(vector["bytes"])
    block = checkpoint.decode_movement_block(blob)
    assert block["robot_id"] == vector["robot_id"]
    assert block["flags"] == vector["flags"]
    assert block["moved_m"] == vector["moved_m"]
    assert [len(h["state"]) for h in block["hypotheses"]] == vector["hypothesis_state_sizes"]
    for hypothesis in block["hypotheses"]:
        size = len(hypothesis["state"])
        assert len(hypothesis["covariance"]) == size and all(len(row) == size for row in hypothesis["covariance"])
        assert all(hypothesis["covariance"][i][i] >= 0.0 for i in range(size))
    assert len(block["links"]) == vector["link_count"]
    assert block["revision"] == vector["revision"]
    assert len(block["counters"]) == vector["counter_count"]
    assert checkpoint.encode_movement_block(block) == blob


@pytest.mark.parametrize("which", ["engine", "movement"])
def test_a_damaged_block_is_refused_with_what_is_wrong(golden, which):
    decode = checkpoint.decode_engine_block if which == "engine" else checkpoint.decode_movement_block
    blob = bytes.fromhex(golden[which]["bytes"])
    with pytest.raises(SogError, match=f"the {which} block is cut short in"):
        decode(blob[:-1])
    with pytest.raises(SogError, match=f"the {which} block has 1 bytes after its end"):
        decode(blob + b"\x00")
    with pytest.raises(SogError, match=f"the {which} block is of version {blob[0] + 1}"):
        decode(bytes([blob[0] + 1]) + blob[1:])


def test_an_absurd_count_is_refused_before_it_is_read(golden):
    blob = bytearray.fromhex(golden["engine"]["bytes"])
    blob[8:12] = (checkpoint.MAX_COUNT + 1).to_bytes(4, "little")  # ENGINE_BLOCK.nodes' count
    with pytest.raises(SogError, match="ENGINE_BLOCK.nodes a count of"):
        checkpoint.decode_engine_block(bytes(blob))


def test_every_list_and_matrix_of_the_tables_names_what_it_repeats():
    for records in (layout.CHECKPOINT_ENGINE_RECORDS, layout.CHECKPOINT_MOVEMENT_RECORDS):
        for spec in records.values():
            seen = set()
            for field in spec["fields"]:
                if "list" in field:
                    assert field["list"] in records
                if "square_of" in field:
                    assert field["square_of"] in seen
                seen.add(field["name"])
