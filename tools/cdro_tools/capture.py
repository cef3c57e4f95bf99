"""cdro-capture: record a serial port into a capture file (.cdrocap, format in docs/protocol.md).

Every chunk (the bytes between two 0x00 delimiters, good frames and garbage alike) becomes one
record with the host time its delimiter arrived. A status line on stderr shows frames decoded,
rejections by reason, bytes/s and frames/s (--quiet: only the final summary). When the port
vanishes (device unplugged, simulator gone) the file is kept, a chunk cut short by the loss is
written as its own record, and the port is reopened with backoff (0.1 s doubling to 2 s); the
capture continues when it returns. SIGINT/SIGTERM or --duration end it with a summary.

examples:
  cdro-capture --port /dev/ttyACM0 --out run.cdrocap
  cdro-capture --port /tmp/cdro-dev --out run.cdrocap --duration 60 --quiet
  cdro-capture --port /dev/ttyACM0 --wait --out run.cdrocap     # the device is not plugged in yet
"""
from __future__ import annotations

import argparse
import collections
import json
import signal
import sys
import time

import serial

from .codec import CaptureWriter, StreamDecoder
from .codec.frames import COUNTER_NAMES
from .simulation.link import Chunker
from .cli import entry_point

BACKOFF_START_S = 0.1
BACKOFF_MAX_S = 2.0
STATUS_PERIOD_TTY_S = 0.5
STATUS_PERIOD_LOG_S = 5.0
RATE_WINDOW_S = 2.0


class OutputError(OSError):
    """The capture file cannot be written."""


def _err(message: str) -> None:
    print(f"cdro-capture: {message}", file=sys.stderr, flush=True)


class Capture:
    def __init__(self, args, stop):
        self.args = args
        self.stop = stop
        self.port: serial.Serial | None = None
        self.writer: CaptureWriter | None = None
        self.chunker: Chunker | None = None
        self.decoder = StreamDecoder()
        self.bytes_total = 0
        self.vanished = 0
        self.partial_chunks = 0
        self.started = time.monotonic()
        self.window: collections.deque = collections.deque()
        self.last_status = 0.0
        self.status_shown = False
        self.tty = sys.stderr.isatty()

    def _open(self) -> serial.Serial:
        return serial.Serial(self.args.port, self.args.baud, timeout=0.1)

    def _reopen(self, reason: str) -> bool:
        """After the port vanished: keeps trying with backoff; False when told to stop."""
        self.vanished += 1
        if self.chunker.pending:
            self.partial_chunks += 1
        self.chunker.finish(time.time_ns() // 1000)
        list(self.decoder.feed(b"\x00"))      # the cut chunk is counted as the rejection it is
        self._clear_status()
        _err(f"{self.args.port} vanished ({reason}); keeping {self.args.out} "
             f"({self.writer.records_written} records so far); reopening with backoff")
        gone = time.monotonic()
        delay = BACKOFF_START_S
        while not self.stop() and not self._expired():
            try:
                self.port = self._open()
            except (serial.SerialException, OSError):
                time.sleep(delay)
                delay = min(BACKOFF_MAX_S, delay * 2)
                continue
            _err(f"{self.args.port} is back after {time.monotonic() - gone:.1f} s; capturing again")
            return True
        return False

    def _expired(self) -> bool:
        return self.args.duration is not None and time.monotonic() - self.started >= self.args.duration

    def run(self) -> str:
        args = self.args
        delay = BACKOFF_START_S
        while True:
            try:
                self.port = self._open()
                break
            except (serial.SerialException, OSError):
                if not args.wait:
                    raise
                if self.stop():
                    return "signal"
                time.sleep(delay)
                delay = min(BACKOFF_MAX_S, delay * 2)
        try:
            self.writer = CaptureWriter(args.out, f"serial:{args.port}@{args.baud}")
        except OSError as error:
            raise OutputError(f"cannot write {args.out}: {error}") from None
        self.chunker = Chunker(self.writer)
        self.started = time.monotonic()
        while True:
            if self.stop():
                return "signal"
            if self._expired():
                return "duration"
            try:
                data = self.port.read(1)
                if data and self.port.in_waiting:
                    data += self.port.read(self.port.in_waiting)
            except (serial.SerialException, OSError) as error:
                try:
                    self.port.close()
                except (serial.SerialException, OSError):
                    pass
                if not self._reopen(str(error)):
                    return "signal" if self.stop() else "duration"
                continue
            if data:
                try:
                    self.chunker.feed(time.time_ns() // 1000, data)
                except OSError as error:
                    raise OutputError(f"cannot write {args.out}: {error}") from None
                list(self.decoder.feed(data))
                self.bytes_total += len(data)
            self._status()

    def _counts(self) -> tuple[int, dict]:
        c = self.decoder.counters
        rejected = {name[:-len("_errors")]: c[name] for name in COUNTER_NAMES if name.endswith("_errors") and c[name]}
        return c["frames_ok"], rejected

    def _status(self) -> None:
        if self.args.quiet:
            return
        now = time.monotonic()
        period = STATUS_PERIOD_TTY_S if self.tty else STATUS_PERIOD_LOG_S
        if now - self.last_status < period:
            return
        self.last_status = now
        frames, rejected = self._counts()
        if not self.window:
            self.window.append((self.started, 0, 0))      # the first line gives the rates since the start
        self.window.append((now, self.bytes_total, frames))
        # The rates are over at least RATE_WINDOW_S: the base is the newest sample that old (or the
        # oldest there is), never dropped merely because status lines come further apart (5 s to a log).
        while len(self.window) > 2 and now - self.window[1][0] >= RATE_WINDOW_S:
            self.window.popleft()
        t0, b0, f0 = self.window[0]
        span = now - t0
        rates = (f"{(self.bytes_total - b0) / span:.0f} B/s, {(frames - f0) / span:.1f} frames/s"
                 if span > 0 else "- B/s, - frames/s")
        rejects = ", ".join(f"{k} {v}" for k, v in rejected.items()) or "none"
        line = (f"frames ok {frames} | rejected {rejects} | {rates} | {self.bytes_total} B, "
                f"{self.writer.records_written} records, {now - self.started:.0f} s")
        if self.tty:
            sys.stderr.write("\r" + line[:200].ljust(100))
            sys.stderr.flush()
            self.status_shown = True
        else:
            _err(line)

    def _clear_status(self) -> None:
        if self.status_shown:
            sys.stderr.write("\n")
            self.status_shown = False

    def close(self) -> dict:
        self._clear_status()
        if self.chunker is not None:
            if self.chunker.pending:
                self.partial_chunks += 1
            self.chunker.finish(time.time_ns() // 1000)
        if self.writer is not None:
            self.writer.close()
        if self.port is not None:
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass
        frames, rejected = self._counts()
        return {"records": self.writer.records_written if self.writer else 0, "bytes": self.bytes_total,
                "seconds": round(time.monotonic() - self.started, 3), "frames_ok": frames, "rejected": rejected,
                "vanished": self.vanished, "partial_chunks": self.partial_chunks}


@entry_point
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cdro-capture", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--port", required=True, help="serial port (or pseudo-terminal) to read")
    parser.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    parser.add_argument("--out", required=True, help="capture file to write (replaced)")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    parser.add_argument("--quiet", action="store_true", help="no live status line, only the final summary")
    parser.add_argument("--wait", action="store_true", help="wait for the port to appear instead of failing")
    args = parser.parse_args(argv)
    if args.duration is not None and not args.duration > 0:
        parser.error("--duration must be above 0")
    if args.baud <= 0:
        parser.error("--baud must be above 0")

    stopping: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, frame: stopping.append(signum))
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    capture = Capture(args, lambda: bool(stopping))
    try:
        ended_by = capture.run()
    except OutputError as error:
        kept = capture.writer.records_written if capture.writer else 0
        try:
            capture.close()
        except OSError:
            pass
        _err(f"{error}; {kept} records were written before")
        return 1
    except (serial.SerialException, OSError) as error:
        capture.close()
        _err(f"cannot capture {args.port}: {error} (nothing written; --wait waits for the port)")
        return 2
    summary = capture.close()
    _err(f"stopped ({ended_by}): {summary['records']} records, {summary['bytes']} bytes in {summary['seconds']} s; "
         f"frames ok {summary['frames_ok']}, rejected {summary['rejected'] or 'none'}; port vanished "
         f"{summary['vanished']} time(s), {summary['partial_chunks']} partial chunk(s) kept; wrote {args.out}")
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
