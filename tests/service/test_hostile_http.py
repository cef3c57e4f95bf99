"""The live map's HTTP server against hostile clients, on the real service (cdro-service-harness
with a device streaming): slow request heads, big bodies, many connections, path traversal
(docs/service.md, "Security model").

Each case runs for a few seconds; every wait is a deadlock guard, nothing depends on how fast
the machine is.
"""
from __future__ import annotations

import os
import socket
import threading
import time

import pytest

from service_support import DEADLOCK_GUARD_S, NODES, OWN, start_running, wait_until

SLOW_CLIENTS = 40          # connections sending their head a byte at a time
SLOW_FOR_S = 6.0           # s they keep it up
HEALTH_CHECKS = 8
BODY_BYTES = 64 << 20      # bytes each big POST announces (and starts sending)
BIG_POSTS = 12


def connect(port: int, source: str = "127.0.0.1") -> socket.socket:
    s = socket.socket()
    s.bind((source, 0))
    s.settimeout(DEADLOCK_GUARD_S)
    s.connect(("127.0.0.1", port))
    return s


def request(port: int, text: bytes, source: str = "127.0.0.1") -> bytes:
    with connect(port, source) as s:
        s.sendall(text)
        out = b""
        while True:
            try:
                data = s.recv(65536)
            except ConnectionResetError:
                return out
            if not data:
                return out
            out += data


def status(response: bytes) -> str:
    return response.split(b"\r\n", 1)[0].decode(errors="replace")


def sanitized(build_dir) -> bool:
    """ASan's allocator keeps freed memory in quarantine: resident memory says nothing there."""
    cache = build_dir / "CMakeCache.txt"
    return cache.exists() and "CDRO_SANITIZE:BOOL=ON" in cache.read_text()


def resident_kib(pid: int) -> int:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


@pytest.fixture
def running(build_dir, tmp_path):
    device, harness = start_running(build_dir, tmp_path)
    harness.sanitized = sanitized(build_dir)
    for i in range(20):
        device.range_frame(OWN, NODES[i % 3], 3000 + i)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 20, "frames delivered")
    yield device, harness
    assert harness.stop() == 0, harness.log()
    device.vanish()


def test_slow_headers_do_not_starve_the_health_endpoint(running):
    device, harness = running
    slow = [connect(harness.port, "127.0.0.2") for _ in range(SLOW_CLIENTS)]
    stop = threading.Event()

    def trickle():
        for s in slow:
            s.sendall(b"GET /api/health HTTP/1.1\r\n")
        while not stop.is_set():
            for s in slow:
                try:
                    s.send(b"X")
                except OSError:
                    pass        # closed by the server: that is allowed
            time.sleep(0.2)

    thread = threading.Thread(target=trickle)
    thread.start()
    answered, started = 0, time.monotonic()
    try:
        time.sleep(0.5)
        for _ in range(HEALTH_CHECKS):
            answered += status(request(harness.port, b"GET /api/health HTTP/1.1\r\n\r\n")) == "HTTP/1.1 200 OK"
            time.sleep(max(0.0, SLOW_FOR_S / HEALTH_CHECKS - 0.1))
    finally:
        stop.set()
        thread.join()
        for s in slow:
            s.close()
    print(f"{answered} of {HEALTH_CHECKS} health checks answered during {time.monotonic() - started:.1f} s of "
          f"{SLOW_CLIENTS} slow clients")
    assert answered == HEALTH_CHECKS
    assert harness.health()["link"] == "connected"


def test_big_bodies_are_refused_and_memory_stays_flat(running):
    device, harness = running
    before_kib = resident_kib(harness.process.pid)
    statuses = []
    chunk = b"x" * (1 << 20)
    for _ in range(BIG_POSTS):
        with connect(harness.port) as s:
            s.sendall(b"POST /api/map HTTP/1.1\r\nHost: x\r\nContent-Length: %d\r\n\r\n" % BODY_BYTES)
            sent = 0
            try:
                while sent < BODY_BYTES:     # the server may close at any point: it does not want it
                    sent += s.send(chunk)
            except OSError:
                pass
            try:
                statuses.append(status(s.recv(4096)))
            except OSError:
                statuses.append("reset")
    after_kib = resident_kib(harness.process.pid)
    print(f"resident {before_kib} KiB before, {after_kib} KiB after {BIG_POSTS} POSTs of {BODY_BYTES >> 20} MiB")
    if not harness.sanitized:
        assert after_kib - before_kib < 16 * 1024
    assert statuses.count("HTTP/1.1 413 Payload Too Large") >= 1, statuses
    assert set(statuses) <= {"HTTP/1.1 413 Payload Too Large", "reset", ""}, statuses
    big_head = b"GET /api/health HTTP/1.1\r\nX-Big: " + b"a" * (256 << 10) + b"\r\n\r\n"
    assert status(request(harness.port, big_head)) == "HTTP/1.1 431 Request Header Fields Too Large"
    assert status(request(harness.port, b"GET /api/health HTTP/1.1\r\n\r\n")) == "HTTP/1.1 200 OK"


def test_many_connections_keep_memory_flat_and_the_map_answered(running):
    device, harness = running
    before_kib = resident_kib(harness.process.pid)
    held = []
    for i in range(600):
        try:
            held.append(connect(harness.port, f"127.0.{4 + i // 200}.{1 + i % 200}"))
            held[-1].sendall(b"GET /api/events HTTP/1.1\r\n\r\n" if i % 3 == 0 else b"GET /api")
        except OSError:
            pass        # refused or reset once the caps are reached
    assert status(request(harness.port, b"GET /api/map HTTP/1.1\r\n\r\n")) == "HTTP/1.1 200 OK"
    after_kib = resident_kib(harness.process.pid)
    for s in held:
        s.close()
    print(f"resident {before_kib} KiB before, {after_kib} KiB with {len(held)} connections opened")
    if not harness.sanitized:
        assert after_kib - before_kib < 16 * 1024
    wait_until(lambda: status(request(harness.port, b"GET /api/health HTTP/1.1\r\n\r\n")) == "HTTP/1.1 200 OK",
               "the health endpoint after the connections closed")


def test_traversal_and_bad_ids_get_4xx(running, tmp_path):
    device, harness = running
    secret = tmp_path / "secret.txt"
    secret.write_text("do not serve me")
    relative = os.path.relpath(secret, "/")
    for path in [f"/../../../../{relative}", f"/..%2f..%2f..%2f{relative}", "/../../../../etc/passwd",
                 "/%2e%2e/%2e%2e/etc/passwd", "/api/../../etc/passwd", "/....//....//etc/passwd",
                 f"/{secret}", "/api/nodes/99999999999999999999/components", "/api/nodes/-1/components",
                 "/api/nodes/0x10/components"]:
        response = request(harness.port, f"GET {path} HTTP/1.1\r\n\r\n".encode())
        assert status(response) in ("HTTP/1.1 404 Not Found", "HTTP/1.1 400 Bad Request"), (path, response[:200])
        assert b"do not serve me" not in response and b"root:" not in response
    response = request(harness.port, b"GET /api/nodes/99999999999999999999/components HTTP/1.1\r\n\r\n")
    assert status(response) == "HTTP/1.1 400 Bad Request"
