"""cdro-decode: frames of a capture file (or of raw serial bytes) as JSON Lines.

One line per chunk: {"host_time_us", "direction", "result", "type", "sequence", "fields"} for
good frames, and the rejection with its reason for everything else; then, on stderr, the
decoder's counters. A pipe stage: compose it with jq, grep, or cdro-plot.

examples:
  cdro-decode run.cdrocap | jq 'select(.type == "RANGE") | .fields.distance_mm'
  cdro-decode --raw dump.bin --summary
  cat /dev/ttyACM0 | cdro-decode --raw -
"""
from __future__ import annotations

import argparse
import json
import sys

from .codec import CaptureError, Frame, Result, StreamDecoder, read_capture


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
            for record in contents.records:
                decoder, direction = (tx, "tx") if record.to_device else (rx, "rx")
                for event in decoder.feed(record.data + b"\x00"):
                    if not args.summary:
                        out.write(json.dumps(_line(event, record.host_time_us, direction)) + "\n")
            print(json.dumps({"capture": {"source": contents.header.source, "records": len(contents.records),
                                          "corrupt_bytes": contents.corrupt_bytes,
                                          "truncated_tail_bytes": contents.truncated_tail_bytes}}),
                  file=sys.stderr)
    except (OSError, CaptureError) as error:
        print(f"cdro-decode: {args.input}: {error}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0
    print(json.dumps({"received": rx.counters, "sent": tx.counters}), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
