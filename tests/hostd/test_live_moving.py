"""cdro-hostd's live service tracks the nodes of map.moving (--moving) in 3D, as the offline mode
does, run as a user runs it on a capture:

    cdro-hostd --replay FLIGHT.cdrocap --fixed-csv A --heights-csv H --moving 10,20 --jsonl OUT

- the moving nodes' lines carry z_m and the keys only 3D tracks have (var_z_m2, cov_xz_m2,
  cov_yz_m2), their covariance positive definite, near the truth of a seeded simulated flight
  (a loose bound: the engine's test states the tracker's own); without the list the same nodes are
  2D nodes whose lines do not have them; every line follows docs/outputs.schema.json;
- a replay gives the same lines byte for byte twice; map.moving in the configuration file gives the
  lines --moving gives;
- bad input is refused with status 2 and a message naming map.moving: fewer than four fixed nodes
  of known height, a moving node that is fixed, a node id that is none;
- the 3D tracks are in checkpoints: a flight replayed in two parts, the second with --resume from
  the first's checkpoint, gives the moving nodes the lines the uninterrupted replay gives from the
  split on, and no warning that a track restarts; a checkpoint written with other nodes tracked in
  3D is resumed with a warning naming them;
- a capture whose run context records map.moving (with the heights and fixed nodes) replays with
  its nodes tracked in 3D untold, to the lines a replay told them gives.

The capture is built from the flight's ranges (one RANGE frame per range, at its time). The binary
is the native build's (CDRO_BUILD_DIR; default ./build). Seeded; CDRO_TEST_SEED replays one."""
from __future__ import annotations

import json
import math
import subprocess

import numpy as np
from offline_run import seed_of
from test_offline_moving import ANCHORS, TAGS, truth, write_flight
from test_output_schema import check_line

from cdro_tools import outputs_schema
from cdro_tools.codec import Frame, decode_sog, encode_frame
from cdro_tools.codec import checkpoint as checkpoint_codec
from cdro_tools.codec.capture_file import CaptureRecord, CaptureWriter, decode_header, encode_header
from cdro_tools.codec.frames import LAYOUT_HASH, PROTOCOL_VERSION

GUARD_S = 120  # s, a deadlock guard only
START_US = 1_700_000_000_000_000  # us since the epoch: the capture's start, the flight's t = 0


def hello_record(node_id=0x6000):
    """The capture record of the tag's HELLO at START_US (node_id: the tag's own node)."""
    hello = Frame("HELLO", 0, dict(device_time_ms=50, firmware_version=0x0102, protocol_version=PROTOCOL_VERSION,
                                   layout_hash=LAYOUT_HASH, node_id=node_id, capabilities=0x03, pozyx_firmware=0x12,
                                   max_nodes=20, reset_cause=1, pozyx_tries=1))
    return CaptureRecord(START_US, encode_frame(hello)[:-1], 0)


def range_record(sequence, t_s, a, b, range_m):
    """The capture record of a RANGE frame a-b at START_US + t_s (s), as the tag sends it."""
    frame = Frame("RANGE", sequence, dict(device_time_ms=100 + round(t_s * 1000), from_id=int(a), to_id=int(b),
                                          distance_mm=round(range_m * 1000), rss_dbm=-80, flags=0))
    return CaptureRecord(START_US + round(t_s * 1e6), encode_frame(frame)[:-1], 0)


def write_capture(folder, context=b"", name="flight.cdrocap", from_s=None, to_s=None):
    """NAME: a HELLO, then a RANGE frame per row of ranges.csv at START_US + t; context: the run's
    context of its header (cdro-hostd's JSON), b"" = none. With from_s (s): the rows from then on
    only, and no HELLO (the second part of a run); with to_s (s): the rows before then only."""
    path = folder / name
    rows = (folder / "ranges.csv").read_text().splitlines()[1:]
    with CaptureWriter(path, "serial:/dev/ttyACM0@115200", START_US) as writer:
        if from_s is None:
            writer.write(hello_record())
        for sequence, row in enumerate(rows, start=1):
            t_s, a, b, range_m = row.split(",")
            if (from_s is not None and float(t_s) < from_s) or (to_s is not None and float(t_s) >= to_s):
                continue
            writer.write(range_record(sequence, float(t_s), a, b, float(range_m)))
    if context:
        data = path.read_bytes()
        header, size = decode_header(data)
        header.context = context
        path.write_bytes(encode_header(header) + data[size:])
    return path


def replay(build_dir, folder, capture, out, *args, checkpoint=""):
    return subprocess.run([str(build_dir / "bin" / "cdro-hostd"), "--replay", str(capture), "--speed", "max",
                           "--jsonl", str(folder / out), "--http-port", "0", "--checkpoint", str(checkpoint),
                           "--capture", "", *map(str, args)], capture_output=True, text=True, timeout=GUARD_S,
                          cwd=folder)


def geometry(folder):
    return ["--fixed-csv", folder / "anchors.csv", "--heights-csv", folder / "heights.csv"]


def node_lines(path):
    return [line for line in (json.loads(t) for t in path.read_text().splitlines() if t) if line["type"] == "node"]


def test_that_a_replay_tracks_the_moving_nodes_in_3d_the_same_twice(build_dir, repo_root, tmp_path):
    folder = write_flight(tmp_path, seed_of(11), duration_s=40.0)
    capture = write_capture(folder)
    config = folder / "moving.yaml"
    config.write_text("map:\n  moving: [10, 0x14]\n")

    first = replay(build_dir, folder, capture, "a.jsonl", *geometry(folder), "--moving", "10,20")
    second = replay(build_dir, folder, capture, "b.jsonl", *geometry(folder), "--moving", "10,20")
    configured = replay(build_dir, folder, capture, "c.jsonl", *geometry(folder), "--config", config)

    for result in (first, second, configured):
        assert result.returncode == 0, result.stderr
    assert "map: 2 nodes tracked in 3D (map.moving)" in first.stderr, first.stderr
    assert (folder / "a.jsonl").read_bytes() == (folder / "b.jsonl").read_bytes()
    assert (folder / "a.jsonl").read_bytes() == (folder / "c.jsonl").read_bytes()
    schema = outputs_schema.load(repo_root / "docs" / "outputs.schema.json")
    for text in (folder / "a.jsonl").read_text().splitlines():
        check_line(schema, json.loads(text), "a replay with map.moving")
    lines = node_lines(folder / "a.jsonl")
    moving = [line for line in lines if line["id"] in TAGS]
    # The anchors range no other static node, so that the static map is empty here (as offline).
    assert all(line["id"] in TAGS for line in lines)
    placed = [line for line in moving if line["placed"]]
    assert {line["id"] for line in placed} == set(TAGS)
    errors = []
    for line in placed:
        assert line["moving"] and line["status"] == "moving"
        cov = np.array([[line["var_x_m2"], line["cov_xy_m2"], line["cov_xz_m2"]],
                        [line["cov_xy_m2"], line["var_y_m2"], line["cov_yz_m2"]],
                        [line["cov_xz_m2"], line["cov_yz_m2"], line["var_z_m2"]]])
        assert np.all(np.linalg.eigvalsh(cov) > 0.0), line
        t_s = line["t_unix_s"] - START_US * 1e-6
        if t_s >= 10.0:
            p = np.array([line["x_m"], line["y_m"], line["z_m"]])
            errors.append(float(np.linalg.norm(p - truth(TAGS.index(line["id"]), t_s))))
    assert len(errors) > 20
    rmse = math.sqrt(sum(e * e for e in errors) / len(errors))
    print(f"live RMSE 3D from 10 s: {rmse:.3f} m over {len(errors)} lines")
    assert rmse < 0.5
    # Without the list the same nodes are static 2D nodes: no line carries the 3D track's keys.
    plain = replay(build_dir, folder, capture, "plain.jsonl", *geometry(folder))
    assert plain.returncode == 0, plain.stderr
    plain_lines = node_lines(folder / "plain.jsonl")
    assert {line["id"] for line in plain_lines} >= set(TAGS)
    assert all("var_z_m2" not in line and "cov_xz_m2" not in line for line in plain_lines)


def test_that_bad_moving_lists_are_refused_naming_map_moving(build_dir, tmp_path):
    folder = write_flight(tmp_path, seed_of(12), duration_s=5.0)
    capture = write_capture(folder)
    three = folder / "three.csv"
    three.write_text("\n".join((folder / "anchors.csv").read_text().splitlines()[:4]) + "\n")

    no_anchors = replay(build_dir, folder, capture, "n.jsonl", "--moving", "10,20")
    too_few = replay(build_dir, folder, capture, "t.jsonl", "--fixed-csv", three, "--heights-csv",
                     folder / "heights.csv", "--moving", "10")
    fixed = replay(build_dir, folder, capture, "f.jsonl", *geometry(folder), "--moving", "10,3")
    not_an_id = replay(build_dir, folder, capture, "i.jsonl", *geometry(folder), "--moving", "10,x")

    assert no_anchors.returncode == 2
    assert "map.moving: the nodes tracked in 3D need at least 4 fixed nodes of known height" in no_anchors.stderr
    assert "0 given" in no_anchors.stderr, no_anchors.stderr
    assert too_few.returncode == 2 and "3 given" in too_few.stderr, too_few.stderr
    assert fixed.returncode == 2 and "map.moving: node 3 is fixed" in fixed.stderr, fixed.stderr
    assert not_an_id.returncode == 2 and "--moving: 'x' is not a node id" in not_an_id.stderr, not_an_id.stderr


def moving_lines(path, from_s=0.0):
    """The moving nodes' lines at or after from_s (s since the flight's start)."""
    return [line for line in node_lines(path)
            if line["id"] in TAGS and line["t_unix_s"] - START_US * 1e-6 >= from_s]


def test_that_a_resumed_replay_goes_on_with_the_3d_tracks_as_if_never_stopped(build_dir, tmp_path):
    seed = seed_of(13)
    folder = write_flight(tmp_path, seed, duration_s=30.0)
    split_s = 17.05  # s, mid-flight: both tags tracked, between two ranges
    whole = write_capture(folder)
    head = write_capture(folder, name="head.cdrocap", to_s=split_s)
    tail = write_capture(folder, name="tail.cdrocap", from_s=split_s)
    checkpoint = folder / "head.cdrosog"
    # A line per update: the JSON Lines writer's pacing per node (jsonl.max_node_rate_hz) starts
    # afresh on a resume, so that with it the two runs would write the same estimates at other times.
    every = ["--set", "jsonl.max_node_rate_hz=0"]

    uninterrupted = replay(build_dir, folder, whole, "whole.jsonl", *geometry(folder), "--moving", "10,20", *every)
    written = replay(build_dir, folder, head, "head.jsonl", *geometry(folder), "--moving", "10,20", *every,
                     checkpoint=checkpoint)
    assert uninterrupted.returncode == 0 and written.returncode == 0, uninterrupted.stderr + written.stderr
    # The Python codec reads the tracks cdro-hostd wrote, and writes the same bytes.
    snapshot = decode_sog(checkpoint.read_bytes())
    flight = checkpoint_codec.flight_block(snapshot)
    assert [node["id"] for node in flight["nodes"]] == list(TAGS)
    assert all(node["status"] == 2 and len(node["heard"]) == len(ANCHORS) for node in flight["nodes"])  # tracking
    assert sorted(anchor["id"] for anchor in flight["anchors"]) == sorted(ANCHORS)
    assert len(flight["state"]) == 6 * len(TAGS) and len(flight["covariance"]) == 6 * len(TAGS)
    assert abs(flight["t_s"] - (START_US * 1e-6 + split_s)) < 0.2
    assert checkpoint_codec.encode_flight_block(flight) == dict(snapshot.extensions)[checkpoint_codec.TAG_FLIGHT]
    resumed = replay(build_dir, folder, tail, "tail.jsonl", *geometry(folder), "--moving", "10,20", *every,
                     "--resume", checkpoint, checkpoint=folder / "again.cdrosog")

    assert resumed.returncode == 0, resumed.stderr
    assert "resume:" in resumed.stderr, resumed.stderr
    assert "restart" not in resumed.stderr, resumed.stderr
    expected = moving_lines(folder / "whole.jsonl", split_s)
    got = moving_lines(folder / "tail.jsonl", split_s)
    print(f"seed {seed}: {len(expected)} lines of the moving nodes after the split at {split_s} s")
    assert len(expected) > 100
    assert {line["id"] for line in got} == set(TAGS)
    assert all(line["placed"] for line in got)
    assert got == expected  # every value, as the uninterrupted replay wrote it

    # The tracks of other nodes than map.moving's: named, and those tracks restart.
    other = replay(build_dir, folder, tail, "other.jsonl", *geometry(folder), "--moving", "10", "--resume",
                   checkpoint, checkpoint=folder / "other.cdrosog")
    assert other.returncode == 0, other.stderr
    assert "the checkpoint's 3D tracks of nodes 20 are not in map.moving: dropped" in other.stderr, other.stderr
    plain = replay(build_dir, folder, tail, "plain.jsonl", *geometry(folder), "--resume", checkpoint,
                   checkpoint=folder / "plain.cdrosog")
    assert plain.returncode == 0, plain.stderr
    assert "the checkpoint's 3D tracks of nodes 10, 20 are not in map.moving: dropped" in plain.stderr, plain.stderr


def test_that_a_capture_recording_map_moving_replays_its_3d_tracks_untold(build_dir, tmp_path):
    folder = write_flight(tmp_path, seed_of(14), duration_s=20.0)
    rows = {name: [line.split(",") for line in (folder / f"{name}.csv").read_text().splitlines()[1:]]
            for name in ("anchors", "heights")}
    context = {"heights": [[int(i), float(z)] for i, z in rows["heights"]],
               "fixed": [[int(i), float(x), float(y)] for i, x, y in rows["anchors"]],
               "settings": "", "moving": list(TAGS)}
    recorded = write_capture(folder, json.dumps(context).encode(), "recorded.cdrocap")

    untold = replay(build_dir, folder, recorded, "untold.jsonl")
    told = replay(build_dir, folder, recorded, "told.jsonl", *geometry(folder), "--moving", "10,20")
    other = replay(build_dir, folder, recorded, "other.jsonl", "--moving", "10")

    assert untold.returncode == 0 and told.returncode == 0, untold.stderr + told.stderr
    assert "the live run's 2 nodes tracked in 3D (map.moving), from the capture" in untold.stderr, untold.stderr
    assert "differ from the live run's" not in told.stderr, told.stderr
    lines = node_lines(folder / "untold.jsonl")
    assert any("var_z_m2" in line for line in lines)
    assert (folder / "untold.jsonl").read_bytes() == (folder / "told.jsonl").read_bytes()
    assert other.returncode == 0, other.stderr
    assert "the nodes tracked in 3D given (map.moving, --moving) differ from the live run's" in other.stderr
