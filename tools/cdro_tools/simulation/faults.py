"""Fault injection between the simulated device and the link, for end-to-end tests.

Faults are scheduled in simulated seconds since the simulation started (not device time,
which restarts at a reset). Each applied fault is counted; report() gives the counts, the
list of events, and what a host decoder must have counted for the bytes that reached the link
(one decoder per connection: a vanished device means a new connection).
"""
from __future__ import annotations

import random
from typing import Callable, Protocol

from ..codec import Frame, FrameError, decode_frame
from .scenario import RESET_CAUSES, Fault

ABSURD_KINDS = ("distance", "self_range", "unknown_node")


class Transport(Protocol):
    def room(self) -> int: ...
    def offer(self, time_us: int, data: bytes, frame: Frame | None) -> bool: ...
    def go_down(self, time_us: int) -> None: ...
    def come_back(self, time_us: int, connected: Callable[[], None]) -> None: ...


def new_counts() -> dict[str, dict[str, float]]:
    return {
        "garbage": {"injected": 0, "bytes": 0},
        "bit_flip": {"injected": 0},
        "cut_frame": {"injected": 0},
        "absurd": {"injected": 0, **{kind: 0 for kind in ABSURD_KINDS}},
        "vanish": {"injected": 0, "seconds": 0.0, "reboots": 0},
        "reset": {"injected": 0},
    }


class FaultLink:
    """The device's sink: frames pass through here to the transport, damaged when a fault is armed."""

    def __init__(self, faults: list[Fault], rng: random.Random, transport: Transport, known_ids: set[int]):
        self.pending = sorted(((int(round(f.at_s * 1e6)), i, f) for i, f in enumerate(faults)), key=lambda p: p[:2])
        self.rng = rng
        self.transport = transport
        self.device = None                 # set by the runner
        self.counts = new_counts()
        self.events: list[dict] = []
        self.flips_armed = 0
        self.cuts_armed = 0
        self.absurd_next = 0
        self.down_until_us: int | None = None
        self.reboot_on_return = False
        unknown = 0xBEEF
        while unknown in known_ids:
            unknown += 1
        self.unknown_id = unknown

    # -- the device's sink --

    def room(self) -> int:
        return self.transport.room()

    def offer(self, time_us: int, data: bytes, frame: Frame | None) -> bool:
        if frame is not None and self.flips_armed:
            damaged = self._flip(data)
            if self.transport.offer(time_us, damaged, None):
                self.flips_armed -= 1
                self.counts["bit_flip"]["injected"] += 1
                return True
            return False
        if frame is not None and self.cuts_armed:
            if self.transport.offer(time_us, data[:(len(data) - 1) // 2], None):
                self.cuts_armed -= 1
                self.counts["cut_frame"]["injected"] += 1
                return True
            return False
        return self.transport.offer(time_us, data, frame)

    def _flip(self, data: bytes) -> bytes:
        """One bit flipped inside the frame's COBS bytes, never making a 0x00 (which would split
        the chunk), and never leaving a chunk that still decodes."""
        body = data[:-1]
        while True:
            index = self.rng.randrange(len(body))
            bit = self.rng.randrange(8)
            value = body[index] ^ (1 << bit)
            if value == 0:
                continue
            damaged = body[:index] + bytes([value]) + body[index + 1:]
            try:
                decode_frame(damaged)
            except FrameError:
                return damaged + b"\x00"

    # -- scheduled faults --

    def next_due_us(self) -> float:
        due = [self.pending[0][0]] if self.pending else []
        if self.down_until_us is not None:
            due.append(self.down_until_us)
        return min(due) if due else float("inf")

    def apply_due(self, now_us: int) -> None:
        """Applies everything due at or before now_us, in time order."""
        while self.next_due_us() <= now_us:
            if self.down_until_us is not None and (not self.pending or self.down_until_us <= self.pending[0][0]):
                self._return(self.down_until_us)
                continue
            at_us, _, fault = self.pending.pop(0)
            self._apply(fault, now_us)

    def _apply(self, fault: Fault, now_us: int) -> None:
        p = fault.params
        event = {"t_s": round(now_us / 1e6, 6), "kind": fault.kind, **p}
        counts = self.counts[fault.kind]
        if fault.kind == "garbage":
            garbage = bytes(self.rng.randrange(256) for _ in range(p["bytes"]))
            if self.transport.offer(now_us, garbage, None):
                counts["injected"] += 1
                counts["bytes"] += len(garbage)
        elif fault.kind == "bit_flip":
            self.flips_armed += p["frames"]
        elif fault.kind == "cut_frame":
            self.cuts_armed += p["frames"]
        elif fault.kind == "absurd":
            for _ in range(p["frames"]):
                kind = ABSURD_KINDS[self.absurd_next % len(ABSURD_KINDS)]
                self.absurd_next += 1
                sent_before = self.device.counters["frames_sent"]
                self.device.send_absurd(kind, self.unknown_id)
                if self.device.counters["frames_sent"] > sent_before:
                    counts["injected"] += 1
                    counts[kind] += 1
        elif fault.kind == "vanish":
            if self.down_until_us is not None:
                event["ignored"] = "the device is already gone"
            else:
                counts["injected"] += 1
                counts["seconds"] += p["duration_s"]
                self.down_until_us = now_us + int(round(p["duration_s"] * 1e6))
                self.reboot_on_return = p["reboot"]
                self.transport.go_down(now_us)
        elif fault.kind == "reset":
            counts["injected"] += 1
            self.device.reset(RESET_CAUSES[p["cause"]])
        self.events.append(event)

    def _return(self, at_us: int) -> None:
        self.down_until_us = None
        reboot = self.reboot_on_return
        self.events.append({"t_s": round(at_us / 1e6, 6), "kind": "vanish_end", "reboot": reboot})

        def connected() -> None:
            # as an Arduino Uno does when the host opens its port (DTR): only then it boots
            if reboot:
                self.counts["vanish"]["reboots"] += 1
                self.device.reset(RESET_CAUSES["external"])

        self.transport.come_back(at_us, connected)

    def report(self) -> dict:
        return {"counts": self.counts, "events": self.events,
                "armed_not_applied": {"bit_flip": self.flips_armed, "cut_frame": self.cuts_armed}}
