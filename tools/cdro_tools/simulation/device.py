"""The simulated device: the firmware's side of the link, per docs/protocol.md "Device
behaviour", in simulated time.

The device is a state machine driven from outside, like the firmware's main loop:
next_due_us() says when it next wants to act, idle_to() lets simulated time pass, run_one()
performs one step (a STATUS, a boot step, one accelerometer poll, or one ranging slot with its
retries) and advances the clock by the step's duration, and receive() takes host bytes, which
are handled between steps, as the firmware handles them between Pozyx operations. Frames go to
a sink at the time they are complete; the sink may refuse a frame (transmit buffer full).

Where the contract is silent, this simulator does what the firmware does (firmware/core/src);
what is the simulator's own (timing, the error model) is listed in docs/tools.md.
"""
from __future__ import annotations

import collections
import dataclasses
import random
from typing import Callable, Protocol

from ..codec import CONSTANTS as C
from ..codec import LAYOUT_HASH, PROTOCOL_VERSION, Frame, Result, StreamDecoder, encode_frame
from ..codec.frames import TYPE_IDS
from .scenario import Scenario, Schedule
from .scheduler import Scheduler, backoff_rounds
from .uwb import POZYX_RANGING_FAILED, POZYX_RANGING_TIMEOUT, UwbModel
from .world import ONE_G_MG, World

MOVING_ABOVE_MG = 80          # deviation that makes a still node moving
STILL_BELOW_MG = 40           # deviation a moving node must stay below ...
STILL_SAMPLES = 16            # ... for this many consecutive samples
WINDOW_SAMPLES = 8            # the deviation is the largest |norm - 1 g| over this many samples
MOTION_PERIODIC_US = 5_000_000  # the device-wide PERIODIC MOTION timer
RX_BUFFER_BYTES = 64          # the Uno's serial receive buffer, which holds host bytes during discovery
NODE_ID_UNKNOWN = 0xFFFF      # HELLO.node_id when the Pozyx did not answer (the firmware's choice)
POZYX_FN_DO_RANGING = 0xB5    # ERROR TIMEOUT detail: the function whose wait timed out
HOST_TYPES = {name for name, type_id in TYPE_IDS.items() if type_id >= 0x40}
RATE_LIMITED_ERRORS = ("TIMEOUT", "COMMAND")   # (and BUS, which the simulator has no cause for)


class Sink(Protocol):
    def offer(self, time_us: int, data: bytes, frame: Frame | None) -> bool:
        """Takes the bytes at time_us; False when the transmit buffer cannot take them whole."""


@dataclasses.dataclass
class MotionState:
    next_poll_us: int
    kind_known: bool = False      # remote nodes: learned by the first read that succeeds
    tag: bool = False             # has an accelerometer (once kind_known)
    window_mg: collections.deque = dataclasses.field(default_factory=lambda: collections.deque(maxlen=WINDOW_SAMPLES))
    moving: bool = False
    still_count: int = 0
    has_sample: bool = False      # a good sample since START (or since the node was listed)
    periodic_due: bool = False    # the device-wide timer asks for this node's next sample
    failed_polls: int = 0         # polls in a row that failed (backoff)
    failing: bool = False         # ERROR ACCEL sent for the current streak

    @property
    def polled(self) -> bool:
        return not self.kind_known or self.tag


def status_counter_names() -> list[str]:
    return ["ranges_ok_direct", "ranges_ok_remote", "ranges_failed_direct", "ranges_failed_remote", "retries",
            "bus_errors", "timeouts", "frames_sent", "frames_dropped", "commands_rejected"]


class SimDevice:
    def __init__(self, scenario: Scenario, world: World, uwb: UwbModel, accel_rng: random.Random, sink: Sink,
                 on_frame: Callable[[int, Frame], None] | None = None):
        self.scenario = scenario
        self.world = world
        self.uwb = uwb
        self.accel_rng = accel_rng
        self.sink = sink
        self.on_frame = on_frame
        self.own_id = scenario.own_id
        self.spec = scenario.device
        # what the device calls its own node: the Pozyx's id, or 0xFFFF when it did not answer
        self.node_id = self.own_id if self.spec.pozyx_present else NODE_ID_UNKNOWN
        self.now_us = 0
        self.boots = 0
        self.host_bytes_lost_booting = 0   # host bytes before HELLO, or beyond the receive buffer
        self._power_on(0, C["CDRO_RESET_POWER_ON"])

    # ---- boot ------------------------------------------------------------------------------

    def _power_on(self, t_us: int, reset_cause: int) -> None:
        self.now_us = max(self.now_us, t_us)
        self.boot_us = self.now_us
        self.boots += 1
        self.reset_cause = reset_cause
        self.sequence = 0
        self.counters = dict.fromkeys(status_counter_names(), 0)
        self.longest_step_us = 0
        self.running = False
        self.nodes: list[int] = []
        self.node_source = C["CDRO_NODE_SOURCE_DISCOVERY"]   # of the node list, sent again after HELLO_REQUEST
        self.schedule = Schedule()
        self.scheduler = Scheduler()
        self.scheduler.configure(self.schedule.mode, self.schedule.moving_boost)
        self.scheduler.set_nodes(self.own_id, [])
        self.decoder = StreamDecoder()
        self.motion: dict[int, MotionState] = {}
        self.next_periodic_us = 0
        self.next_slot_us = 0
        self.dropped_unreported = 0
        self.unreported_errors: dict[str, int] = {}    # rate-limited ERROR kind -> detail of its last occurrence
        self.next_error_report_us = dict.fromkeys(RATE_LIMITED_ERRORS, 0)
        self.next_status_us: int | None = None
        self.rx_backlog = bytearray()
        hello_us = self.boot_us + int(self.spec.boot_ms * 1000)
        self.boot_steps: list[tuple[int, str]] = [(hello_us, "hello")]
        if self.spec.pozyx_present and self.spec.discovery:
            self.boot_steps.append((hello_us + int(self.spec.discovery_ms * 1000), "discovery"))

    def reset(self, reset_cause: int) -> None:
        """A firmware reset now: sequence and device time restart, HELLO again, stopped."""
        self._power_on(self.now_us, reset_cause)

    @property
    def booting(self) -> bool:
        """Before HELLO: the firmware is not running, host bytes are lost."""
        return bool(self.boot_steps) and self.boot_steps[0][1] == "hello"

    @property
    def discovering(self) -> bool:
        """Between HELLO and the discovery's NODE_LIST: host bytes wait in the receive buffer."""
        return bool(self.boot_steps) and self.boot_steps[0][1] == "discovery"

    def device_ms(self) -> int:
        return ((self.now_us - self.boot_us) // 1000) & 0xFFFFFFFF

    def capabilities(self) -> int:
        if not self.spec.pozyx_present:
            return 0
        caps = C["CDRO_CAP_DIRECT_RANGING"] | C["CDRO_CAP_REMOTE_RANGING"]
        if self.world.nodes[self.own_id].accelerometer:
            caps |= C["CDRO_CAP_LOCAL_ACCEL"]
        if any(n.accelerometer for n in self.scenario.nodes if n.id != self.own_id):
            caps |= C["CDRO_CAP_REMOTE_ACCEL"]
        if self.spec.discovery:
            caps |= C["CDRO_CAP_DISCOVERY"]
        return caps

    def _hello(self) -> None:
        self._send("HELLO", {
            "device_time_ms": self.device_ms(), "firmware_version": self.spec.firmware_version,
            "protocol_version": PROTOCOL_VERSION, "layout_hash": LAYOUT_HASH, "node_id": self.node_id,
            "capabilities": self.capabilities(),
            "pozyx_firmware": self.spec.pozyx_firmware if self.spec.pozyx_present else 0,
            "max_nodes": self.spec.max_nodes, "reset_cause": self.reset_cause, "pozyx_tries": 1})

    def _boot_step(self, step: str) -> None:
        if step == "hello":
            self._offer(b"\x00", None)
            self._hello()
            if not self.spec.pozyx_present:
                self._error(C["CDRO_DEVICE_ERROR_POZYX_ABSENT"], 0, 0)   # silent on the bus: detail 0
            self.next_status_us = self.now_us + self.schedule.status_period_ms * 1000
        else:
            t_s = self.now_us / 1e6
            found = sorted(n.id for n in self.scenario.nodes
                           if n.id != self.own_id and self.uwb.reachable(self.own_id, n.id, t_s))
            if found:
                self._set_nodes(found[:self.spec.max_nodes])
                self._send_node_list(C["CDRO_NODE_SOURCE_DISCOVERY"])
            backlog, self.rx_backlog = bytes(self.rx_backlog), bytearray()
            self.receive(backlog)

    # ---- sending ---------------------------------------------------------------------------

    def _send_node_list(self, source: int) -> None:
        self.node_source = source
        self._send("NODE_LIST", {"source": source, "node_ids": self.nodes})

    def _offer(self, data: bytes, frame: Frame | None) -> bool:
        return self.sink.offer(self.now_us, data, frame)

    def _send(self, frame_type: str, fields: dict) -> bool:
        frame = Frame(frame_type, self.sequence, fields)
        self.sequence = (self.sequence + 1) & 0xFFFF     # a dropped frame uses its number too
        if not self._offer(encode_frame(frame), frame):
            self.counters["frames_dropped"] += 1
            self.dropped_unreported += 1
            return False
        self.counters["frames_sent"] += 1
        if self.on_frame:
            self.on_frame(self.now_us, frame)
        if self.dropped_unreported and frame_type != "ERROR":
            count, self.dropped_unreported = self.dropped_unreported, 0
            if not self._error(C["CDRO_DEVICE_ERROR_TX_OVERFLOW"], min(count, 0xFFFF), 0):
                self.dropped_unreported += count
        return True

    def _error(self, code: int, detail: int, node_id: int) -> bool:
        return self._send("ERROR", {"device_time_ms": self.device_ms(), "code": code, "detail": detail & 0xFFFF,
                                    "node_id": node_id})

    def _note_error(self, kind: str, detail: int) -> None:
        """An occurrence of a rate-limited ERROR kind; _report_errors sends it when it may."""
        self.unreported_errors[kind] = detail

    def _report_errors(self) -> None:
        """ERROR TIMEOUT and COMMAND, each at most once per status period (the firmware's
        report_errors, after the host bytes of every step)."""
        for kind in RATE_LIMITED_ERRORS:
            if kind in self.unreported_errors and self.now_us >= self.next_error_report_us[kind]:
                self.next_error_report_us[kind] = self.now_us + self.schedule.status_period_ms * 1000
                self._error(C[f"CDRO_DEVICE_ERROR_{kind}"], self.unreported_errors.pop(kind), 0)

    def send_absurd(self, kind: str, unknown_id: int) -> None:
        """A RANGE frame with a valid CRC and absurd content (fault injection)."""
        own, other = self.own_id, (self.nodes[0] if self.nodes else self.scenario.remote_ids[0])
        fields = {"device_time_ms": self.device_ms(), "from_id": own, "to_id": other, "distance_mm": 4000,
                  "rss_dbm": -80, "flags": 0}
        if kind == "distance":
            fields["distance_mm"] = 167772160
        elif kind == "self_range":
            fields["to_id"] = own
        elif kind == "unknown_node":
            fields["to_id"] = unknown_id
        else:
            raise ValueError(kind)
        on_frame, self.on_frame = self.on_frame, None     # not a range the network measured
        try:
            self._send("RANGE", fields)
        finally:
            self.on_frame = on_frame

    # ---- the main loop, one step at a time ---------------------------------------------------

    def _polled(self) -> list[tuple[int, MotionState]]:
        return [(node_id, state) for node_id, state in self.motion.items() if state.polled]

    def next_due_us(self) -> int:
        if self.boot_steps:
            return self.boot_steps[0][0]
        due = [self.next_status_us]
        if self.running:
            if self.scheduler.pairs():
                due.append(self.next_slot_us)
            polled = self._polled()
            if self.schedule.motion_poll_ms and polled:
                due.append(min(state.next_poll_us for _, state in polled))
        return min(due)

    def idle_to(self, t_us: int) -> None:
        if t_us > self.now_us:
            self.now_us = t_us

    def run_one(self) -> None:
        """One step of the main loop: the most urgent thing that is due (call idle_to first)."""
        start_us = self.now_us
        if self.boot_steps and self.boot_steps[0][0] <= self.now_us:
            self._boot_step(self.boot_steps.pop(0)[1])
            self.longest_step_us = max(self.longest_step_us, self.now_us - start_us)
            return
        self._report_errors()
        polled = self._polled()
        if self.next_status_us is not None and self.next_status_us <= self.now_us:
            self._status()
        elif (self.running and self.schedule.motion_poll_ms and polled
              and min(state.next_poll_us for _, state in polled) <= self.now_us):
            self._poll_one()
        elif self.running and self.scheduler.pairs() and self.next_slot_us <= self.now_us:
            self._slot()
        else:
            raise RuntimeError(f"run_one at {self.now_us} us with nothing due (next {self.next_due_us()} us)")
        self.longest_step_us = max(self.longest_step_us, self.now_us - start_us)

    def _status(self) -> None:
        fields = {"uptime_ms": self.device_ms(), **self.counters, "longest_loop_us": self.longest_step_us,
                  "free_ram_bytes": self.spec.free_ram_bytes, "running": int(self.running),
                  "node_count": len(self.nodes), "bus_recoveries": 0}
        self.next_status_us = self.now_us + self.schedule.status_period_ms * 1000
        self._send("STATUS", fields)
        self.longest_step_us = 0

    # ---- motion -----------------------------------------------------------------------------

    def _accel_candidates(self) -> list[int]:
        """The own node if it has an accelerometer, and every listed node (whose kind the first
        poll asks: anchors are then left alone)."""
        if not self.spec.pozyx_present:
            return []
        own = [self.own_id] if self.world.has(self.own_id) and self.world.nodes[self.own_id].accelerometer else []
        return own + list(self.nodes)

    def _restart_motion(self, keep: set[int] = frozenset()) -> None:
        """Fresh motion states (still, first sample to come) for every node but those in keep;
        the polls of new ones are staggered over one period."""
        ids = self._accel_candidates()
        period_us = self.schedule.motion_poll_ms * 1000
        old = self.motion
        self.motion = {}
        for index, node_id in enumerate(ids):
            state = old.get(node_id) if node_id in keep else None
            if state is None:
                state = MotionState(next_poll_us=self.now_us + index * period_us // max(1, len(ids)),
                                    kind_known=node_id == self.own_id, tag=node_id == self.own_id)
            self.motion[node_id] = state

    def flagged_moving(self, node_id: int) -> bool:
        state = self.motion.get(node_id)
        return bool(state and state.moving)

    def _remote_read(self, node_id: int) -> int:
        """One remote register read over UWB: the Pozyx error code, 0 when it succeeded."""
        self.now_us += self.uwb.operation_us("remote_accel")
        if not self.uwb.reachable(self.own_id, node_id, self.now_us / 1e6):
            return POZYX_RANGING_TIMEOUT
        return POZYX_RANGING_FAILED if self.uwb.dropout() else 0

    def _poll_one(self) -> None:
        node_id, state = min(self._polled(), key=lambda item: item[1].next_poll_us)  # list order on ties
        if self.now_us >= self.next_periodic_us:     # the device-wide timer: every node's next sample
            for other in self.motion.values():
                other.periodic_due = True
            self.next_periodic_us = self.now_us + MOTION_PERIODIC_US
        period_us = self.schedule.motion_poll_ms * 1000
        code = 0
        if node_id == self.own_id:
            self.now_us += self.uwb.operation_us("local_accel")
        else:
            if not state.kind_known:                  # HARDWARE_VER first: is it a tag?
                code = self._remote_read(node_id)
                if not code:
                    state.kind_known = True
                    state.tag = self.world.has(node_id) and self.world.nodes[node_id].accelerometer
            if not code and state.tag:
                code = self._remote_read(node_id)
        while state.next_poll_us <= self.now_us:
            state.next_poll_us += period_us
        if code:
            state.failed_polls += 1
            state.next_poll_us += backoff_rounds(state.failed_polls) * period_us
            if not state.failing:                     # once per streak of failed reads
                state.failing = True
                self._error(C["CDRO_DEVICE_ERROR_ACCEL"], code, node_id)
            return
        state.failed_polls, state.failing = 0, False
        if not state.tag:
            return                                    # an anchor: never polled again
        norm_mg = self.world.accel_norm_mg(node_id, self.now_us / 1e6, self.accel_rng)
        state.window_mg.append(abs(norm_mg - ONE_G_MG))
        deviation_mg = int(round(max(state.window_mg)))
        state.still_count = min(state.still_count + 1, STILL_SAMPLES) if deviation_mg < STILL_BELOW_MG else 0
        changed = False
        if not state.moving and deviation_mg > MOVING_ABOVE_MG:
            state.moving = changed = True
        elif state.moving and state.still_count >= STILL_SAMPLES:
            state.moving, changed = False, True
        if changed or not state.has_sample or state.periodic_due:
            reason = C["CDRO_MOTION_REASON_CHANGE"] if changed else C["CDRO_MOTION_REASON_PERIODIC"]
            self._send("MOTION", {"device_time_ms": self.device_ms(), "node_id": node_id, "moving": int(state.moving),
                                  "accel_norm_mg": min(norm_mg, C["CDRO_MAX_ACCEL_MG"]),
                                  "deviation_mg": min(deviation_mg, 0xFFFF), "reason": reason})
        state.has_sample, state.periodic_due = True, False

    # ---- ranging ----------------------------------------------------------------------------

    def pairs(self) -> list[tuple[int, int]]:
        return self.scheduler.pairs()

    def _slot(self) -> None:
        p = self.scheduler.next(self.flagged_moving)
        if p is None:
            return
        a, b = self.scheduler.pairs()[p]
        slot_start_us = self.now_us
        remote = a != self.own_id
        kind = "remote" if remote else "direct"
        ok = False
        for attempt in range(self.schedule.max_retries + 1):
            if attempt:
                self.counters["retries"] += 1
            moving = self.flagged_moving(a) or self.flagged_moving(b)
            outcome = self.uwb.measure(a, b, self.now_us / 1e6, remote)
            self.now_us += outcome.duration_us
            if outcome.ok:
                ok = True
                self.counters[f"ranges_ok_{kind}"] += 1
                flags = ((C["CDRO_RANGE_FLAG_REMOTE"] if remote else 0) | (C["CDRO_RANGE_FLAG_RETRY"] if attempt else 0)
                         | (C["CDRO_RANGE_FLAG_MOVING"] if moving else 0))
                self._send("RANGE", {"device_time_ms": self.device_ms(), "from_id": a, "to_id": b,
                                     "distance_mm": outcome.distance_mm, "rss_dbm": outcome.rss_dbm, "flags": flags})
                break
            self.counters[f"ranges_failed_{kind}"] += 1
            detail = outcome.error_code
            if remote and outcome.error_code == POZYX_RANGING_TIMEOUT:
                # the firmware's wait for the result message expired: a timeout, no Pozyx error code
                self.counters["timeouts"] += 1
                self._note_error("TIMEOUT", POZYX_FN_DO_RANGING)
                detail = 0
            if self.scheduler.attempt_failed(p):
                self._error(C["CDRO_DEVICE_ERROR_RANGING"], detail, b)
        self.scheduler.slot_done(p, ok)
        period_us = self.schedule.slot_period_ms * 1000
        self.next_slot_us = slot_start_us + period_us if period_us else self.now_us

    # ---- commands ---------------------------------------------------------------------------

    def _set_nodes(self, ids: list[int]) -> None:
        """A new node list: pair states cleared, the round restarts; listed nodes start still
        (their first sample reported PERIODIC), the own node keeps its motion state."""
        self.nodes = list(ids)
        self.scheduler.set_nodes(self.own_id, self.nodes)
        self._restart_motion(keep={self.own_id})

    def receive(self, data: bytes) -> None:
        """Host bytes, handled now (between steps)."""
        if self.booting:
            self.host_bytes_lost_booting += len(data)
            return
        if self.discovering:
            room = RX_BUFFER_BYTES - len(self.rx_backlog)
            self.rx_backlog += data[:room]
            self.host_bytes_lost_booting += max(0, len(data) - room)
            return
        for event in self.decoder.feed(data):
            self._command(event)
        self._report_errors()

    def _nack(self, frame: Frame, reason: str) -> None:
        self.counters["commands_rejected"] += 1
        self._send("NACK", {"nacked_type": frame.type_id, "nacked_sequence": frame.sequence,
                            "reason": C[f"CDRO_NACK_{reason}"]})

    def _ack(self, frame: Frame, value: int = 0) -> None:
        self._send("ACK", {"acked_type": frame.type_id, "acked_sequence": frame.sequence, "value": value})

    def _command(self, event) -> None:
        """One host chunk, answered as the firmware's handle_chunk does."""
        frame, result = event.frame, event.result
        if frame is None or result not in (Result.OK, Result.VERSION, Result.LENGTH, Result.TYPE, Result.VALUE):
            # COBS, CRC, too short or too long: cannot be trusted to say what it was
            self.counters["commands_rejected"] += 1
            self._note_error("COMMAND", int(result))      # detail: the cdro_result_t, two's complement
            return
        if result in (Result.VERSION, Result.LENGTH):
            return self._nack(frame, "MALFORMED")
        if result == Result.TYPE or frame.type not in HOST_TYPES:
            return self._nack(frame, "UNKNOWN_TYPE")     # a device-to-host type, whatever its values
        if result == Result.VALUE:
            return self._nack(frame, "BAD_VALUE")
        f = frame.fields
        if frame.type == "SET_NODES":
            if len(f["node_ids"]) > self.spec.max_nodes:
                return self._nack(frame, "TOO_MANY_NODES")
            if self.node_id in f["node_ids"]:
                return self._nack(frame, "BAD_VALUE")
            self._ack(frame)
            self._set_nodes(f["node_ids"])
            self._send_node_list(C["CDRO_NODE_SOURCE_HOST"])
        elif frame.type == "SET_SCHEDULE":
            self._ack(frame)
            old_status_ms = self.schedule.status_period_ms
            self.schedule = Schedule(**f)
            if self.schedule.status_period_ms != old_status_ms:
                self.next_status_us = self.now_us + self.schedule.status_period_ms * 1000
            self.scheduler.configure(self.schedule.mode, self.schedule.moving_boost)
        elif frame.type == "START":
            if not self.nodes or not self.spec.pozyx_present:
                return self._nack(frame, "WRONG_STATE")
            self._ack(frame)
            if not self.running:
                self.running = True
                self.next_slot_us = self.now_us
                self.next_periodic_us = self.now_us + MOTION_PERIODIC_US
                for state in self.motion.values():        # motion state is kept across STOP/START;
                    state.periodic_due = True             # each node's first sample is reported
        elif frame.type == "STOP":
            self._ack(frame)
            self.running = False
        elif frame.type == "PING":
            self._ack(frame, f["nonce"])
        elif frame.type in ("SET_UWB", "DIAGNOSE"):
            # No Pozyx settings to set or bench items to measure (no CDRO_CAP_POZYX_SETUP).
            return self._nack(frame, "UNKNOWN_TYPE")
        elif frame.type == "HELLO_REQUEST":
            # A host that opened the link of a running device has seen neither the boot HELLO
            # nor the node list: both again (docs/protocol.md, "Commands").
            self._hello()
            if self.nodes:
                self._send_node_list(self.node_source)
