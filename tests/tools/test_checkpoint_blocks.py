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
    for records in (layout.CHECKPOINT_ENGINE_RECORDS, layout.CHECKPOINT_MOVEMENT_RECORDS,
                    layout.CHECKPOINT_FLIGHT_RECORDS):
        for spec in records.values():
            seen = set()
            for field in spec["fields"]:
                if "list" in field:
                    assert field["list"] in records
                if "square_of" in field:
                    assert field["square_of"] in seen
                seen.add(field["name"])


def _flight_block():
    """Two tags, one of them tracking, six anchors taken, a body; doubles that are not round."""
    state = [0.1 * k + 1.0 / 3.0 for k in range(12)]
    covariance = [[(1.0 if i == j else 0.01) / (1 + i + j) for j in range(12)] for i in range(12)]
    return {"version": checkpoint.FLIGHT_VERSION,
            "flags": layout.CONSTANTS["CDRO_CHECKPOINT_FLIGHT_ANCHORS_SET"]
            | layout.CONSTANTS["CDRO_CHECKPOINT_FLIGHT_HAVE_TIME"],
            "t_s": 1_700_000_017.0123456,
            "nodes": [{"id": 10, "status": 2, "refused_in_a_row": 1, "heard": [1, 2, 3, 4]},
                      {"id": 20, "status": 1, "refused_in_a_row": 0, "heard": [2]}],
            "bodies": [{"a_id": 10, "b_id": 20, "separation_m": 0.45}],
            "anchors": [{"id": i, "x_m": 0.5 * i, "y_m": -0.25 * i, "z_m": 1.6 + i / 7.0, "taken": 10 * i,
                         "down_weighted": i, "refused": i % 2} for i in range(1, 7)],
            "tag_taken": 31, "tag_down_weighted": 2, "tag_refused": 1,
            "state": state, "covariance": covariance, "counters": list(range(10))}


def test_the_flight_block_round_trips_through_its_table():
    block = _flight_block()
    blob = checkpoint.encode_flight_block(block)
    assert blob[0] == checkpoint.FLIGHT_VERSION
    assert checkpoint.decode_flight_block(blob) == block  # doubles exactly, lists and rows as given
    assert checkpoint.encode_flight_block(checkpoint.decode_flight_block(blob)) == blob
    assert checkpoint.TAG_FLIGHT == 0x0003


def test_a_damaged_flight_block_is_refused_with_what_is_wrong():
    blob = checkpoint.encode_flight_block(_flight_block())
    with pytest.raises(SogError, match="the flight block is cut short in"):
        checkpoint.decode_flight_block(blob[:-1])
    with pytest.raises(SogError, match="the flight block has 1 bytes after its end"):
        checkpoint.decode_flight_block(blob + b"\x00")
    with pytest.raises(SogError, match=f"the flight block is of version {blob[0] + 1}"):
        checkpoint.decode_flight_block(bytes([blob[0] + 1]) + blob[1:])
    bad = _flight_block()
    bad["nodes"][0]["status"] = 3  # past the last FlightStatus
    with pytest.raises(SogError, match="FLIGHT_NODE.status is 3, outside 0..2"):
        checkpoint.decode_flight_block(checkpoint.encode_flight_block(bad))
    square = _flight_block()
    square["covariance"] = square["covariance"][:-1]
    with pytest.raises(ValueError, match="FLIGHT_BLOCK.covariance is not 12 by 12"):
        checkpoint.encode_flight_block(square)


def test_the_output_frame_block_round_trips_through_its_table():
    # A reflection and a turn of 30 degrees: doubles that are not round.
    c, s = 3.0 ** 0.5 / 2.0, 0.5
    block = {"version": checkpoint.OUTPUT_FRAME_VERSION, "rotation_xx": c, "rotation_xy": s,
             "rotation_yx": s, "rotation_yy": -c, "translation_x_m": 12.345678901, "translation_y_m": -0.1 / 3.0}
    blob = checkpoint.encode_output_frame_block(block)
    assert len(blob) == 1 + 6 * 8
    assert checkpoint.decode_output_frame_block(blob) == block
    assert checkpoint.TAG_OUTPUT_FRAME == 0x0004
    with pytest.raises(SogError, match="the output frame block is cut short in"):
        checkpoint.decode_output_frame_block(blob[:-1])
    with pytest.raises(SogError, match=f"the output frame block is of version {blob[0] + 1}"):
        checkpoint.decode_output_frame_block(bytes([blob[0] + 1]) + blob[1:])
