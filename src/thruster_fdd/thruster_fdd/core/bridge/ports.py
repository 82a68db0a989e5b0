"""Serial ports of a process, all read by one thread through one selector.

With every driver of a vehicle in one process, a single thread waits on all ports at once
(``selectors``), hands each chunk of bytes with its host arrival time to the port's ``on_data``
callback, and re-opens a port that fails or vanishes. The same thread calls each port's
periodic ``tick`` (a driver's command frames, ``start_ticks``) on a grid of whole periods of the
monotonic clock, so ports with one period share one wake instead of one timer each. Other writes
come from the caller's thread.

Nothing here blocks its caller: ``open`` and ``close`` are carried out by the reader thread,
which a self-pipe wakes.
"""

from __future__ import annotations

import contextlib
import os
import selectors
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import serial

OnData = Callable[[bytes, int], None]
"""Called in the reader thread with the bytes read and their host arrival time (ns)."""

OnTick = Callable[[], None]
"""Called in the reader thread once per tick period (``SerialPorts.start_ticks``)."""

READ_SIZE = 4096
"""Largest read of one port at once, bytes."""


@dataclass(eq=False)
class SerialLink:
    """One serial port as the reader thread keeps it; read its state, do not modify it.

    Attributes
    ----------
    device : str
        Port path (a device or a symlink to one).
    baud : int
        Baud rate, bit/s.
    reconnect_s : float
        Time between two attempts to (re-)open the port, s.
    on_data : OnData
        Receives every chunk read, in the reader thread.
    error : str
        Why the port is not open ("" while it is; "not opened yet" before the first attempt).
    reconnects : int
        Times the port was re-opened after it had been open.
    """

    device: str
    baud: int
    reconnect_s: float
    on_data: OnData
    error: str = "not opened yet"
    reconnects: int = 0
    _port: serial.Serial | None = field(default=None, repr=False)
    _was_open: bool = field(default=False, repr=False)
    _retry_at: float = field(default=0.0, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _tick: tuple[float, OnTick] | None = field(default=None, repr=False)
    _tick_at: float = field(default=0.0, repr=False)

    @property
    def is_open(self) -> bool:
        """Whether the port is open."""
        return self._port is not None

    def write(self, data: bytes) -> bool:
        """Write ``data`` without blocking; False when the port is not open or the write fails.

        A failed write is not a lost port: the reader thread notices that when reading.
        """
        with self._lock:
            port = self._port
            if port is None:
                return False
            try:
                port.write(data)
            except (serial.SerialException, OSError):
                return False
            return True


class SerialPorts:
    """Every serial port of the process, read by one daemon thread (see module docstring).

    Parameters
    ----------
    clock_ns : Callable[[], int]
        Host clock that stamps each read, ns (the ROS clock in a node).
    """

    def __init__(self, clock_ns: Callable[[], int] = time.time_ns) -> None:
        self._clock_ns = clock_ns
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._selector.register(self._wake_r, selectors.EVENT_READ, None)
        self._lock = threading.Lock()
        self._links: list[SerialLink] = []
        self._to_close: list[SerialLink] = []
        self._thread: threading.Thread | None = None

    def open(self, device: str, baud: int, reconnect_s: float, on_data: OnData) -> SerialLink:
        """Start reading ``device``; the reader thread opens it now and again after failures.

        Raises
        ------
        ValueError
            If ``baud`` or ``reconnect_s`` is not positive.
        """
        if baud <= 0 or reconnect_s <= 0:
            raise ValueError(f"{device}: baud and reconnect period must be positive")
        link = SerialLink(device, baud, reconnect_s, on_data)
        with self._lock:
            self._links.append(link)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="serial-ports", daemon=True)
                self._thread.start()
        self._wake()
        return link

    def close(self, link: SerialLink) -> None:
        """Stop reading ``link`` and close its port (done by the reader thread, soon after)."""
        with self._lock:
            if link in self._links:
                self._links.remove(link)
                self._to_close.append(link)
        self._wake()

    def start_ticks(self, link: SerialLink, period_s: float, on_tick: OnTick) -> None:
        """Call ``on_tick`` in the reader thread every ``period_s`` until ``stop_ticks``.

        Ticks fall on whole multiples of ``period_s`` of the monotonic clock, so every port of
        one period ticks in the same wake; a tick the thread is too late for is skipped, never
        made up in a burst. They go on while the port is closed (a write then fails).

        Raises
        ------
        ValueError
            If ``period_s`` is not positive.
        """
        if not period_s > 0:
            raise ValueError(f"{link.device}: tick period must be positive")
        with self._lock:
            link._tick = (period_s, on_tick)
            link._tick_at = _next_multiple(time.monotonic(), period_s)
        self._wake()

    def stop_ticks(self, link: SerialLink) -> None:
        """Stop ``link``'s ticks; a tick under way in the reader thread still ends."""
        with self._lock:
            link._tick = None

    def _wake(self) -> None:
        with contextlib.suppress(BlockingIOError):
            os.write(self._wake_w, b"\0")

    def _run(self) -> None:
        while True:
            with self._lock:
                links, closing = list(self._links), self._to_close
                self._to_close = []
            for link in closing:
                self._release(link, "closed")
            now = time.monotonic()
            for link in links:
                if link._port is None and now >= link._retry_at:
                    self._try_open(link, now)
            self._run_ticks(links, time.monotonic())
            due = [link._retry_at for link in links if link._port is None]
            due += [link._tick_at for link in links if link._tick is not None]
            timeout = max(0.0, min(due) - time.monotonic()) if due else None
            for key, _ in self._selector.select(timeout):
                if key.data is None:
                    with contextlib.suppress(BlockingIOError):
                        os.read(self._wake_r, READ_SIZE)
                else:
                    self._read(key.data, key.fd)

    def _run_ticks(self, links: list[SerialLink], now: float) -> None:
        for link in links:
            with self._lock:
                tick = link._tick
                if tick is None or now < link._tick_at:
                    continue
                link._tick_at = _next_multiple(now, tick[0])
            tick[1]()

    def _try_open(self, link: SerialLink, now: float) -> None:
        try:
            port = serial.Serial(link.device, link.baud, timeout=0, write_timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            link.error = f"{link.device}: {exc}"
            link._retry_at = now + link.reconnect_s
            return
        with link._lock:
            link._port = port
        self._selector.register(port.fileno(), selectors.EVENT_READ, link)
        if link._was_open:
            link.reconnects += 1
        link._was_open = True
        link.error = ""

    def _read(self, link: SerialLink, fd: int) -> None:
        try:
            data = os.read(fd, READ_SIZE)
        except BlockingIOError:
            return
        except OSError as exc:
            self._release(link, f"read failed: {exc}")
            return
        if not data:
            self._release(link, "the port reports end of file (device gone?)")
            return
        link.on_data(data, self._clock_ns())

    def _release(self, link: SerialLink, reason: str) -> None:
        with link._lock:
            port, link._port = link._port, None
        if port is None:
            return
        with contextlib.suppress(KeyError, ValueError, OSError):
            self._selector.unregister(port.fileno())
        with contextlib.suppress(Exception):
            port.close()
        link.error = f"{link.device}: {reason}"
        link._retry_at = time.monotonic() + link.reconnect_s


def _next_multiple(now: float, period_s: float) -> float:
    """The first whole multiple of ``period_s`` after ``now`` (both s)."""
    return (now // period_s + 1.0) * period_s
