"""A serial line stuck low or high: long runs of 0x00 or 0xFF bytes are a link fault.

A receive line held low (a broken wire to a powered-down bridge, a short) reads as a stream of
0x00 bytes (UART breaks); a floating or shorted-high line through some adapters as 0xFF. Neither
ever forms a tfdd frame (no sync), but ten 0x00 bytes are a KISS frame with a valid CRC-8
(0 V, 0 A, 0 rpm), so the decoders count such runs and the KISS decoder never returns a frame
made of one repeated 0x00 / 0xFF byte. No ROS import.
"""

from __future__ import annotations

import re

STUCK_RUN_BYTES = 16
"""Shortest run of one repeated 0x00 or 0xFF byte taken as a stuck line. Valid frames hold at
most 8 such bytes in a row (tfdd: zero current and rpm then status; KISS: zero current,
consumption and eRPM, a zero CRC, and the next frame's 0 °C)."""


_RUNS = re.compile(rb"\x00+|\xff+")


class StuckRun:
    """Counts bytes that belong to runs of at least ``min_run`` 0x00 or 0xFF bytes, across
    chunk boundaries.

    Parameters
    ----------
    min_run : int
        Shortest run counted, bytes (>= 2).
    """

    def __init__(self, min_run: int = STUCK_RUN_BYTES) -> None:
        if min_run < 2:
            raise ValueError(f"min_run must be >= 2, got {min_run}")
        self._min_run = min_run
        self._byte: int | None = None
        self._run = 0
        self.low_bytes = 0
        """Bytes in runs of 0x00 of at least ``min_run``."""
        self.high_bytes = 0
        """Bytes in runs of 0xFF of at least ``min_run``."""

    @property
    def stuck(self) -> str:
        """``"low"`` or ``"high"`` while the current run is long enough, else ``""``."""
        if self._byte is None or self._run < self._min_run:
            return ""
        return "low" if self._byte == 0 else "high"

    def _extend(self, byte: int, n: int) -> None:
        before, self._run = self._run, self._run + n
        if self._run < self._min_run:
            return
        # The bytes of a run count from its start once it is long enough.
        counted = self._run if before < self._min_run else n
        if byte == 0:
            self.low_bytes += counted
        else:
            self.high_bytes += counted

    def feed(self, data: bytes) -> None:
        """Account for the next received bytes, any length."""
        pos = 0
        if self._byte is not None and data:
            rest = data.lstrip(bytes([self._byte]))
            pos = len(data) - len(rest)
            self._extend(self._byte, pos)
            if not rest:
                return
            self._byte, self._run = None, 0
        for match in _RUNS.finditer(data, pos):
            byte = data[match.start()]
            self._byte, self._run = byte, 0
            self._extend(byte, match.end() - match.start())
            if match.end() < len(data):
                self._byte, self._run = None, 0
