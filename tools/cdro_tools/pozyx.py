"""cdro-pozyx: set up and check the Pozyx network behind a CDRO board, over its serial port.

  info       what the device reports at start: its HELLO (CDRO and Pozyx firmware), the nodes it
             found, each node's Pozyx firmware and UWB settings and what differs between them
  uwb        sets every node's UWB settings (SET_UWB: the remote nodes first, then the shield's
             own Pozyx), then prints each node as it is now; not saved to the Pozyx's flash, so a
             power cycle restores the old ones
  diagnose   the bench checklist of docs/firmware.md (DIAGNOSE): INT_STATUS around a remote
             ranging, the result message, ranging times, GETIDS with an offset, I2C timing
             (clock stretching), the accelerometer at rest, printed item by item

cdro-hostd must not hold the port meanwhile. Opening the port resets an Uno (DTR), so the device
boots and reports afresh; a device that does not reset is asked for HELLO (and, for `info`, for
its nodes' settings by setting its node list again).

examples:
  cdro-pozyx --device /dev/ttyACM0 info
  cdro-pozyx --device /dev/ttyACM0 uwb --channel 5 --bitrate 6.8M --prf 64 --preamble 128 --gain-db 11.5
  cdro-pozyx --device /dev/ttyACM0 diagnose
"""
from __future__ import annotations

import argparse
import collections
import sys
import time

import serial

from .codec import CONSTANTS as C
from .codec import Frame, StreamDecoder, encode_frame
from .codec.frames import Result
from .cli import entry_point

BITRATES = {"110k": 0, "850k": 1, "6.8M": 2}
PRFS = {16: 1, 64: 2}
PREAMBLES = {64: 0x04, 128: 0x14, 256: 0x24, 512: 0x34, 1024: 0x08, 1536: 0x18, 2048: 0x28, 4096: 0x0C}
PROTOCOLS = {"precision": 0, "fast": 1}
HELLO_WAIT_S = 4.0   # an Uno reset by the port's opening boots in ~1 s; then HELLO_REQUEST
QUIET_S = 2.0        # a round is over when nothing of it came for this long
INT_BITS = [(0x01, "ERR"), (0x02, "POS"), (0x04, "IMU"), (0x08, "RX_DATA"), (0x10, "FUNC")]


class DeviceError(Exception):
    """The device did not answer as expected."""


def _flags(bits: int) -> str:
    names = [name for bit, name in INT_BITS if bits & bit]
    return "|".join(names) if names else "none"


def pozyx_version(value: int) -> str:
    return f"{value >> 4}.{value & 0x0F}"


def uwb_text(f: dict) -> str:
    bitrate = {v: k for k, v in BITRATES.items()}.get(f["uwb_rates"] & 0x3F, "?")
    prf = {v: k for k, v in PRFS.items()}.get(f["uwb_rates"] >> 6, "?")
    preamble = {v: k for k, v in PREAMBLES.items()}.get(f["uwb_plen"], "?")
    protocol = {v: k for k, v in PROTOCOLS.items()}.get(f["range_protocol"], "?")
    return (f"channel {f['uwb_channel']}, {bitrate}bit/s, PRF {prf} MHz, preamble {preamble}, "
            f"gain {f['uwb_gain'] / 2:.1f} dB, {protocol}")


MISMATCH_NAMES = [(C["CDRO_MISMATCH_CHANNEL"], "channel"), (C["CDRO_MISMATCH_RATES"], "bitrate/PRF"),
                  (C["CDRO_MISMATCH_PLEN"], "preamble"), (C["CDRO_MISMATCH_GAIN"], "gain"),
                  (C["CDRO_MISMATCH_PROTOCOL"], "ranging protocol"),
                  (C["CDRO_MISMATCH_FIRMWARE"], "Pozyx firmware (not one the CDRO firmware drives)")]


def node_info_line(f: dict) -> str:
    node = f"node 0x{f['node_id']:04X}"
    if f["result"] == C["CDRO_NODE_INFO_NO_ANSWER"]:
        return f"{node}: no answer (out of reach, off, or on other UWB settings)"
    line = f"{node}: Pozyx firmware {pozyx_version(f['pozyx_firmware'])}, {uwb_text(f)}"
    differs = [name for bit, name in MISMATCH_NAMES if f["mismatch"] & bit]
    return line + (f"  <- differs from the own node in: {', '.join(differs)}" if differs else "")


def diag_line(f: dict) -> str:
    """One bench-checklist item in words (docs/firmware.md, "Bench checklist")."""
    item, a, b, c = f["item"], f["value_a"], f["value_b"], f["value_c"]
    node = f"0x{f['node_id']:04X}"
    status = "" if f["status"] == 0 else f"  [failed: driver status {f['status']}]"
    if item == C["CDRO_DIAG_REMOTE_FLAGS"]:
        text = (f"1 INT_STATUS around a remote ranging by {node}: up to its acknowledgement {_flags(a)} (0x{a:02X}), "
                f"after it up to the result message {_flags(b)} (0x{b:02X}); result {c} ms after the acknowledgement")
    elif item == C["CDRO_DIAG_RESULT_MESSAGE"]:
        text = (f"2 result message from {node}: {a} bytes (the firmware expects 4), first 4 bytes as u32 = {b}; "
                f"GETRANGEINFO said {c} mm")
    elif item == C["CDRO_DIAG_REMOTE_TIME"]:
        text = (f"3 remote-to-remote range with {node}: {a} ms in all, {b} ms from TX_SEND to the acknowledgement, "
                f"{c} ms from the result message to GETRANGEINFO's reply")
    elif item == C["CDRO_DIAG_LOCAL_TIME"]:
        text = f"4 local range with {node}: DO_RANGING to FUNC {a} ms, {b} mm, {c} ms with GETRANGEINFO"
    elif item == C["CDRO_DIAG_GETIDS_OFFSET"]:
        verdict = "offset honoured" if b == c else "OFFSET IGNORED: nodes past 15 would be lost"
        text = (f"5 GETIDS with an offset: {a} devices listed, id 1 from offset 0 = 0x{b:04X}, "
                f"from offset 1 = 0x{c:04X} ({verdict})")
    elif item == C["CDRO_DIAG_I2C_TIMING"]:
        text = (f"6 I2C timing: longest 1-byte register read {a} us, longest GETRANGEINFO call {b} us against {c} us "
                f"on the wire: ~{max(b - c, 0)} us of clock stretching and Wire overhead")
    elif item == C["CDRO_DIAG_ACCEL"]:
        z = b - (1 << 32) if b >= (1 << 31) else b
        text = f"7 accelerometer of {node} at rest: norm {a} mg (expect ~1000), z {z} mg"
    else:
        text = f"item {item}: {a} {b} {c}"
    return text + status


class Device:
    """The board's serial port: frames in, commands out, with their sequence numbers."""

    def __init__(self, path: str, baud: int, out=sys.stdout, hello_wait_s: float = HELLO_WAIT_S):
        self.hello_wait_s = hello_wait_s
        try:
            self.port = serial.Serial(path, baud, timeout=0.05)
        except serial.SerialException as error:
            raise DeviceError(f"cannot open {path}: {error}") from error
        self.decoder = StreamDecoder()
        self.pending: collections.deque = collections.deque()  # decoded, not yet handed out
        self.sequence = 1
        self.out = out
        self.hello: Frame | None = None
        self.node_ids: list[int] = []
        self.expect_timeouts = False  # SET_UWB: remote writes time out as the nodes switch

    def close(self) -> None:
        self.port.close()

    def frames(self, duration_s: float):
        """Frames for duration_s, as they come (a caller that stops early leaves the rest for
        the next call)."""
        end = time.monotonic() + duration_s
        while True:
            while self.pending:
                yield self.pending.popleft()
            if time.monotonic() >= end:
                return
            for event in self.decoder.feed(self.port.read(256)):
                if event.result == Result.OK and event.frame is not None:
                    self._note(event.frame)
                    self.pending.append(event.frame)

    def _note(self, frame: Frame) -> None:
        if frame.type == "HELLO":
            self.hello = frame
            h = frame
            pozyx = ("no Pozyx" if h["node_id"] == 0xFFFF
                     else f"node 0x{h['node_id']:04X}, Pozyx firmware {pozyx_version(h['pozyx_firmware'])}")
            self.out.write(f"HELLO: CDRO firmware {h['firmware_version'] >> 8}.{h['firmware_version'] & 0xFF}, "
                           f"protocol {h['protocol_version']}, {pozyx}, found at try {h['pozyx_tries']}\n")
        elif frame.type == "NODE_LIST":
            self.node_ids = list(frame["node_ids"])
        elif frame.type in ("NODE_INFO", "DIAG"):
            self.print_frame(frame)
        elif frame.type == "ERROR":
            code = frame["code"]
            names = {v: k[len("CDRO_DEVICE_ERROR_"):] for k, v in C.items() if k.startswith("CDRO_DEVICE_ERROR_")}
            node = frame["node_id"]
            about = f", node 0x{node:04X}" if node else ""
            note = ""
            if self.expect_timeouts and code == C["CDRO_DEVICE_ERROR_TIMEOUT"]:
                note = " (expected: a node that switched answers on its new settings, unheard)"
            self.out.write(f"device ERROR {names.get(code, code)}: detail 0x{frame['detail']:04X}{about}{note}\n")

    def send(self, frame_type: str, fields: dict | None = None) -> int:
        sequence = self.sequence
        self.sequence = (self.sequence + 1) & 0xFFFF
        self.port.write(encode_frame(Frame(frame_type, sequence, fields or {})))
        return sequence

    def wait_hello(self) -> Frame:
        for _ in self.frames(self.hello_wait_s):
            if self.hello is not None:
                break
        if self.hello is None:
            self.send("HELLO_REQUEST")
            for _ in self.frames(self.hello_wait_s):
                if self.hello is not None:
                    break
        if self.hello is None:
            raise DeviceError("no HELLO from the device (is the CDRO firmware flashed? the baud rate?)")
        h = self.hello
        if not h["capabilities"] & C["CDRO_CAP_POZYX_SETUP"]:
            raise DeviceError("the device takes no Pozyx set-up commands (no Pozyx, an unsupported Pozyx firmware, "
                              "or not the CDRO firmware)")
        return h

    def command(self, frame_type: str, fields: dict | None = None, attempts: int = 10):
        """Sends a command until it is ACKed; a device busy with a round (WRONG_STATE) is asked
        again (0.5 s apart). Returns the frames that came meanwhile."""
        seen = []
        for _ in range(attempts):
            sequence = self.send(frame_type, fields)
            answer = None
            for frame in self.frames(1.5):
                if frame.type in ("ACK", "NACK") and frame[f"{frame.type.lower()}ed_sequence"] == sequence:
                    answer = frame
                    break
                seen.append(frame)
            if answer is not None and answer.type == "ACK":
                return seen
            if answer is not None and answer["reason"] != C["CDRO_NACK_WRONG_STATE"]:
                raise DeviceError(f"{frame_type} refused (NACK reason {answer['reason']})")
            time.sleep(0.5)
        raise DeviceError(f"{frame_type} not accepted")

    def collect(self, frame_type: str, expected: int, timeout_s: float, seen=()) -> list[Frame]:
        """Frames of one type until `expected` came, or QUIET_S without one, or timeout_s (they
        are printed as they come)."""
        got = [f for f in seen if f.type == frame_type]
        last = time.monotonic()
        end = last + timeout_s
        while len(got) < expected and time.monotonic() < end and time.monotonic() - last < QUIET_S:
            for frame in self.frames(0.2):
                if frame.type == frame_type:
                    got.append(frame)
                    last = time.monotonic()
        return got

    def print_frame(self, frame: Frame) -> None:
        if frame.type == "NODE_INFO":
            self.out.write(node_info_line(frame.fields) + "\n")
        elif frame.type == "DIAG":
            self.out.write(diag_line(frame.fields) + "\n")
        self.out.flush()


def run_info(device: Device) -> int:
    device.wait_hello()
    infos = device.collect("NODE_INFO", 1 + len(device.node_ids), 10.0)
    if len(infos) < 1 + len(device.node_ids) and device.node_ids:
        # A device that did not reset on opening reads its nodes again when its list is set
        # (to the same list: never to an empty one, which would drop the nodes it has).
        device.out.write("asking for the nodes' settings again "
                         f"(SET_NODES with the device's {len(device.node_ids)} nodes)\n")
        seen = device.command("SET_NODES", {"node_ids": device.node_ids})
        infos = device.collect("NODE_INFO", 1 + len(device.node_ids), 10.0, seen)
    return 0 if infos and all(f["mismatch"] == 0 and f["result"] == 0 for f in infos) else 1


def run_uwb(device: Device, args) -> int:
    device.wait_hello()
    fields = {"uwb_channel": args.channel, "uwb_rates": (PRFS[args.prf] << 6) | BITRATES[args.bitrate],
              "uwb_plen": PREAMBLES[args.preamble], "uwb_gain": round(args.gain_db * 2),
              "range_protocol": PROTOCOLS[args.protocol]}
    device.command("STOP")
    device.collect("NODE_INFO", 1 + len(device.node_ids), 10.0)  # the start's round, if any
    device.out.write(f"setting: {uwb_text(fields)}; the nodes then:\n")
    device.expect_timeouts = True
    seen = device.command("SET_UWB", fields)
    infos = device.collect("NODE_INFO", 1 + len(device.node_ids), 30.0, seen)
    return 0 if infos and all(f["mismatch"] == 0 and f["result"] == 0 for f in infos) else 1


def run_diagnose(device: Device) -> int:
    device.wait_hello()
    device.command("STOP")
    device.collect("NODE_INFO", 1 + len(device.node_ids), 10.0)
    seen = device.command("DIAGNOSE")
    diags = device.collect("DIAG", 99, 20.0, seen)
    return 0 if diags and all(f["status"] == 0 for f in diags) else 1


@entry_point
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cdro-pozyx", description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", required=True, help="the board's serial port (e.g. /dev/ttyACM0)")
    parser.add_argument("--baud", type=int, default=115200, help="bit/s (115200)")
    parser.add_argument("--hello-wait-s", type=float, default=HELLO_WAIT_S,
                        help="s to wait for the boot HELLO before asking for one (4)")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="the device's and every node's Pozyx firmware and UWB settings")
    uwb = sub.add_parser("uwb", help="set every node's UWB settings")
    uwb.add_argument("--channel", type=int, choices=[1, 2, 3, 4, 5, 7], required=True)
    uwb.add_argument("--bitrate", choices=list(BITRATES), required=True, help="bit/s")
    uwb.add_argument("--prf", type=int, choices=list(PRFS), required=True, help="MHz")
    uwb.add_argument("--preamble", type=int, choices=list(PREAMBLES), required=True, help="symbols")
    uwb.add_argument("--gain-db", type=float, required=True, help="TX gain in dB, 0 to 33.5 in 0.5 dB steps")
    uwb.add_argument("--protocol", choices=list(PROTOCOLS), default="precision")
    sub.add_parser("diagnose", help="the bench checklist, item by item")
    args = parser.parse_args(argv)
    if args.command == "uwb" and not 0 <= args.gain_db <= 33.5:
        parser.error("--gain-db: 0 to 33.5 dB")
    try:
        device = Device(args.device, args.baud, hello_wait_s=args.hello_wait_s)
    except DeviceError as error:
        print(f"cdro-pozyx: {error}", file=sys.stderr)
        return 1
    try:
        if args.command == "info":
            return run_info(device)
        if args.command == "uwb":
            return run_uwb(device, args)
        return run_diagnose(device)
    except DeviceError as error:
        print(f"cdro-pozyx: {error}", file=sys.stderr)
        return 1
    finally:
        device.close()


if __name__ == "__main__":
    sys.exit(main())
