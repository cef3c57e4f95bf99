"""The simulated device: the CDRO firmware itself (firmware/core, the code the Uno runs), built
for the host (sim/host_device) and driven here in simulated time. Its Pozyx is
sim/pozyx_sim's register model, the one firmware in the loop uses; what that Pozyx
measures comes from the world: where the nodes are (World), what each ranging reports
(UwbModel: noise, NLOS, outliers, dropouts) and what each accelerometer reads.

Nothing of the device is modelled in Python: commands, the schedule, retries and backoff,
motion detection, the reports and their rate limits, the timing of every step are the
firmware's. The runner drives it like the Uno's main loop: next_due_us() says when the
firmware next wants to run, idle_to() lets simulated time pass, run_one() runs one
cdro_fw_step (simulated time moves by what it spends on the I2C bus and in its waits), and
receive() puts host bytes into the serial receive buffer, which the next step reads. Frames go
to a sink at the time the firmware writes them; the sink's room limits what the firmware may
write (it drops and counts what does not fit, as on the Uno).
"""
from __future__ import annotations

import ctypes
import random
from typing import Callable, Protocol

from ..codec import CONSTANTS as C
from ..codec import Frame, FrameError, decode_frame, encode_frame
from . import host_device
from .scenario import Scenario
from .uwb import UwbModel
from .world import World


class Sink(Protocol):
    def offer(self, time_us: int, data: bytes, frame: Frame | None) -> bool:
        """Takes the bytes at time_us; False when the transmit buffer cannot take them whole."""

    def room(self) -> int:
        """Bytes it takes now."""


def status_counter_names() -> list[str]:
    return ["ranges_ok_direct", "ranges_ok_remote", "ranges_failed_direct", "ranges_failed_remote", "retries",
            "bus_errors", "timeouts", "frames_sent", "frames_dropped", "commands_rejected"]


class FirmwareDevice:
    def __init__(self, scenario: Scenario, world: World, uwb: UwbModel, accel_rng: random.Random, sink: Sink,
                 on_frame: Callable[[int, Frame], None] | None = None, seed: int = 0):
        self.lib = host_device.library()
        self.scenario = scenario
        self.world = world
        self.uwb = uwb
        self.accel_rng = accel_rng
        self.sink = sink
        self.on_frame = on_frame
        self.own_id = scenario.own_id
        self._error: BaseException | None = None
        self._callbacks = host_device.Callbacks(
            None, host_device.POSITION_FN(self._guard(self._position)), host_device.ACCEL_FN(self._guard(self._accel)),
            host_device.RANGE_FN(self._guard(self._range)), host_device.ROOM_FN(self._guard(self._room)),
            host_device.WRITE_FN(self._guard(self._write)))
        spec = scenario.device
        config = host_device.Config(seed=seed & 0xFFFFFFFFFFFFFFFF, max_range_m=scenario.uwb.max_range_m,
                                    pozyx_firmware=spec.pozyx_firmware, pozyx_present=int(spec.pozyx_present),
                                    free_ram_bytes=spec.free_ram_bytes)
        self._hd = self.lib.cdro_hd_create(ctypes.byref(config), ctypes.byref(self._callbacks))
        if not self._hd:
            raise MemoryError("cdro_hd_create")
        nodes = [scenario.node(self.own_id)] + [n for n in scenario.nodes if n.id != self.own_id]
        for node in nodes:
            if self.lib.cdro_hd_add_node(self._hd, node.id, int(node.accelerometer)) != 0:
                raise ValueError(f"node 0x{node.id:04X}: the Pozyx model takes no more nodes")
        self.lib.cdro_hd_power_on(self._hd, C["CDRO_RESET_POWER_ON"])

    def __del__(self) -> None:
        hd, self._hd = getattr(self, "_hd", None), None
        if hd:
            self.lib.cdro_hd_destroy(hd)

    # ---- the world, asked by the firmware's Pozyx ---------------------------------------------

    def _guard(self, function):
        """A callback that keeps an exception for _check (ctypes would only print it)."""
        def call(*args):
            try:
                return function(*args)
            except BaseException as error:          # noqa: BLE001 - re-raised after the C call
                if self._error is None:
                    self._error = error
                return 0
        return call

    def _check(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def _position(self, _context, node_id: int, t_s: float, xyz) -> None:
        x, y, z = self.world.position(node_id, t_s)
        xyz[0], xyz[1], xyz[2] = x, y, z

    def _accel(self, _context, node_id: int, t_s: float) -> float:
        return float(self.world.accel_norm_mg(node_id, t_s, self.accel_rng))

    def _range(self, _context, a: int, b: int, t_s: float, distance_mm, rss_dbm) -> int:
        outcome = self.uwb.measure(a, b, t_s)
        if not outcome.ok:
            return outcome.error_code
        distance_mm[0] = outcome.distance_mm
        rss_dbm[0] = outcome.rss_dbm
        return 0

    def _room(self, _context) -> int:
        return max(0, min(0xFFFF, self.sink.room()))

    def _write(self, _context, data, length: int, t_us: int) -> None:
        chunk = ctypes.string_at(data, length)
        frame = None
        if length > 1:
            try:
                frame = decode_frame(chunk[:-1])
            except FrameError:                      # not expected from the firmware's encoder
                frame = None
        if self.sink.offer(t_us, chunk, frame) and frame is not None and self.on_frame:
            self.on_frame(t_us, frame)

    # ---- state -----------------------------------------------------------------------------------

    @property
    def now_us(self) -> int:
        return int(self.lib.cdro_hd_now_us(self._hd))

    @property
    def boot_us(self) -> int:
        return int(self.lib.cdro_hd_boot_us(self._hd))

    def _counters(self) -> host_device.Counters:
        counters = host_device.Counters()
        self.lib.cdro_hd_read_counters(self._hd, ctypes.byref(counters))
        return counters

    @property
    def counters(self) -> dict[str, int]:
        """The firmware's STATUS counters now."""
        c = self._counters()
        return {name: getattr(c, name) for name in status_counter_names()}

    @property
    def boots(self) -> int:
        return self._counters().boots

    @property
    def host_bytes_lost_booting(self) -> int:
        """Host bytes that found the serial receive buffer full (while the firmware boots and
        discovers, it does not read them)."""
        return self._counters().host_bytes_lost

    @property
    def running(self) -> bool:
        return bool(self.lib.cdro_hd_running(self._hd))

    @property
    def booting(self) -> bool:
        """Before HELLO."""
        return self.lib.cdro_hd_state(self._hd) == host_device.constant("STATE_BOOT")

    def flagged_moving(self, node_id: int) -> bool:
        return bool(self.lib.cdro_hd_moving(self._hd, node_id))

    def device_ms(self) -> int:
        return ((self.now_us - self.boot_us) // 1000) & 0xFFFFFFFF

    # ---- the main loop ------------------------------------------------------------------------

    def next_due_us(self) -> int:
        return int(self.lib.cdro_hd_next_due_us(self._hd))

    def idle_to(self, t_us: int) -> None:
        self.lib.cdro_hd_idle_to(self._hd, max(0, int(t_us)))
        self._check()

    def run_one(self) -> None:
        """One cdro_fw_step at the current time (call idle_to first)."""
        self.lib.cdro_hd_step(self._hd)
        self._check()

    def receive(self, data: bytes) -> None:
        """Host bytes into the serial receive buffer (what does not fit is lost)."""
        if data:
            self.lib.cdro_hd_receive(self._hd, data, len(data))

    def reset(self, reset_cause: int) -> None:
        """The Uno resets now: the firmware starts again (sequence and device time from 0, HELLO,
        stopped); the Pozyx network keeps running."""
        self.lib.cdro_hd_power_on(self._hd, reset_cause)

    # ---- fault injection ----------------------------------------------------------------------

    def send_absurd(self, kind: str, unknown_id: int) -> None:
        """A RANGE frame with a valid CRC and absurd content, numbered and counted as the
        firmware's own frames are (it is not a range the network measured)."""
        remote = self.scenario.remote_ids
        own, other = self.own_id, remote[0]
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
        frame = Frame("RANGE", self.lib.cdro_hd_next_sequence(self._hd), fields)
        data = encode_frame(frame)
        sent = len(data) <= self.lib.cdro_hd_tx_free(self._hd) and self.sink.offer(self.now_us, data, frame)
        self._check()
        self.lib.cdro_hd_injected_frame(self._hd, int(sent))
