"""A minimal host over a serial port, for scripted checks of a device (simulated or real):
send commands, collect decoded frames until a condition holds. Used by the tests; handy for
end-to-end scripts too.

    with HostLink("/tmp/cdro-dev") as host:
        host.wait_for(lambda f: f.type == "HELLO", timeout_s=10)
        host.send("PING", {"nonce": 7})
        ack = host.wait_for(lambda f: f.type == "ACK", timeout_s=10)
"""
from __future__ import annotations

import os
import time
from typing import Callable

import serial

from ..codec import DecodeEvent, Frame, Result, StreamDecoder, encode_frame


class HostLink:
    def __init__(self, path: str, baud: int = 115200, appear_timeout_s: float = 10.0,
                 give_up: Callable[[], bool] = lambda: False):
        deadline = time.monotonic() + appear_timeout_s
        while not os.path.exists(path):
            if time.monotonic() > deadline or give_up():
                raise TimeoutError(f"{path} did not appear within {appear_timeout_s} s")
            time.sleep(0.01)
        self.port = serial.Serial(path, baud, timeout=0.05)
        self.decoder = StreamDecoder()
        self.events: list[DecodeEvent] = []
        self.received = bytearray()          # every byte read, as read
        self.sequence = 0
        self._seen = 0

    @property
    def frames(self) -> list[Frame]:
        return [e.frame for e in self.events if e.result == Result.OK]

    def send(self, frame_type: str, fields: dict | None = None, sequence: int | None = None) -> int:
        """Sends one frame; returns its sequence number."""
        seq = self.sequence if sequence is None else sequence
        self.sequence = (seq + 1) & 0xFFFF
        self.port.write(encode_frame(Frame(frame_type, seq, fields or {})))
        return seq

    def send_raw(self, data: bytes) -> None:
        self.port.write(data)

    def poll(self) -> int:
        """Reads what is there; returns the number of new events."""
        # read only what is there (or wait for one byte): pyserial's read(n) collects until n bytes
        # or the timeout, and loses what it collected when the port hangs up meanwhile
        try:
            waiting = self.port.in_waiting
        except OSError as error:
            # pyserial's in_waiting lets the ioctl's EIO through as it is when the device side of a
            # pseudo-terminal has gone, where read() says SerialException: one error for one event
            raise serial.SerialException(f"{self.port.port}: the device went away ({error})") from error
        data = self.port.read(waiting) if waiting else self.port.read(1)
        self.received += data
        before = len(self.events)
        self.events.extend(self.decoder.feed(data))
        return len(self.events) - before

    def wait_for(self, condition: Callable[[Frame], bool], timeout_s: float) -> Frame:
        """The first frame not seen by an earlier wait_for that meets the condition."""
        deadline = time.monotonic() + timeout_s
        while True:
            while self._seen < len(self.events):
                event = self.events[self._seen]
                self._seen += 1
                if event.result == Result.OK and condition(event.frame):
                    return event.frame
            if time.monotonic() > deadline:
                raise TimeoutError(f"no matching frame within {timeout_s} s; last frames: "
                                   f"{[f.type for f in self.frames[-8:]]}")
            self.poll()

    def read_for(self, seconds: float) -> None:
        """Collects frames for a while (a deadlock guard, not a timing assertion)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.poll()

    def close(self) -> None:
        self.port.close()

    def __enter__(self) -> "HostLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
