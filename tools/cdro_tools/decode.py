"""cdro-decode: frames of a capture file (or of raw serial bytes) as JSON Lines.

One line per chunk: {"host_time_us", "direction", "result", "type", "sequence", "fields"} for
good frames, and the rejection with its reason for everything else; then, on stderr, the
decoder's counters. The robot's odometry messages in a capture (format version 2) are lines
{"direction": "odometry", "result": "ok", "host_time_us", "type": "ODOMETRY", "fields": {"t",
"distance_m", "dheading_rad", "source"}}, in their place among the frames; the engine's host
events (format version 3) lines {"direction": "host_event", "result": "ok", "host_time_us",
"data": hex}. A pipe stage:
compose it with jq, grep, or cdro-plot.

examples:
  cdro-decode run.cdrocap | jq 'select(.type == "RANGE") | .fields.distance_mm'
  cdro-decode run.cdrocap | jq -c 'select(.type == "ODOMETRY") | .fields'
  cdro-decode --raw dump.bin --summary
  cat /dev/ttyACM0 | cdro-decode --raw -
"""
from __future__ import annotations

import argparse
import json
import sys

from .codec import CaptureError, Frame, Result, StreamDecoder, read_capture
from .cli import entry_point


def _line(event, host_time_us=None, direction="rx") -> dict:
    line: dict = {"direction": direction, "result": str(event.result)}
    if host_time_us is not None:
        line["host_time_us"] = host_time_us
    frame: Frame | None = event.frame
    if frame is not None:
        line.update(type=frame.type, sequence=frame.sequence)
        if event.result in (Result.OK, Result.VALUE):
            line["fields"] = frame.fields
    if event.result != Result.OK:
        line.update(chunk=event.chunk.hex(), chunk_length=event.chunk_length, reason=event.message)
    return line


def _odometry_line(record) -> dict:
    line: dict = {"direction": "odometry", "host_time_us": record.host_time_us}
    try:
        fields = record.odometry_message()
        if not isinstance(fields, dict):
            raise ValueError("not a JSON object")
    except (UnicodeDecodeError, ValueError) as error:
        # Only a hand-made or damaged-but-checksummed file gets here; say so, keep going.
        line.update(result="bad_odometry", type="ODOMETRY", chunk=record.data.hex(), chunk_length=len(record.data),
                    reason=f"odometry record is not a JSON object: {error}")
        return line
    line.update(result="ok", type="ODOMETRY", fields=fields)
    return line


@entry_point
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cdro-decode", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("input", help="capture file (.cdrocap), or with --raw a file of serial bytes, - for stdin")
    parser.add_argument("--raw", action="store_true", help="the input is raw serial bytes, not a capture file")
    parser.add_argument("--summary", action="store_true", help="print only the counters")
    args = parser.parse_args(argv)

    out = sys.stdout
    rx = StreamDecoder()
    tx = StreamDecoder()
    try:
        if args.raw:
            stream = sys.stdin.buffer if args.input == "-" else open(args.input, "rb")
            with stream:
                while block := stream.read(65536):
                    for event in rx.feed(block):
                        if not args.summary:
                            out.write(json.dumps(_line(event)) + "\n")
        else:
            contents = read_capture(args.input)
            odometry = host_events = 0
            for record in contents.records:
                if record.host_event:
                    host_events += 1
                    if not args.summary:
                        out.write(json.dumps({"direction": "host_event", "host_time_us": record.host_time_us,
                                              "result": "ok", "data": record.data.hex()}) + "\n")
                    continue
                if record.odometry:
                    odometry += 1
                    if not args.summary:
                        out.write(json.dumps(_odometry_line(record)) + "\n")
                    continue
                decoder, direction = (tx, "tx") if record.to_device else (rx, "rx")
                for event in decoder.feed(record.data + b"\x00"):
                    if not args.summary:
                        out.write(json.dumps(_line(event, record.host_time_us, direction)) + "\n")
            print(json.dumps({"capture": {"source": contents.header.source,
                                          "format_version": contents.header.format_version,
                                          "context": contents.header.context.decode("utf-8", errors="replace"),
                                          "records": len(contents.records), "odometry_records": odometry,
                                          "host_event_records": host_events,
                                          "corrupt_bytes": contents.corrupt_bytes,
                                          "truncated_tail_bytes": contents.truncated_tail_bytes}}),
                  file=sys.stderr)
    except BrokenPipeError:
        raise               # the reader went away (| head): entry_point ends quietly
    except (OSError, CaptureError) as error:
        print(f"cdro-decode: {args.input}: {error}", file=sys.stderr)
        return 2
    print(json.dumps({"received": rx.counters, "sent": tx.counters}), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
