"""cdro-replay: play a capture file's device-to-host records into a serial port or a
pseudo-terminal, at the recorded timing divided by --speed (or as fast as the reader takes
the bytes with --speed max). Each record is written as its chunk followed by the 0x00
delimiter, so a capture made by cdro-capture or cdro-sim plays back byte for byte.
Host-to-device records, the robot's odometry records (a cdro-hostd capture, format
version 2) and the engine's host events (format 3): none of them came over the serial link, so
they are skipped, counted in the summary as records_skipped_to_device, records_skipped_odometry
and records_skipped_host_events (the service fed this way adopts its global solves on its own
timing, as live; its own replay of the file repeats the recorded ones).

With --pty, playing starts when a reader opens the link, and the link is removed after the
reader has read everything (at most 5 s).

examples:
  cdro-replay run.cdrocap --pty /tmp/cdro-dev               # then: cdro-hostd --device /tmp/cdro-dev
  cdro-replay run.cdrocap --port /dev/ttyUSB1 --speed 4
  cdro-replay run.cdrocap --pty /tmp/cdro-dev --speed max
"""
from __future__ import annotations

import argparse
import collections
import json
import select
import signal
import sys
import time

import serial

from .codec import CaptureError, StreamDecoder, read_capture
from .simulation.link import LinkError, PtyLink
from .simulation.runner import READER_GRACE_S
from .sim import _speed
from .cli import entry_point


def _err(message: str) -> None:
    print(f"cdro-replay: {message}", file=sys.stderr, flush=True)


class PtyOutput:
    def __init__(self, path: str, stop):
        self.link = PtyLink(path)
        self.stop = stop
        slave = self.link.create()
        _err(f"playing into {path} -> {slave} when a reader opens it")

    def wait_reader(self) -> bool:
        seen = None
        while not self.stop():
            if self.link.reader_present():
                seen = seen or time.monotonic()
                if time.monotonic() - seen >= READER_GRACE_S:
                    self.link.hold()
                    return True
            else:
                seen = None
            time.sleep(0.01)
        return False

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view and not self.stop():
            written = self.link.write(view)
            view = view[written:]
            if view:
                select.select([], [self.link.master], [], 0.1)

    def close(self, drain: bool) -> int:
        unread = self.link.wait_drained(5.0, self.stop) if drain else 0
        self.link.close()
        return unread


class PortOutput:
    def __init__(self, path: str, baud: int):
        self.port = serial.Serial(path, baud, write_timeout=None)

    def wait_reader(self) -> bool:
        return True

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def close(self, drain: bool) -> int:
        if drain:
            self.port.flush()
        self.port.close()
        return 0


@entry_point
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cdro-replay", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("capture", metavar="FILE", help="capture file (.cdrocap)")
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--port", metavar="PATH", help="serial port to write to")
    target.add_argument("--pty", metavar="LINK_PATH", help="create a pseudo-terminal linked at LINK_PATH")
    parser.add_argument("--baud", type=int, default=115200, help="baud rate with --port (default 115200)")
    parser.add_argument("--speed", type=_speed, default=1.0, metavar="X|max",
                        help="recorded time per wall time (default 1); max: no waiting")
    args = parser.parse_args(argv)

    try:
        contents = read_capture(args.capture)
    except (OSError, CaptureError) as error:
        _err(f"{args.capture}: {error}")
        return 2
    records = [r for r in contents.records if r.device]
    skipped = sum(1 for r in contents.records if r.to_device)
    skipped_odometry = sum(1 for r in contents.records if r.odometry and not r.to_device)
    skipped_host_events = sum(1 for r in contents.records if r.host_event)
    if contents.corrupt_bytes or contents.truncated_tail_bytes:
        _err(f"{args.capture}: skipping {contents.corrupt_bytes} corrupt bytes and a truncated tail of "
             f"{contents.truncated_tail_bytes} bytes (the records around them play)")

    stopping: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, frame: stopping.append(signum))
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    stop = lambda: bool(stopping)  # noqa: E731
    try:
        output = PtyOutput(args.pty, stop) if args.pty else PortOutput(args.port, args.baud)
    except (LinkError, serial.SerialException, OSError) as error:
        _err(f"cannot open {args.pty or args.port}: {error}")
        return 2

    decoder = StreamDecoder()
    frames_by_type: collections.Counter = collections.Counter()
    played = played_bytes = truncated = 0
    ended_by = "end of capture"
    started = time.monotonic()
    try:
        if not output.wait_reader():
            ended_by = "signal"
        else:
            started = time.monotonic()
            first_us = records[0].host_time_us if records else 0
            for record in records:
                if stop():
                    ended_by = "signal"
                    break
                if args.speed is not None:
                    due = started + (record.host_time_us - first_us) / 1e6 / args.speed
                    while not stop() and time.monotonic() < due:
                        time.sleep(min(0.05, max(0.0, due - time.monotonic())))
                    if stop():
                        ended_by = "signal"
                        break
                data = record.data + b"\x00"
                output.write(data)
                played += 1
                played_bytes += len(data)
                truncated += record.truncated
                for event in decoder.feed(data):
                    if event.frame is not None and str(event.result) == "ok":
                        frames_by_type[event.frame.type] += 1
        unread = output.close(drain=ended_by != "signal")
    except (serial.SerialException, OSError) as error:
        _err(f"{args.pty or args.port}: {error} after {played} records")
        output.close(drain=False)
        return 1
    seconds = time.monotonic() - started
    c = decoder.counters
    summary = {"ended_by": ended_by, "records_played": played, "bytes": played_bytes, "seconds": round(seconds, 3),
               "records_skipped_to_device": skipped, "records_skipped_odometry": skipped_odometry,
               "records_skipped_host_events": skipped_host_events,
               "records_truncated": truncated,
               "capture_corrupt_bytes": contents.corrupt_bytes,
               "capture_truncated_tail_bytes": contents.truncated_tail_bytes, "bytes_unread": unread,
               "frames_ok": c["frames_ok"], "frames_by_type": dict(sorted(frames_by_type.items())),
               "rejected": {k[:-7]: v for k, v in c.items() if k.endswith("_errors") and v}}
    _err(f"played {played} of {len(records)} device records ({played_bytes} bytes) in {seconds:.1f} s "
         f"({ended_by}); {c['frames_ok']} good frames, rejected {summary['rejected'] or 'none'}; skipped {skipped} "
         f"host-to-device, {skipped_odometry} odometry and {skipped_host_events} host event records")
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
