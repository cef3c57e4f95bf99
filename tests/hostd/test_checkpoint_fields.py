"""A checkpoint cdro-hostd writes, read by the Python codec from checkpoint_layout.def's tables:
the engine and movement blocks decode into named fields that agree with what the same run wrote
elsewhere (the SoG records of the checkpoint, the JSON lines), and encode to the same bytes.
Timeouts are deadlock guards only."""
from __future__ import annotations

import json
import subprocess

import pytest

from cdro_tools.codec import checkpoint
from cdro_tools.codec.sog import decode_sog
from robot_capture import ROBOT, write_robot_capture

GUARD_S = 300.0
CONVERGED = 2  # ENGINE_NODE.lifecycle
MOVING = 3


@pytest.fixture(scope="module")
def run(build_dir, tmp_path_factory):
    """plaza-like with its robot, replayed to the end: (the checkpoint's bytes, the JSON lines)."""
    folder = tmp_path_factory.mktemp("checkpoint")
    capture, _ = write_robot_capture(folder, GUARD_S)
    path, lines = folder / "final.cdrosog", folder / "lines.jsonl"
    result = subprocess.run([str(build_dir / "bin" / "cdro-hostd"), "--replay", str(capture), "--speed", "max",
                             "--set", f"movement.robot_id={ROBOT:#06x}", "--jsonl", str(lines),
                             "--checkpoint", str(path)], capture_output=True, text=True, timeout=GUARD_S)
    assert result.returncode == 0, result.stderr
    return path.read_bytes(), [json.loads(line) for line in lines.read_text().splitlines() if line.strip()]


def test_the_engine_block_names_the_nodes_and_links_the_run_wrote(run):
    data, lines = run
    snapshot = decode_sog(data)
    engine, movement = checkpoint.engine_blocks(snapshot)
    assert [node["id"] for node in engine["nodes"]] == [node["id"] for node in snapshot.nodes]
    assert len(engine["ring_update_counts"]) == len(snapshot.pairs)
    assert engine["counters"][0] == snapshot.header["ranges_processed"]  # ranges_received, the first counter
    for exact, rounded in zip(engine["nodes"], snapshot.nodes):  # the SOG_NODE is the same estimate, in mm
        assert abs(exact["x_m"] * 1000.0 - rounded["x_mm"]) <= 0.5 + 1e-9
        assert abs(exact["y_m"] * 1000.0 - rounded["y_mm"]) <= 0.5 + 1e-9
    ids = {node["id"] for node in engine["nodes"]}
    assert engine["links"] and all(link["a_id"] in ids and link["b_id"] in ids for link in engine["links"])
    assert len({(link["a_id"], link["b_id"]) for link in engine["links"]}) == len(engine["links"])
    last = {line["id"]: line for line in lines if line["type"] == "node"}
    assert set(last) <= ids
    for node in engine["nodes"]:
        if node["id"] in last:
            assert (node["lifecycle"] == CONVERGED) == (last[node["id"]]["status"] == "converged"), node["id"]
            assert (node["lifecycle"] == MOVING) == last[node["id"]]["moving"], node["id"]
    assert checkpoint.encode_engine_block(engine) == dict(snapshot.extensions)[checkpoint.TAG_ENGINE]

    assert movement is not None and movement["robot_id"] == ROBOT
    assert any(line["type"] == "robot" and line["id"] == ROBOT for line in lines)
    assert movement["hypotheses"]
    for hypothesis in movement["hypotheses"]:
        assert set(hypothesis["node_ids"]) <= ids
        assert len(hypothesis["covariance"]) == len(hypothesis["state"])
    assert checkpoint.encode_movement_block(movement) == dict(snapshot.extensions)[checkpoint.TAG_MOVEMENT]
