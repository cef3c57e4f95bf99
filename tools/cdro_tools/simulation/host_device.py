"""The CDRO firmware built for the host (sim/host_device: libcdro_host_device.so), loaded
with ctypes: firmware/core as the Uno runs it, against sim/pozyx_sim's Pozyx register
model, with the world answering through callbacks. See sim/host_device/include/
cdro_host_device/host_device.h for the C side.

The library is found, in this order, at $CDRO_HOST_DEVICE_LIB, in $CDRO_BUILD_DIR/lib, in the
repository's build/lib (an editable install), and next to an installed environment
(PREFIX/lib/cdro, where `cmake --install` puts it). A sanitizer build's is passed over (ASan
cannot be loaded into Python), and so is a candidate that does not load. Loading checks that the
Structures below have the sizes and field offsets of the C structs they mirror (LayoutMismatch).
"""
from __future__ import annotations

import ctypes
import functools
import os
import pathlib
import sys

LIBRARY = "libcdro_host_device.so"
BUILD_COMMAND = "cmake -S . -B build -G Ninja && cmake --build build --target cdro_host_device"


class HostDeviceMissing(OSError):
    """The firmware library is not built (the message says how to build it)."""


class LayoutMismatch(RuntimeError):
    """A Structure below does not match the C struct of host_device.h it mirrors."""


class Config(ctypes.Structure):
    _fields_ = [("seed", ctypes.c_uint64), ("max_range_m", ctypes.c_double), ("pozyx_firmware", ctypes.c_uint8),
                ("pozyx_present", ctypes.c_uint8), ("free_ram_bytes", ctypes.c_uint16)]


POSITION_FN = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_uint16, ctypes.c_double,
                               ctypes.POINTER(ctypes.c_double))
ACCEL_FN = ctypes.CFUNCTYPE(ctypes.c_double, ctypes.c_void_p, ctypes.c_uint16, ctypes.c_double)
RANGE_FN = ctypes.CFUNCTYPE(ctypes.c_uint8, ctypes.c_void_p, ctypes.c_uint16, ctypes.c_uint16, ctypes.c_double,
                            ctypes.POINTER(ctypes.c_uint32), ctypes.POINTER(ctypes.c_int16))
ROOM_FN = ctypes.CFUNCTYPE(ctypes.c_uint16, ctypes.c_void_p)
WRITE_FN = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint8), ctypes.c_uint16, ctypes.c_uint64)


class Callbacks(ctypes.Structure):
    _fields_ = [("context", ctypes.c_void_p), ("position", POSITION_FN), ("accel", ACCEL_FN), ("range", RANGE_FN),
                ("room", ROOM_FN), ("write", WRITE_FN)]


COUNTER_FIELDS = ("ranges_ok_direct", "ranges_ok_remote", "ranges_failed_direct", "ranges_failed_remote", "retries",
                  "bus_errors", "timeouts", "frames_sent", "frames_dropped", "commands_rejected", "stale_results",
                  "accel_failures", "host_bytes_lost", "boots")


class Counters(ctypes.Structure):
    _fields_ = [(name, ctypes.c_uint32) for name in COUNTER_FIELDS]


# The C struct (host_device.h) each Structure above mirrors by hand; library() checks them.
STRUCTURES = {"cdro_hd_config_t": Config, "cdro_hd_callbacks_t": Callbacks, "cdro_hd_counters_t": Counters}


def candidates() -> list[pathlib.Path]:
    out = []
    if os.environ.get("CDRO_HOST_DEVICE_LIB"):
        out.append(pathlib.Path(os.environ["CDRO_HOST_DEVICE_LIB"]))
    if os.environ.get("CDRO_BUILD_DIR"):
        build = pathlib.Path(os.environ["CDRO_BUILD_DIR"])
        cache = build / "CMakeCache.txt"
        # A sanitizer build's library cannot be loaded into Python (ASan would end the process
        # rather than fail the load): the plain build's is used then.
        if not (cache.is_file() and "CDRO_SANITIZE:BOOL=ON" in cache.read_text(errors="replace")):
            out.append(build / "lib" / LIBRARY)
    out.append(pathlib.Path(__file__).resolve().parents[3] / "build" / "lib" / LIBRARY)
    out.append(pathlib.Path(sys.prefix).parent / LIBRARY)
    return out


@functools.cache
def library() -> ctypes.CDLL:
    """The loaded library, with its prototypes; HostDeviceMissing when none is found."""
    tried = []
    for path in candidates():
        if not path.is_file():
            tried.append(f"{path} (absent)")
            continue
        try:
            lib = ctypes.CDLL(str(path))
        except OSError as error:
            tried.append(f"{path} ({error})")
            continue
        _prototypes(lib)
        # A mismatch is a bug on one side, not a library to pass over: no other candidate is tried.
        check_layouts(lib)
        return lib
    raise HostDeviceMissing(f"cdro-sim runs the firmware built for the host ({LIBRARY}), which was not found: "
                            f"{'; '.join(tried)}. Build it with: {BUILD_COMMAND} (or set CDRO_BUILD_DIR to a "
                            f"build that has it)")


def _prototypes(lib: ctypes.CDLL) -> None:
    p = ctypes.c_void_p
    signatures = {
        "cdro_hd_create": (p, [ctypes.POINTER(Config), ctypes.POINTER(Callbacks)]),
        "cdro_hd_destroy": (None, [p]),
        "cdro_hd_add_node": (ctypes.c_int, [p, ctypes.c_uint16, ctypes.c_uint8]),
        "cdro_hd_power_on": (None, [p, ctypes.c_uint8]),
        "cdro_hd_now_us": (ctypes.c_uint64, [p]),
        "cdro_hd_boot_us": (ctypes.c_uint64, [p]),
        "cdro_hd_idle_to": (None, [p, ctypes.c_uint64]),
        "cdro_hd_next_due_us": (ctypes.c_uint64, [p]),
        "cdro_hd_step": (None, [p]),
        "cdro_hd_receive": (ctypes.c_uint16, [p, ctypes.c_char_p, ctypes.c_uint16]),
        "cdro_hd_read_counters": (None, [p, ctypes.POINTER(Counters)]),
        "cdro_hd_running": (ctypes.c_uint8, [p]),
        "cdro_hd_state": (ctypes.c_uint8, [p]),
        "cdro_hd_moving": (ctypes.c_uint8, [p, ctypes.c_uint16]),
        "cdro_hd_next_sequence": (ctypes.c_uint16, [p]),
        "cdro_hd_injected_frame": (None, [p, ctypes.c_uint8]),
        "cdro_hd_tx_free": (ctypes.c_uint16, [p]),
        "cdro_hd_constant": (ctypes.c_int64, [ctypes.c_char_p, ctypes.POINTER(ctypes.c_uint8)]),
        "cdro_hd_layout": (ctypes.c_uint32, [ctypes.c_char_p, ctypes.POINTER(ctypes.c_uint8)]),
    }
    for name, (restype, argtypes) in signatures.items():
        function = getattr(lib, name)
        function.restype = restype
        function.argtypes = argtypes


def check_layouts(lib: ctypes.CDLL, structures: dict[str, type[ctypes.Structure]] | None = None) -> None:
    """LayoutMismatch, naming the struct and field, unless every Structure has the size and field
    offsets (bytes) the library reports for its C struct (cdro_hd_layout). The fields are
    declared twice, in C and here; this is what keeps the two the same."""
    for c_name, structure in (STRUCTURES if structures is None else structures).items():
        where = f"{structure.__name__} ({__name__}) against {c_name} (host_device.h)"
        found = ctypes.c_uint8(0)
        size = lib.cdro_hd_layout(c_name.encode(), ctypes.byref(found))
        if not found.value:
            raise LayoutMismatch(f"{where}: the library has no struct {c_name}")
        if ctypes.sizeof(structure) != size:
            raise LayoutMismatch(f"{where}: {ctypes.sizeof(structure)} bytes here, {size} in C")
        for field in structure._fields_:
            name = field[0]
            offset = lib.cdro_hd_layout(f"{c_name}.{name}".encode(), ctypes.byref(found))
            if not found.value:
                raise LayoutMismatch(f"{where}: field {name} is not in the C struct")
            if getattr(structure, name).offset != offset:
                raise LayoutMismatch(f"{where}: field {name} at byte {getattr(structure, name).offset} here, "
                                     f"{offset} in C")


def constant(name: str) -> int:
    """A compile-time constant of the firmware (config.h, or a state of cdro_fw_state_t, without
    CDRO_FW_), e.g. MOVING_ABOVE_MG, STATE_BOOT."""
    found = ctypes.c_uint8(0)
    value = library().cdro_hd_constant(name.encode(), ctypes.byref(found))
    if not found.value:
        raise KeyError(name)
    return int(value)
