"""cdro-export: a capture (.cdrocap) or the service's JSON Lines as an MCAP recording for Foxglove
(foxglove.SceneUpdate, PoseInFrame, PosesInFrame, FrameTransforms, JSON health and ranges) or,
with --ros2, for `ros2 bag play -s mcap` (PoseWithCovarianceStamped, MarkerArray, TFMessage,
CDR-encoded); or a capture's ranges as the ranges.csv that `cdro-hostd --ranges-csv` and
cdro-eval read.

A capture's estimates come from replaying it through cdro-hostd (`--replay FILE --speed max`,
bit for bit the live run's node and robot lines); its ranges are decoded from its frames.
Message times: the line's `t_unix_s` when the stream has it, else the capture's creation time
(or --start-unix-s for JSON Lines) plus `t_s`. docs/outputs.md lists the topics.

examples:
  cdro-export run.cdrocap -o run.mcap                      # open in Foxglove
  cdro-export run.cdrocap -o run-ros2.mcap --ros2          # ros2 bag play -s mcap run-ros2.mcap
  cdro-export estimates.jsonl -o estimates.mcap --rate-hz 0
  cdro-export run.cdrocap --format ranges-csv -o ranges.csv && cdro-hostd --ranges-csv ranges.csv --out-csv est.csv
"""
from __future__ import annotations

import argparse
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile

from ..codec import CaptureError, read_capture
from ..codec.capture_file import MAGIC
from .ranges import RANGES_CSV_HEADER, RangeTally, capture_ranges, format_row
from .recorder import FoxgloveRecorder, Ros2Recorder, record_stream
from .stream import StreamError, Tally, read_jsonl, seconds_to_ns
from ..cli import entry_point

PROG = "cdro-export"


def log(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr)


def find_hostd(given: str | None) -> str:
    """--hostd, else $CDRO_BUILD_DIR/bin, else PATH, else the repository's build/bin."""
    candidates = [given] if given else []
    if os.environ.get("CDRO_BUILD_DIR"):
        candidates.append(os.path.join(os.environ["CDRO_BUILD_DIR"], "bin", "cdro-hostd"))
    on_path = shutil.which("cdro-hostd")
    if on_path:
        candidates.append(on_path)
    candidates.append(str(pathlib.Path(__file__).resolve().parents[3] / "build" / "bin" / "cdro-hostd"))
    for candidate in candidates:
        if candidate and os.access(candidate, os.X_OK):
            return candidate
    raise StreamError("cdro-hostd not found (give --hostd PATH, or set CDRO_BUILD_DIR); it replays the capture "
                      "into estimates")


def is_capture(path: str) -> bool:
    if path == "-":
        return False
    with open(path, "rb") as f:
        return f.read(len(MAGIC)) == MAGIC


def replay_capture(args, capture: str, scratch: pathlib.Path) -> pathlib.Path:
    """The capture's JSON Lines from cdro-hostd --replay."""
    hostd = find_hostd(args.hostd)
    jsonl = scratch / "replay.jsonl"
    command = [hostd, "--replay", capture, "--speed", "max", "--jsonl", str(jsonl), "--capture", "",
               "--checkpoint", "", "--log-level", "warn"]
    if args.config:
        command += ["--config", args.config]
    # Every update, as the engine made it: --rate-hz thins them here, not the service's per-node
    # limit on its JSON Lines file (jsonl.max_node_rate_hz).
    command += ["--set", "jsonl.max_node_rate_hz=0"]
    if args.heights_csv:
        command += ["--heights-csv", args.heights_csv]
    command += args.hostd_arg
    log(f"replaying {capture} through {hostd}")
    done = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        raise StreamError(f"cdro-hostd --replay exited {done.returncode}: {done.stderr.strip()[-2000:]}")
    return jsonl


def export_ranges_csv(args) -> int:
    contents = read_capture(args.input)
    tally = RangeTally()
    out = sys.stdout if args.output == "-" else open(args.output, "w", encoding="utf-8")
    try:
        out.write(RANGES_CSV_HEADER + "\n")
        for row in capture_ranges(contents, tally):
            out.write(format_row(row) + "\n")
    finally:
        if out is not sys.stdout:
            out.close()
    if contents.corrupt_bytes or contents.truncated_tail_bytes:
        log(f"{args.input}: {contents.corrupt_bytes} corrupt byte(s) skipped between records, "
            f"{contents.truncated_tail_bytes} byte(s) of a cut-short last record dropped")
    log(f"{args.output}: {tally.summary()}")
    return 0


def export_mcap(args) -> int:
    tally = Tally("stdin" if args.input == "-" else args.input)
    capture = None
    start_ns = seconds_to_ns(args.start_unix_s) if args.start_unix_s is not None else None
    with tempfile.TemporaryDirectory(prefix="cdro-export-") as scratch_dir:
        if is_capture(args.input):
            capture = read_capture(args.input)
            if capture.corrupt_bytes or capture.truncated_tail_bytes:
                log(f"{args.input}: {capture.corrupt_bytes} corrupt byte(s) skipped between records, "
                    f"{capture.truncated_tail_bytes} byte(s) of a cut-short last record dropped")
            if start_ns is None:
                start_ns = capture.header.created_unix_us * 1000
            jsonl_path = replay_capture(args, args.input, pathlib.Path(scratch_dir))
            source = open(jsonl_path, encoding="utf-8", errors="replace")
        else:
            source = sys.stdin if args.input == "-" else open(args.input, encoding="utf-8", errors="replace")
        recorder = (Ros2Recorder if args.ros2 else FoxgloveRecorder)(args.output)
        try:
            objects = read_jsonl(source, "stdin" if args.input == "-" else args.input, tally)
            range_tally = RangeTally()
            ranges = capture_ranges(capture, range_tally) if capture is not None and not args.no_ranges else None
            written = record_stream(recorder, objects, ranges, args.rate_hz, start_ns)
        finally:
            recorder.close()
            if source is not sys.stdin:
                source.close()
    if start_ns is None and not written.saw_unix_time:
        log("the stream has no t_unix_s: message times are t_s after the Unix epoch (give --start-unix-s)")
    log(tally.summary())
    if ranges is not None:
        log(f"ranges: {range_tally.summary()}")
    log(f"{args.output}: " + ", ".join(f"{topic} {n}" for topic, n in sorted(written.counts.items())))
    return 0


@entry_point
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("input", help="a capture (.cdrocap), or cdro-hostd's JSON Lines (a file, - for stdin)")
    parser.add_argument("-o", "--output", required=True, help="the MCAP file (or the CSV; - = stdout for CSV)")
    parser.add_argument("--format", choices=("mcap", "ranges-csv"), default="mcap")
    parser.add_argument("--ros2", action="store_true",
                        help="ROS 2 messages (CDR, ros2msg schemas) instead of Foxglove's protobuf schemas")
    parser.add_argument("--rate-hz", type=float, default=10.0,
                        help="Hz of stream time: the whole map at most this often (default 10); "
                             "0 = a message per line, for the node it names")
    parser.add_argument("--start-unix-s", type=float, default=None,
                        help="s since the Unix epoch at t_s = 0, for JSON Lines without t_unix_s")
    parser.add_argument("--no-ranges", action="store_true", help="no /cdro/ranges topic from a capture")
    parser.add_argument("--hostd", help="the cdro-hostd that replays a capture (default: found)")
    parser.add_argument("--config", help="cdro-hostd configuration for the replay (the engine's settings)")
    parser.add_argument("--heights-csv", help="known heights id,z (m) for the replay")
    parser.add_argument("--hostd-arg", action="append", default=[], metavar="ARG",
                        help="one more argument for the replay, e.g. --hostd-arg=--set=engine.range.sigma_m=0.13")
    args = parser.parse_args(argv)
    if args.rate_hz < 0:
        parser.error("--rate-hz must be 0 or more")
    try:
        if args.format == "ranges-csv":
            if args.ros2:
                parser.error("--ros2 is for --format mcap")
            if args.input == "-" or not is_capture(args.input):
                raise StreamError(f"{args.input}: ranges come from a capture (.cdrocap); JSON Lines carry "
                                  "estimates, not ranges")
            return export_ranges_csv(args)
        if args.output == "-":
            parser.error("MCAP needs a file (-o FILE.mcap)")
        return export_mcap(args)
    except (OSError, CaptureError, StreamError) as error:
        log(f"{error}")
        return 2
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    raise SystemExit(main())
