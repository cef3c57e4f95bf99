"""Running a scenario: offline (simulated time, as fast as possible: CSV files and capture
files) or live (a pseudo-terminal acting as the device, at a speed factor of real time or as
fast as the reader takes the bytes)."""
from __future__ import annotations

import collections
import dataclasses
import random
import select
import sys
import time
from typing import Callable

from ..codec import CaptureWriter, Frame, StreamDecoder, encode_frame
from ..codec.capture_file import FLAG_TO_DEVICE
from ..codec.frames import COUNTER_NAMES
from .device import FirmwareDevice
from .faults import FaultLink
from .link import Chunker, PtyLink
from .scenario import Scenario
from .uwb import UwbModel
from .world import World

HOST_REACTION_US = 50_000      # the simulated host answers a HELLO after 50 ms
READER_GRACE_S = 0.1           # after a reader opens the link, before the first byte (pyserial flushes on open)


def streams(seed: int) -> dict[str, random.Random]:
    """Independent random streams, one per concern, all fixed by the seed."""
    names = ("links", "ranges", "accel", "odometry", "faults")
    return {name: random.Random(f"cdro-sim:{seed}:{name}") for name in names}


class Tally:
    """What a host decoder counts for the bytes that reached it; a new decoder per connection."""

    def __init__(self) -> None:
        self.total = dict.fromkeys(COUNTER_NAMES, 0)
        self.decoder = StreamDecoder()
        self.connections = 1
        self.frames_by_type: collections.Counter = collections.Counter()

    def feed(self, data: bytes) -> None:
        for event in self.decoder.feed(data):
            if event.frame is not None and str(event.result) == "ok":
                self.frames_by_type[event.frame.type] += 1

    def new_connection(self) -> None:
        for name, value in self.decoder.counters.items():
            self.total[name] += value
        self.decoder = StreamDecoder()
        self.connections += 1

    def counters(self) -> dict:
        out = {name: self.total[name] + self.decoder.counters[name] for name in COUNTER_NAMES}
        out["frames_by_type"] = dict(sorted(self.frames_by_type.items()))
        out["connections"] = self.connections
        return out


@dataclasses.dataclass
class LinkStats:
    bytes_delivered: int = 0
    frames_lost_while_gone: int = 0   # frames the device sent while the link was gone
    bytes_lost_while_gone: int = 0
    bytes_unread_at_vanish: int = 0   # left in the pseudo-terminal when it vanished (live mode)
    host_bytes: int = 0               # bytes the host sent


class Simulation:
    """The pieces every mode shares: world, error model, device, faults; and the logs the CSV
    outputs are made of."""

    def __init__(self, scenario: Scenario, seed: int, transport, faults_enabled: bool = True):
        self.scenario = scenario
        self.seed = seed
        self.rng = streams(seed)
        self.world = World(scenario)
        self.uwb = UwbModel(scenario, self.world, self.rng["links"], self.rng["ranges"])
        self.ranges: list[tuple[int, int, int, int]] = []     # (t_us, from, to, distance_mm)
        self.transport = transport
        faults = scenario.faults if faults_enabled else []
        self.faults = FaultLink(faults, self.rng["faults"], transport, {n.id for n in scenario.nodes})
        self.device: FirmwareDevice | None = None

    def power_on(self) -> FirmwareDevice:
        self.device = FirmwareDevice(self.scenario, self.world, self.uwb, self.rng["accel"], self.faults,
                                     self._on_frame, self.seed)
        self.faults.device = self.device
        return self.device

    def _on_frame(self, time_us: int, frame: Frame) -> None:
        if frame.type == "RANGE":
            f = frame.fields
            self.ranges.append((time_us, f["from_id"], f["to_id"], f["distance_mm"]))

    def next_event_us(self) -> float:
        return min(self.device.next_due_us(), self.faults.next_due_us())

    def step(self) -> None:
        """The next thing in time order: a fault, or a device step."""
        if self.faults.next_due_us() <= self.device.next_due_us():
            self.device.idle_to(int(self.faults.next_due_us()))
            self.faults.apply_due(self.device.now_us)
        else:
            self.device.idle_to(self.device.next_due_us())
            self.device.run_one()


# ---- offline --------------------------------------------------------------------------------

class OfflineTransport:
    """Everything the device sends reaches the simulated host, except while the device is gone."""

    def __init__(self, writer: CaptureWriter | None, epoch_us: int):
        self.rx = Chunker(writer)
        self.tx = Chunker(writer, FLAG_TO_DEVICE)
        self.epoch_us = epoch_us
        self.up = True
        self.tally = Tally()
        self.stats = LinkStats()
        self.on_delivered: Callable[[int, Frame], None] | None = None

    def room(self) -> int:
        return 0xFFFF

    def offer(self, time_us: int, data: bytes, frame: Frame | None) -> bool:
        if not self.up:
            self.stats.frames_lost_while_gone += frame is not None
            self.stats.bytes_lost_while_gone += len(data)
            return True
        self.rx.feed(self.epoch_us + time_us, data)
        self.tally.feed(data)
        self.stats.bytes_delivered += len(data)
        if frame is not None and self.on_delivered:
            self.on_delivered(time_us, frame)
        return True

    def go_down(self, time_us: int) -> None:
        self.up = False

    def come_back(self, time_us: int, connected: Callable[[], None]) -> None:
        self.up = True
        self.tally.new_connection()
        connected()


class ScriptedHost:
    """The host side of an offline run: configures the device after every HELLO (at boot and
    after a reset) with the scenario's nodes (as many as HELLO.max_nodes says the device takes),
    the scenario's schedule, and START."""

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        self.sequence = 0
        self.due_us: int | None = None
        self.max_nodes = 0

    def on_frame(self, time_us: int, frame: Frame) -> None:
        if frame.type == "HELLO":
            self.due_us = time_us + HOST_REACTION_US
            self.max_nodes = frame.fields["max_nodes"]

    def next_due_us(self) -> float:
        return float("inf") if self.due_us is None else self.due_us

    def commands(self) -> list[bytes]:
        self.due_us = None
        ids = self.scenario.remote_ids[:self.max_nodes]
        frames = [Frame("SET_NODES", 0, {"node_ids": ids}),
                  Frame("SET_SCHEDULE", 0, self.scenario.schedule.fields()),
                  Frame("START", 0, {})]
        out = []
        for frame in frames:
            frame.sequence = self.sequence
            self.sequence = (self.sequence + 1) & 0xFFFF
            out.append(encode_frame(frame))
        return out


def run_offline(scenario: Scenario, seed: int, duration_s: float, capture_path: str | None = None,
                faults_enabled: bool = True, source: str = "") -> Simulation:
    """Runs the whole scenario in simulated time; returns the simulation with its logs."""
    epoch_us = int(round(scenario.epoch_unix_s * 1e6))
    writer = (CaptureWriter(capture_path, source or f"sim:{scenario.name} seed {seed}", epoch_us)
              if capture_path else None)
    transport = OfflineTransport(writer, epoch_us)
    sim = Simulation(scenario, seed, transport, faults_enabled)
    host = ScriptedHost(scenario)
    transport.on_delivered = host.on_frame
    device = sim.power_on()
    end_us = int(round(duration_s * 1e6))
    try:
        while True:
            t_host = host.next_due_us()
            if min(t_host, sim.next_event_us()) > end_us:
                break
            if t_host <= sim.next_event_us():
                device.idle_to(int(t_host))
                for command in host.commands():
                    transport.tx.feed(epoch_us + device.now_us, command)
                    transport.stats.host_bytes += len(command)
                    device.receive(command)
            else:
                sim.step()
    finally:
        if writer is not None:
            transport.rx.finish(epoch_us + device.now_us)
            writer.close()
    return sim


# ---- live: a pseudo-terminal ----------------------------------------------------------------

class LiveTransport:
    """Frames wait in a transmit queue until their time (scaled to wall time), then go to the
    pseudo-terminal. In real-time mode the queue holds at most tx_buffer_bytes; a frame that does
    not fit is refused (the device counts it dropped). In max mode there is no limit: the device
    only runs when the reader has taken everything."""

    def __init__(self, link: PtyLink, capacity_bytes: int | None, writer: CaptureWriter | None,
                 log: Callable[[str], None]):
        self.link = link
        self.capacity_bytes = capacity_bytes
        self.queue: collections.deque = collections.deque()    # [time_us, bytes]
        self.queued_bytes = 0
        self.rx = Chunker(writer)
        self.tx = Chunker(writer, FLAG_TO_DEVICE)
        self.tally = Tally()
        self.stats = LinkStats()
        self.log = log
        self.state = "waiting"        # waiting for a reader, "up", or "gone"
        self.connected: Callable[[], None] | None = None
        self.reader_seen_at: float | None = None

    @property
    def up(self) -> bool:
        return self.state == "up"

    def room(self) -> int:
        if not self.up or self.capacity_bytes is None:
            return 0xFFFF
        return max(0, self.capacity_bytes - self.queued_bytes)

    def offer(self, time_us: int, data: bytes, frame: Frame | None) -> bool:
        if not self.up:
            self.stats.frames_lost_while_gone += frame is not None
            self.stats.bytes_lost_while_gone += len(data)
            return True
        if self.capacity_bytes is not None and self.queued_bytes + len(data) > self.capacity_bytes:
            return False
        self.queue.append([time_us, data])
        self.queued_bytes += len(data)
        return True

    def due_output(self, sim_now_us: float | None) -> bool:
        return bool(self.queue) and (sim_now_us is None or self.queue[0][0] <= sim_now_us)

    def pump(self, sim_now_us: float | None) -> None:
        """Writes what is due (everything when sim_now_us is None) as far as the terminal takes it."""
        while self.up and self.due_output(sim_now_us):
            item = self.queue[0]
            written = self.link.write(item[1])
            if written:
                chunk = item[1][:written]
                self.rx.feed(time.time_ns() // 1000, chunk)
                self.tally.feed(chunk)
                self.stats.bytes_delivered += written
                self.queued_bytes -= written
                item[1] = item[1][written:]
            if item[1]:
                return                          # the terminal is full
            self.queue.popleft()

    def go_down(self, time_us: int) -> None:
        self.pump(time_us)
        self.stats.bytes_unread_at_vanish += self.link.wait_drained(1.0)
        self.stats.bytes_lost_while_gone += self.queued_bytes
        self.queue.clear()
        self.queued_bytes = 0
        self.link.close()
        self.state = "gone"
        self.log(f"device gone: {self.link.link_path} removed")

    def come_back(self, time_us: int, connected: Callable[[], None]) -> None:
        slave = self.link.create()
        self.tally.new_connection()
        self.state = "waiting"
        self.connected = connected
        self.reader_seen_at = None
        self.log(f"device back at {self.link.link_path} -> {slave}; waiting for a reader")

    def poll_reader(self) -> bool:
        """In state waiting: True once a reader has had the link open for READER_GRACE_S."""
        if self.state != "waiting" or not self.link.reader_present():
            self.reader_seen_at = None if self.state == "waiting" else self.reader_seen_at
            return False
        now = time.monotonic()
        if self.reader_seen_at is None:
            self.reader_seen_at = now
        if now - self.reader_seen_at < READER_GRACE_S:
            return False
        self.link.hold()
        self.state = "up"
        if self.connected:
            connected, self.connected = self.connected, None
            connected()
        return True


class LiveRunner:
    def __init__(self, scenario: Scenario, seed: int, link_path: str, speed: float | None, duration_s: float,
                 hold: bool, capture_path: str | None, faults_enabled: bool, log: Callable[[str], None],
                 stop: Callable[[], bool]):
        self.scenario = scenario
        self.speed = speed                      # None: as fast as the reader takes the bytes
        self.end_us = int(round(duration_s * 1e6))
        self.hold = hold
        self.log = log
        self.stop = stop
        self.link = PtyLink(link_path)
        self.writer = (CaptureWriter(capture_path, f"sim:pty:{link_path} {scenario.name} seed {seed}")
                       if capture_path else None)
        capacity = scenario.device.tx_buffer_bytes if speed is not None else None
        self.transport = LiveTransport(self.link, capacity, self.writer, log)
        self.sim = Simulation(scenario, seed, self.transport, faults_enabled)
        self.anchor_sim_us = 0.0
        self.anchor_wall_s = 0.0
        self.ended_by = ""

    # simulated time now, from the wall clock
    def sim_now_us(self) -> float:
        rate = self.speed if self.speed is not None else 1.0
        return self.anchor_sim_us + (time.monotonic() - self.anchor_wall_s) * rate * 1e6

    def reanchor(self) -> None:
        self.anchor_sim_us = float(self.sim.device.now_us) if self.sim.device else 0.0
        self.anchor_wall_s = time.monotonic()

    def paced(self) -> bool:
        """Max mode runs at real time while nothing streams: stopped, booting, or gone."""
        device = self.sim.device
        return self.speed is not None or not device.running or device.booting or not self.transport.up

    def run(self) -> None:
        slave = self.link.create()
        print(f"{self.link.link_path} {slave}", flush=True)         # for scripts: the link is ready
        self.log(f"device at {self.link.link_path} -> {slave}; it powers on when a reader opens it")
        try:
            self._wait_first_reader()
            if self.sim.device is not None:
                self._loop()
        finally:
            self._finish()

    def _wait_first_reader(self) -> None:
        def connected() -> None:
            self.sim.power_on()
            self.reanchor()
            self.log("reader connected; device powered on")
        self.transport.connected = connected
        while not self.stop():
            if self.transport.poll_reader():
                return
            time.sleep(0.01)
        self.ended_by = "signal"

    def _loop(self) -> None:
        sim, device, transport = self.sim, self.sim.device, self.transport
        while True:
            if self.stop():
                self.ended_by = "signal"
                return
            if transport.state == "waiting" and transport.poll_reader():
                self.reanchor()
            if transport.up:
                data = self.link.read()       # every turn, so that commands never wait for a stream
                if data:
                    if self.paced():
                        device.idle_to(int(min(self.sim_now_us(), sim.next_event_us())))
                    transport.tx.feed(time.time_ns() // 1000, data)
                    transport.stats.host_bytes += len(data)
                    device.receive(data)
            transport.pump(self.sim_now_us() if self.speed is not None else None)
            t_next = sim.next_event_us()
            ended = not self.hold and (device.now_us >= self.end_us or t_next > self.end_us)
            if ended and (not transport.queue or not transport.up):
                self.ended_by = "end of scenario"
                return
            if not ended:
                was_paced = self.paced()
                runnable = self.sim_now_us() >= t_next if was_paced else not transport.queue
                if runnable:
                    sim.step()
                    if self.speed is None and not (was_paced and self.paced()):
                        self.reanchor()
                    continue
            self._wait(t_next)

    def _wait(self, t_next: float) -> None:
        transport = self.transport
        timeout_s = 0.1
        rate = self.speed if self.speed is not None else 1.0
        if self.paced() and t_next != float("inf"):
            timeout_s = min(timeout_s, max(0.0, (t_next - self.sim_now_us()) / rate / 1e6))
        if self.speed is not None and transport.queue and transport.up:
            timeout_s = min(timeout_s, max(0.0, (transport.queue[0][0] - self.sim_now_us()) / rate / 1e6))
        if transport.state == "waiting":
            timeout_s = min(timeout_s, 0.01)
        readers = [self.link.master] if transport.up else []
        writers = [self.link.master] if transport.up and transport.due_output(
            self.sim_now_us() if self.speed is not None else None) else []
        if readers or writers:
            select.select(readers, writers, [], timeout_s)
        else:
            time.sleep(timeout_s)

    def _finish(self) -> None:
        transport = self.transport
        if self.ended_by == "end of scenario" and transport.up:
            transport.pump(None)
            deadline = time.monotonic() + 2.0
            while transport.queue and time.monotonic() < deadline and not self.stop():
                select.select([], [self.link.master], [], 0.05)
                transport.pump(None)
            self.link.wait_drained(2.0, self.stop)
        now_us = time.time_ns() // 1000
        if self.writer is not None:
            transport.rx.finish(now_us)
            transport.tx.finish(now_us)
            self.writer.close()
        self.link.close()


def print_to_stderr(prefix: str) -> Callable[[str], None]:
    def log(message: str) -> None:
        print(f"{prefix}: {message}", file=sys.stderr, flush=True)
    return log
