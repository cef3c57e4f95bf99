"""The output frame's offset, where the two languages meet: a checkpoint that cdro-hostd wrote after
a node of the frame triangle started moving holds the output frame block (docs/protocol.md, tag 4),
and the Python codec reads it and writes the same bytes, as a user's tool reads it:

    cdro-hostd --replay RUN.cdrocap --heights-csv H --checkpoint C.cdrosog

- without any motion the checkpoint has no such block (the triangle's own frame);
- with a MOTION frame for the triangle's origin node mid-run (the accelerometer's report), the
  checkpoint's engine block names another triangle, without that node, and holds the block: a
  rotation that is orthonormal, an offset of a few metres at most (the outputs stay in the
  building), and the codec's encoding of what it decoded is cdro-hostd's bytes.

The run is the demo scenario's ranges (cdro-sim) as RANGE frames at their times. Seeded;
CDRO_TEST_SEED replays one draw (printed)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
from offline_run import GUARD_S, seed_of

from test_live_moving import START_US, hello_record, range_record

from cdro_tools.codec import Frame, decode_sog, encode_frame
from cdro_tools.codec import checkpoint as checkpoint_codec
from cdro_tools.codec.capture_file import CaptureRecord, CaptureWriter
MOTION_AT_S = 20.0  # s: the triangle's origin reported moving (the map has converged by then)


def write_capture(folder, name, moving_at_s=None, moving_id=0):
    """NAME: a HELLO, then a RANGE frame per row of ranges.csv at its time; with moving_at_s (s) a
    MOTION frame there reporting moving_id moving (never reported still again)."""
    path = folder / name
    rows = (folder / "ranges.csv").read_text().splitlines()[1:]
    with CaptureWriter(path, "serial:/dev/ttyACM0@115200", START_US) as writer:
        writer.write(hello_record(0x6001))
        sequence = 1
        for row in rows:
            t_s, a, b, range_m = row.split(",")
            if moving_at_s is not None and moving_at_s <= float(t_s):
                motion = Frame("MOTION", sequence, dict(device_time_ms=100 + round(moving_at_s * 1000),
                                                        node_id=moving_id, moving=1, accel_norm_mg=1187,
                                                        deviation_mg=164, reason=0))
                writer.write(CaptureRecord(START_US + round(moving_at_s * 1e6), encode_frame(motion)[:-1], 0))
                sequence += 1
                moving_at_s = None
            writer.write(range_record(sequence, float(t_s), a, b, float(range_m)))
            sequence += 1
    return path


def replay(hostd, folder, capture, checkpoint):
    return subprocess.run([str(hostd), "--replay", str(capture), "--speed", "max", "--heights-csv",
                           str(folder / "heights.csv"), "--jsonl", str(folder / f"{capture.stem}.jsonl"),
                           "--http-port", "0", "--checkpoint", str(checkpoint), "--capture", ""],
                          capture_output=True, text=True, timeout=GUARD_S, cwd=folder)


def frame_nodes(snapshot):
    engine, _ = checkpoint_codec.engine_blocks(snapshot)
    assert engine["has_frame"] == 1
    return engine["frame_origin_id"], engine["frame_axis_id"], engine["frame_side_id"]


def test_that_the_python_codec_reads_the_output_frame_cdro_hostd_kept_after_a_frame_node_moved(hostd, tmp_path):
    # Fixture
    seed = seed_of(3)
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--seed", str(seed), "--ranges-csv",
                    str(tmp_path / "ranges.csv"), "--heights-csv", str(tmp_path / "heights.csv")],
                   check=True, capture_output=True, timeout=GUARD_S)
    still = write_capture(tmp_path, "still.cdrocap")
    still_checkpoint = tmp_path / "still.cdrosog"
    first = replay(hostd, tmp_path, still, still_checkpoint)
    assert first.returncode == 0, first.stderr
    still_snapshot = decode_sog(still_checkpoint.read_bytes())
    origin, axis, side = frame_nodes(still_snapshot)
    print(f"seed {seed}: frame triangle {origin:#06x}, {axis:#06x}, {side:#06x}; the first moves at {MOTION_AT_S} s")
    moved = write_capture(tmp_path, "moved.cdrocap", MOTION_AT_S, origin)
    moved_checkpoint = tmp_path / "moved.cdrosog"

    # Act
    second = replay(hostd, tmp_path, moved, moved_checkpoint)

    # Assert
    assert second.returncode == 0, second.stderr
    assert checkpoint_codec.output_frame_block(still_snapshot) is None
    snapshot = decode_sog(moved_checkpoint.read_bytes())
    assert origin not in frame_nodes(snapshot)
    block = checkpoint_codec.output_frame_block(snapshot)
    assert block is not None
    rotation = np.array([[block["rotation_xx"], block["rotation_xy"]], [block["rotation_yx"], block["rotation_yy"]]])
    assert np.allclose(rotation @ rotation.T, np.eye(2), atol=1e-9)
    offset_m = np.hypot(block["translation_x_m"], block["translation_y_m"])
    print(f"rotation {rotation.tolist()}, translation {offset_m:.3f} m")
    assert not np.allclose(rotation, np.eye(2)) or offset_m > 1e-6  # not the identity: that is never written
    assert offset_m < 50.0  # the demo room is 12 m x 9 m: the outputs stay near it
    assert checkpoint_codec.encode_output_frame_block(block) == dict(snapshot.extensions)[
        checkpoint_codec.TAG_OUTPUT_FRAME]
