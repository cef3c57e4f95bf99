"""Pseudo-terminal links (the simulated device's and cdro-replay's serial port) and chunking of
a byte stream into capture records.

A PtyLink creates a pseudo-terminal pair, puts the slave side in raw mode and points a symlink
at it. Until a reader opens the slave, the master reports a hang-up; reader_present() watches
for that. Once a reader is there, the link keeps its own descriptor on the slave so that bytes
the reader has not read yet can be counted (FIONREAD) and the master keeps working if the
reader closes and reopens.
"""
from __future__ import annotations

import fcntl
import os
import pathlib
import select
import struct
import termios
import time
import tty
from typing import Callable

from ..codec import CaptureRecord, CaptureWriter


class LinkError(OSError):
    """The link path cannot be used."""


class PtyLink:
    def __init__(self, link_path: str | os.PathLike):
        self.link_path = pathlib.Path(link_path)
        self.master: int | None = None
        self.slave_name = ""
        self._held_slave: int | None = None
        self._poll: select.poll | None = None

    def create(self) -> str:
        """Opens a new pair and (re)points the symlink at it; returns the slave's device path."""
        if self.link_path.exists() and not self.link_path.is_symlink():
            raise LinkError(f"{self.link_path} exists and is not a symlink; refusing to replace it")
        if not self.link_path.parent.is_dir():
            raise LinkError(f"{self.link_path.parent} is not a directory")
        master, slave = os.openpty()
        tty.setraw(slave)
        self.slave_name = os.ttyname(slave)
        os.close(slave)                      # hang-up on the master until a reader opens the slave
        os.set_blocking(master, False)
        self.master = master
        self._poll = select.poll()
        self._poll.register(master, select.POLLIN | select.POLLHUP)
        temporary = self.link_path.with_name(f".{self.link_path.name}.{os.getpid()}.tmp")
        if temporary.is_symlink():
            temporary.unlink()
        os.symlink(self.slave_name, temporary)
        os.replace(temporary, self.link_path)
        return self.slave_name

    @property
    def is_open(self) -> bool:
        return self.master is not None

    def reader_present(self) -> bool:
        if self.master is None:
            return False
        if self._held_slave is not None:
            return True
        return not any(mask & select.POLLHUP for _, mask in self._poll.poll(0))

    def hold(self) -> None:
        """Keeps a descriptor on the slave (after a reader has opened it)."""
        if self._held_slave is None and self.master is not None:
            self._held_slave = os.open(self.slave_name, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)

    def unread_bytes(self) -> int:
        """Bytes written to the master that the reader has not read yet (needs hold())."""
        if self._held_slave is None:
            return 0
        raw = fcntl.ioctl(self._held_slave, termios.FIONREAD, b"\0\0\0\0")
        return struct.unpack("i", raw)[0]

    def write(self, data: bytes) -> int:
        """Non-blocking; returns how many bytes the pseudo-terminal took."""
        try:
            return os.write(self.master, data)
        except BlockingIOError:
            return 0

    def read(self) -> bytes:
        """Non-blocking; b"" when nothing is there."""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:                      # EIO: no reader at the moment
            return b""

    def wait_drained(self, timeout_s: float, stop: Callable[[], bool] = lambda: False) -> int:
        """Waits until the reader has read everything (or the timeout); returns bytes left unread."""
        deadline = time.monotonic() + timeout_s
        time.sleep(0.005)                    # the kernel moves written bytes to the slave asynchronously
        while time.monotonic() < deadline and not stop():
            if self.unread_bytes() == 0:
                return 0
            time.sleep(0.01)
        return self.unread_bytes()

    def close(self) -> None:
        """Closes both sides and removes the symlink (when it still points at this link)."""
        try:
            if self.link_path.is_symlink() and os.readlink(self.link_path) == self.slave_name:
                self.link_path.unlink()
        except OSError:
            pass
        for fd in (self._held_slave, self.master):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._held_slave = None
        self.master = None
        self._poll = None


class Chunker:
    """Splits a byte stream at 0x00 delimiters into capture records, one per chunk (empty chunks
    too, so that replaying the records reproduces the bytes exactly)."""

    def __init__(self, writer: CaptureWriter | None, flags: int = 0):
        self.writer = writer
        self.flags = flags
        self.pending = bytearray()
        self.records = 0

    def feed(self, host_time_us: int, data: bytes) -> None:
        start = 0
        while True:
            end = data.find(b"\x00", start)
            if end < 0:
                self.pending += data[start:]
                return
            self.pending += data[start:end]
            self._record(host_time_us)
            start = end + 1

    def _record(self, host_time_us: int) -> None:
        if self.writer is not None:
            self.writer.write(CaptureRecord(host_time_us, bytes(self.pending), self.flags))
        self.records += 1
        self.pending.clear()

    def finish(self, host_time_us: int) -> int:
        """Writes a chunk that never got its delimiter as a last record; returns its length."""
        length = len(self.pending)
        if length:
            self._record(host_time_us)
        return length
