"""Which telemetry frames the driver publishes: the sequence-number window of docs/protocol.md.

A serial line delivers bytes in order, so a frame whose sequence number is not ahead of the
newest one is never a late frame: it is a duplicate (same number) or a replay (an older one,
e.g. a bridge that re-sends its buffer after a glitch). Such frames are dropped. The newest
number moves only forward (serial-number arithmetic, u16 wrap 65535 -> 0 is progress).

Two legitimate events move it back: a bridge reset announced by the RESET status bit (the frame
is taken and the window re-anchored on it), and a restart whose RESET frame was lost (numbers far
behind the window): the window re-anchors once ``confirm`` consecutive frames continue that new
numbering, and drops them until then. A replayed RESET frame (the same number and bridge time as
the last RESET frame taken) is dropped like any replay. No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from thruster_fdd.core.bridge.tfdd import SEQ_MODULUS, checked_int

DEFAULT_WINDOW = 1024
"""Sequence numbers up to this far behind the newest are replays (20 s at 50 Hz)."""


DEFAULT_CONFIRM = 8
"""Consecutive frames far behind the window that re-anchor it (a restart without RESET)."""


Verdict = Literal["ok", "lost", "duplicate", "replayed", "reset", "resync", "pending"]


@dataclass(frozen=True)
class SeqDecision:
    """What to do with one frame.

    Attributes
    ----------
    publish : bool
        Whether the frame is new telemetry.
    verdict : str
        ``ok`` (the next number), ``lost`` (``lost`` numbers skipped), ``duplicate`` (the newest
        number again), ``replayed`` (an older number within the window), ``reset`` (RESET bit:
        window re-anchored), ``resync`` (re-anchored on a new numbering without RESET),
        ``pending`` (far behind the window, waiting for confirmation; dropped).
    lost : int
        Frames missing before this one (``lost`` only).
    """

    publish: bool
    verdict: Verdict
    lost: int = 0


@dataclass(frozen=True)
class SeqCounts:
    """Counters of a :class:`SequenceWindow` since it was created (a snapshot).

    Attributes
    ----------
    accepted : int
        Frames to publish.
    lost : int
        Sequence numbers skipped (frames that never arrived).
    duplicates : int
        Frames with the newest number again (dropped).
    replayed : int
        Frames with an older number within the window, or far behind it without confirmation
        (dropped).
    resets : int
        RESET frames that re-anchored the window after the first frame (a bridge restarting
        while the driver runs).
    resyncs : int
        Re-anchorings on a new numbering without a RESET frame.
    """

    accepted: int = 0
    lost: int = 0
    duplicates: int = 0
    replayed: int = 0
    resets: int = 0
    resyncs: int = 0


class SequenceWindow:
    """The anti-replay window over one bridge's u16 sequence numbers (module docstring).

    Parameters
    ----------
    window : int
        Numbers 1..``window`` behind the newest are replays, 1..32767.
    confirm : int
        Consecutive frames beyond the window that re-anchor it, >= 2.

    Raises
    ------
    ValueError
        If ``window`` or ``confirm`` is out of range.
    """

    def __init__(self, window: int = DEFAULT_WINDOW, confirm: int = DEFAULT_CONFIRM) -> None:
        self._window = checked_int("window", window, 1, SEQ_MODULUS // 2 - 1)
        self._confirm = checked_int("confirm", confirm, 2, SEQ_MODULUS // 2 - 1)
        self._newest: int | None = None
        self._candidate: tuple[int, int] | None = None  # (last number, run length)
        self._last_reset: tuple[int, int | None] | None = None
        self._counts = SeqCounts()

    @property
    def newest(self) -> int | None:
        """The newest sequence number taken, None before the first frame."""
        return self._newest

    def counts(self) -> SeqCounts:
        """Return a snapshot of the counters."""
        return self._counts

    def _count(self, **increments: int) -> None:
        c = self._counts
        self._counts = SeqCounts(**{k: getattr(c, k) + increments.get(k, 0) for k in vars(c)})

    def _take(self, seq: int, verdict: Verdict, lost: int = 0) -> SeqDecision:
        self._newest = seq
        self._candidate = None
        self._count(accepted=1, lost=lost)
        return SeqDecision(True, verdict, lost)

    def check(
        self, seq: int, reset: bool = False, bridge_time_us: int | None = None
    ) -> SeqDecision:
        """Decide about one frame and update the window.

        Parameters
        ----------
        seq : int
            The frame's sequence number, 0..65535.
        reset : bool
            Whether the frame carries the RESET status bit.
        bridge_time_us : int or None
            The bridge's timestamp of the frame, µs (tells a replayed RESET frame from a new
            one); None when unknown.

        Returns
        -------
        SeqDecision
            Whether to publish and why.

        Raises
        ------
        ValueError
            If ``seq`` is outside 0..65535.
        """
        checked_int("seq", seq, 0, SEQ_MODULUS - 1)
        if reset:
            if self._last_reset == (seq, bridge_time_us):
                self._count(replayed=1)
                return SeqDecision(False, "replayed")
            self._last_reset = (seq, bridge_time_us)
            # A bridge that starts with the driver is no event; one that restarts later is.
            self._count(resets=int(self._newest is not None))
            return self._take(seq, "reset")
        if self._newest is None:
            return self._take(seq, "ok")
        ahead = (seq - self._newest) % SEQ_MODULUS
        if ahead == 0:
            self._count(duplicates=1)
            return SeqDecision(False, "duplicate")
        if ahead < SEQ_MODULUS // 2:
            return self._take(seq, "ok" if ahead == 1 else "lost", ahead - 1)
        if SEQ_MODULUS - ahead <= self._window:
            self._count(replayed=1)
            return SeqDecision(False, "replayed")
        return self._far_behind(seq)

    def _far_behind(self, seq: int) -> SeqDecision:
        """A number beyond the window: a restart whose RESET frame was lost, or an old replay."""
        run = 1
        if self._candidate is not None and seq == (self._candidate[0] + 1) % SEQ_MODULUS:
            run = self._candidate[1] + 1
        if run >= self._confirm:
            self._count(resyncs=1)
            return self._take(seq, "resync")
        self._candidate = (seq, run)
        self._count(replayed=1)
        return SeqDecision(False, "pending")
