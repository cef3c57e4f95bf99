"""Helpers for the service's end-to-end tests: a scripted fake device on a pseudo-terminal
(written with the Python codec, behaving as docs/protocol.md's "Device behaviour" says), and
the cdro-service-harness process with its outputs.

The real network simulator (cdro-sim --pty) drives the full-system tests
(tests/hostd/test_hostd_live.py); these tests need exact control over what goes on the wire
(garbage, cut frames, absurd values, resets), which a scripted device gives.
"""
from __future__ import annotations

import json
import os
import pathlib
import select
import signal
import socket
import subprocess
import threading
import time
import tty
import urllib.error
import urllib.request

from cdro_tools.codec import Frame, StreamDecoder, encode_frame
from cdro_tools.codec.checksums import crc16
from cdro_tools.codec.cobs import cobs_encode
from cdro_tools.codec.frames import LAYOUT_HASH, PROTOCOL_VERSION, Result, pack_fields
from cdro_tools.codec.layout import FRAME_TYPES

DEADLOCK_GUARD_S = 30.0  # s; only ever reached when something is broken

OWN = 0x6000                        # the scripted device's own node (FakeDevice's default)
NODES = [0x6069, 0x6A11, 0x6A2C]    # the remote nodes the tests range to


def wait_until(predicate, what: str, timeout_s: float = DEADLOCK_GUARD_S, poll_s: float = 0.02):
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(poll_s)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def raw_frame(type_id: int, sequence: int, payload: bytes, version: int = PROTOCOL_VERSION) -> bytes:
    """A frame built by hand (another protocol version, say): COBS(header|payload|crc) 0x00."""
    raw = bytes([version, type_id]) + sequence.to_bytes(2, "little") + bytes([len(payload)]) + payload
    raw += crc16(raw).to_bytes(2, "little")
    return cobs_encode(raw) + b"\x00"


class FakeDevice:
    """The Pozyx tag's firmware as seen from the serial port, on a PTY behind a symlink."""

    def __init__(self, link_path: pathlib.Path, node_id: int = 0x6000, layout_hash: int = LAYOUT_HASH,
                 protocol_version: int = PROTOCOL_VERSION, answer: bool = True,
                 header_version: int = PROTOCOL_VERSION):
        self.link_path = pathlib.Path(link_path)
        self.node_id = node_id
        self.layout_hash = layout_hash
        self.protocol_version = protocol_version
        self.answer = answer
        self.header_version = header_version  # another value: a firmware built from another layout
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        if self.link_path.is_symlink() or self.link_path.exists():
            self.link_path.unlink()
        self.link_path.symlink_to(os.ttyname(self.slave))
        self.sequence = 0
        self.device_time_ms = 0
        self.running = False
        self.nodes: list[int] = []
        self.host_frames: list[Frame] = []   # every frame the host sent
        self.host_rejects: list[str] = []    # host chunks that did not decode
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        self._decoder = StreamDecoder()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    # ---- sending ---------------------------------------------------------------------------

    def write(self, data: bytes) -> None:
        with self._write_lock:
            view = memoryview(data)
            while view:
                n = os.write(self.master, view)
                view = view[n:]

    def send(self, type_name: str, **fields) -> bytes:
        """Encodes and sends one frame with the next sequence number; returns its bytes."""
        with self._write_lock:
            data = encode_frame(Frame(type_name, self.sequence & 0xFFFF, fields))
            self.sequence += 1
            view = memoryview(data)
            while view:
                n = os.write(self.master, view)
                view = view[n:]
        return data

    def hello(self) -> None:
        if self.header_version != PROTOCOL_VERSION:
            payload = pack_fields(FRAME_TYPES["HELLO"]["fields"], dict(
                device_time_ms=self.device_time_ms, firmware_version=0x0200, protocol_version=self.header_version,
                layout_hash=0xABCD, node_id=self.node_id, capabilities=0x03, pozyx_firmware=0x12, max_nodes=20,
                pozyx_tries=1, reset_cause=1))
            self.write(raw_frame(0x01, self.sequence & 0xFFFF, payload, version=self.header_version))
            self.sequence += 1
            return
        self.send("HELLO", device_time_ms=self.device_time_ms, firmware_version=0x0102,
                  protocol_version=self.protocol_version, layout_hash=self.layout_hash, node_id=self.node_id,
                  capabilities=0x03, pozyx_firmware=0x12, max_nodes=20, reset_cause=1, pozyx_tries=1)

    def boot(self) -> None:
        """Power on: one 0x00, HELLO with sequence 0, stopped."""
        self.sequence = 0
        self.device_time_ms = 50
        self.running = False
        self.write(b"\x00")
        self.hello()

    def range_frame(self, from_id: int, to_id: int, distance_mm: int, step_ms: int = 12) -> bytes:
        self.device_time_ms += step_ms
        return self.send("RANGE", device_time_ms=self.device_time_ms, from_id=from_id, to_id=to_id,
                         distance_mm=distance_mm, rss_dbm=-80, flags=0)

    def motion(self, node_id: int, moving: int) -> bytes:
        self.device_time_ms += 5
        return self.send("MOTION", device_time_ms=self.device_time_ms, node_id=node_id, moving=moving,
                         accel_norm_mg=1000 + 200 * moving, deviation_mg=100 * moving, reason=0)

    # ---- answering the host ----------------------------------------------------------------

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.master], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(self.master, 4096)
            except OSError:
                return
            for event in self._decoder.feed(data):
                if event.result != Result.OK:
                    self.host_rejects.append(str(event.result))
                    continue
                self.host_frames.append(event.frame)
                if self.answer:
                    try:
                        self._answer(event.frame)
                    except OSError:
                        return

    def _ack(self, frame: Frame, value: int = 0) -> None:
        self.send("ACK", acked_type=frame.type_id, acked_sequence=frame.sequence, value=value)

    def _answer(self, frame: Frame) -> None:
        if frame.type == "HELLO_REQUEST":
            self.hello()
        elif frame.type == "SET_NODES":
            self.nodes = list(frame["node_ids"])
            self._ack(frame)
            self.send("NODE_LIST", source=1, node_ids=self.nodes)
        elif frame.type == "SET_SCHEDULE":
            self._ack(frame)
        elif frame.type == "START":
            self.running = True
            self._ack(frame)
        elif frame.type == "STOP":
            self.running = False
            self._ack(frame)
        elif frame.type == "PING":
            self._ack(frame, value=frame["nonce"])

    def host_types(self) -> list[str]:
        return [f.type for f in list(self.host_frames)]

    def vanish(self) -> None:
        """Unplugged: both ends of the PTY close and the symlink goes away."""
        self._stop.set()
        self._thread.join(timeout=5)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        if self.link_path.is_symlink():
            self.link_path.unlink()


class Harness:
    """cdro-service-harness with a generated config, its outputs in tmp_path."""

    def __init__(self, build_dir: pathlib.Path, tmp_path: pathlib.Path, device: pathlib.Path | None = None,
                 extra_config: str = "", args: list[str] | None = None, name: str = "run",
                 http: bool = True, nodes: list[int] | None = None):
        self.binary = build_dir / "bin" / "cdro-service-harness"
        assert self.binary.exists(), f"{self.binary} missing: build the native tree first"
        self.dir = tmp_path
        self.name = name
        self.port = free_port() if http else 0
        self.capture = tmp_path / f"{name}.cdrocap"
        self.jsonl = tmp_path / f"{name}.jsonl"
        self.checkpoint = tmp_path / f"{name}.cdrosog"
        self.received = tmp_path / f"{name}.received.jsonl"
        self.stderr_path = tmp_path / f"{name}.stderr.log"
        nodes = [0x6069, 0x6A11, 0x6A2C] if nodes is None else nodes
        config = f"""
serial:
  device: {device or tmp_path / 'no-device'}
  reconnect_min_s: 0.05
  reconnect_max_s: 0.4
  hello_timeout_s: 0.3
  hello_retries: 20
  command_timeout_s: 0.5
  command_retries: 3
  keepalive_period_s: 0.5
  keepalive_misses: 3
nodes:
  ids: [{", ".join(str(n) for n in nodes)}]
capture: {{path: {self.capture}}}
output: {{jsonl: {self.jsonl}, health_period_s: 0.5}}
http: {{port: {self.port}, update_period_s: 0.05}}
checkpoint: {{path: {self.checkpoint}, period_s: 0.5}}
logging: {{level: debug, drop_log_per_s: 1000}}
{extra_config}
"""
        self.config_path = tmp_path / f"{name}.yaml"
        self.config_path.write_text(config)
        command = [str(self.binary), "--config", str(self.config_path), "--received", str(self.received)]
        command += args or []
        self._stderr = open(self.stderr_path, "w")
        self.process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=self._stderr)

    # ---- live view through the JSON API ------------------------------------------------------

    def api(self, path: str):
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{self.port}{path}", timeout=5) as response:
                return json.loads(response.read())
        except (urllib.error.URLError, ConnectionError, json.JSONDecodeError):
            return None

    def health(self):
        return self.api("/api/health")

    def wait_health(self, predicate, what: str, timeout_s: float = DEADLOCK_GUARD_S):
        def check():
            if self.process.poll() is not None:
                raise AssertionError(f"harness exited ({self.process.returncode}) while waiting for {what}:\n"
                                     + self.log())
            h = self.health()
            return h if h and predicate(h) else None
        return wait_until(check, what, timeout_s)

    def wait_connected(self, handshakes: int = 1):
        return self.wait_health(lambda h: h["link"] == "connected" and h["counters"]["handshakes"] >= handshakes,
                                f"link connected (handshake {handshakes})")

    # ---- ending and results --------------------------------------------------------------------

    def stop(self, sig: int = signal.SIGTERM) -> int:
        self.process.send_signal(sig)
        try:
            code = self.process.wait(timeout=DEADLOCK_GUARD_S)
        finally:
            self._stderr.close()
        return code

    def wait_exit(self) -> int:
        code = self.process.wait(timeout=DEADLOCK_GUARD_S)
        self._stderr.close()
        return code

    def log(self) -> str:
        return self.stderr_path.read_text(errors="replace") if self.stderr_path.exists() else ""

    def received_lines(self) -> list[dict]:
        if not self.received.exists():
            return []
        lines = []
        for line in self.received.read_text().splitlines():
            try:
                lines.append(json.loads(line))
            except json.JSONDecodeError:
                pass  # a line cut by kill -9
        return lines

    def jsonl_lines(self) -> list[dict]:
        return [json.loads(line) for line in self.jsonl.read_text().splitlines() if line]

    def __del__(self):
        if getattr(self, "process", None) and self.process.poll() is None:
            self.process.kill()
            self.process.wait()


def start_running(build_dir, tmp_path, name="run", **harness_options):
    """A FakeDevice on tmp_path/ttyPOZYX, booted, and the harness on it once it is connected."""
    link = tmp_path / "ttyPOZYX"
    device = FakeDevice(link)
    harness = Harness(build_dir, tmp_path, device=link, name=name, **harness_options)
    device.boot()
    harness.wait_connected()
    return device, harness
