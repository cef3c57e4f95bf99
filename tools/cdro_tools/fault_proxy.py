"""cdro-fault-proxy: a seeded, fault-injecting proxy between a serial device and cdro-hostd.

It opens the device (a real tag, or cdro-sim --pty) as a host would, and acts as the device on
a pseudo-terminal of its own (--link), which cdro-hostd opens as its serial port. The host's
commands pass through untouched; the device's frames pass through, damaged by the fault classes
given, each frame with the class's probability, drawn from one seeded random generator (the seed
is printed). Every fault is counted, and --report writes the counts as JSON together with what a
host that follows docs/service.md must count for them, so that a test compares the host's
counters exactly with what was injected.

Fault classes (device-to-host data frames only: RANGE, MOTION, STATUS; the conversation itself
is left alone so that every run reaches the same state):

  bit_flip   one or more bits flipped so that the chunk no longer decodes   -> chunks_rejected
  garbage    a run of random bytes and a delimiter before the frame          -> chunks_rejected
  phantom    a RANGE whose from_id or to_id is replaced by an id the device  -> frames_rejected_unknown_node
             does not have, with the CRC recomputed (a corruption the CRC
             missed)
  version    the frame re-encoded with the next protocol version and a valid CRC;   -> version_errors
             never two in a row
  duplicate  the frame sent twice                                            -> duplicate_frames
  drop       the frame not sent                                              -> frames_lost
  slow       every byte from the device held back by --slow-delay-s for the
             --slow-window-s seconds after --slow-start-s (the device does not
             reset: the host must not count resets)                          -> device_resets stays 0

examples:
  cdro-sim --scenario demo --pty /tmp/dev --speed 4 &
  cdro-fault-proxy --device /tmp/dev --link /tmp/dev-faulty --seed 3 --fault phantom=0.1 --report r.json &
  cdro-hostd --device /tmp/dev-faulty ...
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import pathlib
import random
import select
import signal
import sys
import termios
import time
import tty

from .codec import PROTOCOL_VERSION, Frame, FrameError, cobs_decode, cobs_encode, crc16, decode_frame, encode_frame
from .simulation.link import PtyLink
from .cli import entry_point

CLASSES = ("bit_flip", "garbage", "phantom", "version", "duplicate", "drop", "slow")
DATA_TYPES = ("RANGE", "MOTION", "STATUS")
OTHER_VERSION = PROTOCOL_VERSION + 1  # a protocol version this build does not speak
GARBAGE_BYTES = (4, 40)    # length range of an injected garbage run (bytes)


def log(message: str) -> None:
    print(f"cdro-fault-proxy: {message}", file=sys.stderr, flush=True)


class Injector:
    """Decides and applies the faults, one complete chunk (without its delimiter) at a time."""

    def __init__(self, rates: dict[str, float], rng: random.Random, known_ids: set[int]):
        self.rates = rates
        self.rng = rng
        self.known_ids = set(known_ids)
        self.counts = collections.Counter({name: 0 for name in CLASSES})
        self.frames_in = 0
        self.frames_passed = 0       # data frames forwarded unharmed (or duplicated)
        self.drops_pending = 0       # drops not yet followed by a forwarded frame (no gap seen yet)
        self.drops_seen = 0          # drops a later frame reveals as a gap
        self.previous_was_version = False

    def chunk(self, chunk: bytes) -> bytes:
        """The bytes to forward for one chunk (delimiters included)."""
        try:
            frame = decode_frame(chunk)
        except FrameError:
            return chunk + b"\x00"
        self.frames_in += 1
        if frame.type == "NODE_LIST":
            self.known_ids.update(frame["node_ids"])
        elif frame.type == "HELLO":
            self.known_ids.add(frame["node_id"])
        if frame.type not in DATA_TYPES:
            return self._passed(chunk)
        for name in ("drop", "bit_flip", "phantom", "version", "duplicate", "garbage"):
            rate = self.rates.get(name, 0.0)
            if rate <= 0.0 or self.rng.random() >= rate:
                continue
            if name == "phantom" and frame.type != "RANGE":
                continue
            if name == "version" and self.previous_was_version:
                continue
            out = getattr(self, "_" + name)(chunk, frame)
            self.counts[name] += 1
            self.previous_was_version = name == "version"
            return out
        self.previous_was_version = False
        return self._passed(chunk)

    def _passed(self, chunk: bytes) -> bytes:
        self.frames_passed += 1
        self.drops_seen += self.drops_pending
        self.drops_pending = 0
        return chunk + b"\x00"

    def _drop(self, chunk: bytes, frame: Frame) -> bytes:
        self.drops_pending += 1
        return b""

    def _bit_flip(self, chunk: bytes, frame: Frame) -> bytes:
        while True:
            damaged = bytearray(chunk)
            for _ in range(self.rng.randint(1, 3)):
                index = self.rng.randrange(len(damaged))
                damaged[index] ^= 1 << self.rng.randrange(8)
            if 0 in damaged:
                continue                      # a 0x00 would split the chunk in two
            try:
                decode_frame(bytes(damaged))
            except FrameError:
                self.drops_pending += 1       # the host sees its sequence number missing
                return bytes(damaged) + b"\x00"

    def _garbage(self, chunk: bytes, frame: Frame) -> bytes:
        while True:
            run = bytes(self.rng.randrange(1, 256) for _ in range(self.rng.randint(*GARBAGE_BYTES)))
            try:
                decode_frame(run)
            except FrameError:
                return run + b"\x00" + self._passed(chunk)

    def _phantom(self, chunk: bytes, frame: Frame) -> bytes:
        while True:
            phantom = self.rng.randrange(1, 0x10000)
            if phantom not in self.known_ids:
                break
        fields = dict(frame.fields)
        fields["to_id" if self.rng.random() < 0.5 else "from_id"] = phantom
        if fields["from_id"] == fields["to_id"]:
            fields["from_id"] = frame["from_id"]
            fields["to_id"] = phantom
        # Its sequence number is the frame's own: the host sees no gap, only an unknown id.
        self.drops_seen += self.drops_pending
        self.drops_pending = 0
        return encode_frame(Frame(frame.type, frame.sequence, fields))

    def _version(self, chunk: bytes, frame: Frame) -> bytes:
        raw = bytearray(cobs_decode(chunk))
        raw[0] = OTHER_VERSION
        raw[-2:] = crc16(bytes(raw[:-2])).to_bytes(2, "little")
        # The host drops it (another version) and sees its sequence number missing.
        self.drops_pending += 1
        return cobs_encode(bytes(raw)) + b"\x00"

    def _duplicate(self, chunk: bytes, frame: Frame) -> bytes:
        return self._passed(chunk) + chunk + b"\x00"

    def report(self) -> dict:
        injected = {name: self.counts[name] for name in CLASSES}
        expected = {
            # What docs/service.md says the host counts for these faults, and nothing else.
            "chunks_rejected": injected["bit_flip"] + injected["garbage"] + injected["version"],
            "version_errors": injected["version"],
            "frames_rejected_unknown_node": injected["phantom"],
            "unknown_node_frames": injected["phantom"],
            "nodes_learned": 0,
            "duplicate_frames": injected["duplicate"],
            "device_resets": 0,
            "frames_dropped_incompatible": 0,
            "incompatible_devices": 0,
            # Frames the host saw missing: dropped, flipped or of another version, when a later
            # frame revealed the gap (the device itself loses none on a pseudo-terminal).
            "frames_lost": self.drops_seen,
        }
        return {"injected": injected, "frames_in": self.frames_in, "frames_passed": self.frames_passed,
                "lost_frames_revealed": self.drops_seen, "expected_counters": expected}


class Proxy:
    def __init__(self, device: str, link: str, injector: Injector, slow_start_s: float, slow_window_s: float,
                 slow_delay_s: float):
        self.device_path = device
        self.link = PtyLink(link)
        self.injector = injector
        self.slow = injector.rates.get("slow", 0.0) > 0.0
        self.slow_start_s = slow_start_s
        self.slow_window_s = slow_window_s
        self.slow_delay_s = slow_delay_s
        self.pending = bytearray()                    # the device's current chunk
        self.to_host: collections.deque[tuple[float, bytes]] = collections.deque()
        self.to_device = bytearray()
        self.bytes_from_device = 0
        self.bytes_to_host = 0
        self.bytes_to_device = 0
        self.stopping = False
        self.started_at: float | None = None

    def run(self) -> None:
        self.link.create()
        log(f"waiting for the host to open {self.link.link_path}")
        while not self.stopping and not self.link.reader_present():
            time.sleep(0.01)
        self.link.hold()
        device = self._open_device()
        if device is None:
            return
        self.started_at = time.monotonic()
        log(f"{self.device_path} <-> {self.link.link_path}: running")
        try:
            self._loop(device)
        finally:
            os.close(device)
            self._flush_to_host(deadline_s=5.0)
            self.link.wait_drained(5.0)       # the host has read everything before the link goes
            self.link.close()

    def _open_device(self) -> int | None:
        deadline = time.monotonic() + 30.0
        while not self.stopping:
            try:
                fd = os.open(self.device_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
                tty.setraw(fd)
                termios.tcflush(fd, termios.TCIOFLUSH)
                return fd
            except OSError as error:
                if time.monotonic() > deadline:
                    log(f"cannot open {self.device_path}: {error}")
                    return None
                time.sleep(0.05)
        return None

    def _loop(self, device: int) -> None:
        poller = select.poll()
        poller.register(device, select.POLLIN)
        poller.register(self.link.master, select.POLLIN)
        while not self.stopping:
            for fd, events in poller.poll(10):
                if fd == device:
                    if events & select.POLLIN:
                        try:
                            data = os.read(device, 4096)
                        except (BlockingIOError, InterruptedError):
                            data = b""
                        except OSError:
                            log("the device went away")
                            return
                        if data:
                            self._from_device(data)
                    elif events & (select.POLLHUP | select.POLLERR):
                        log("the device hung up")
                        return
                elif fd == self.link.master and events & select.POLLIN:
                    data = self.link.read()
                    self.to_device += data
                    self.bytes_to_device += len(data)
            if self.to_device:
                try:
                    n = os.write(device, self.to_device)
                    del self.to_device[:n]
                except (BlockingIOError, InterruptedError):
                    pass
                except OSError:
                    log("the device went away")
                    return
            self._flush_to_host()

    def _from_device(self, data: bytes) -> None:
        self.bytes_from_device += len(data)
        now = time.monotonic()
        release = now
        if self.slow and self.slow_start_s <= now - self.started_at < self.slow_start_s + self.slow_window_s:
            release = now + self.slow_delay_s
            self.injector.counts["slow"] += 1
        start = 0
        while True:
            end = data.find(b"\x00", start)
            if end < 0:
                self.pending += data[start:]
                return
            self.pending += data[start:end]
            chunk, self.pending = bytes(self.pending), bytearray()
            start = end + 1
            out = self.injector.chunk(chunk) if chunk else b"\x00"
            if out:
                # Never before what is already queued: a slow link delays, it does not reorder.
                release_at = max(release, self.to_host[-1][0]) if self.to_host else release
                self.to_host.append((release_at, out))

    def _flush_to_host(self, deadline_s: float = 0.0) -> None:
        end = time.monotonic() + deadline_s
        while self.to_host:
            release_at, data = self.to_host[0]
            now = time.monotonic()
            if release_at > now:
                if deadline_s <= 0.0 or now > end:
                    return
                time.sleep(min(0.01, release_at - now))
                continue
            n = self.link.write(data)
            self.bytes_to_host += n
            if n < len(data):
                self.to_host[0] = (release_at, data[n:])
                if deadline_s <= 0.0 or time.monotonic() > end:
                    return
                time.sleep(0.005)
                continue
            self.to_host.popleft()

    def report(self) -> dict:
        out = self.injector.report()
        out["bytes_from_device"] = self.bytes_from_device
        out["bytes_to_host"] = self.bytes_to_host
        out["bytes_to_device"] = self.bytes_to_device
        return out


def _fault(text: str) -> tuple[str, float]:
    name, _, rate = text.partition("=")
    if name not in CLASSES:
        raise argparse.ArgumentTypeError(f"{name!r} is not a fault class ({', '.join(CLASSES)})")
    try:
        value = float(rate) if rate else 1.0
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: the rate must be a number") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text!r}: the rate is a probability per frame, 0..1")
    return name, value


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cdro-fault-proxy", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", required=True, help="the device's serial port (a tag, or cdro-sim --pty's link)")
    p.add_argument("--link", required=True, help="symlink to the pseudo-terminal the host opens")
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    p.add_argument("--fault", type=_fault, action="append", default=[], metavar="CLASS[=RATE]",
                   help="a fault class and its probability per data frame (slow: any rate turns it on)")
    p.add_argument("--known-id", type=lambda t: int(t, 0), action="append", default=[],
                   help="a node id the device has (phantom ids avoid them; HELLO and NODE_LIST add to them)")
    p.add_argument("--slow-start-s", type=float, default=5.0, help="slow: s after the start (default 5)")
    p.add_argument("--slow-window-s", type=float, default=5.0, help="slow: for how long, s (default 5)")
    p.add_argument("--slow-delay-s", type=float, default=3.0, help="slow: the delay, s (default 3)")
    p.add_argument("--report", metavar="FILE", help="write the counts as JSON here at the end")
    return p


@entry_point
def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    rates = dict(args.fault)
    rng = random.Random(args.seed)
    log(f"seed {args.seed}; faults: " + (", ".join(f"{k}={v:g}" for k, v in rates.items()) or "none"))
    proxy = Proxy(args.device, args.link, Injector(rates, rng, set(args.known_id)), args.slow_start_s,
                  args.slow_window_s, args.slow_delay_s)

    def stop(signo, _frame):
        proxy.stopping = True
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    proxy.run()
    report = proxy.report()
    log(f"injected {json.dumps(report['injected'])}; {report['frames_in']} frames in")
    if args.report:
        pathlib.Path(args.report).write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
