"""Command signals for simulation and experiments (normalised command -1..1)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from thruster_fdd.core.errors import BadInputError

SIGNAL_FORMS = ("steps", "sine:F", "chirp", "multilevel", "mission", "patrol")
"""Accepted ``spec`` forms of ``make_signal`` (F is a frequency in Hz)."""


STEP_LEVELS: tuple[float, ...] = (
    0.0, 0.25, 0.5, 0.75, 1.0, 0.75, 0.5, 0.25, 0.0, -0.25, -0.5, -0.75, -1.0, -0.75, -0.5, -0.25,
)  # fmt: skip
"""One cycle of the paper's staircase of 0.25 command steps."""


STEP_HOLD_S = 10.0
"""Hold time of each step, s (the T100 settles in about 3 s)."""


CHIRP_F0_HZ = 0.01


CHIRP_F1_HZ = 0.1


def make_signal(
    spec: str, duration_s: float, rate_hz: float, *, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Build a command signal.

    Parameters
    ----------
    spec : str
        ``"steps"`` (the paper's 0.25 steps, each held ``STEP_HOLD_S``), ``"sine:F"`` (amplitude
        1, F in Hz), ``"chirp"`` (linear 0.01 -> 0.1 Hz over the duration, amplitude 1),
        ``"multilevel"`` (random levels held 2-15 s), ``"mission"`` (transit plateaus,
        station keeping, reversals, idle), ``"patrol"`` (a resident vehicle's long patrol:
        idle holds, creeping at small commands, long cruise legs, turns, short reversals,
        every change ramped).
    duration_s : float
        Signal length, s, > 0.
    rate_hz : float
        Sample rate, Hz, > 0.
    seed : int
        Seed of the random forms (``multilevel``, ``mission``).

    Returns
    -------
    t : np.ndarray, shape (n,)
        Sample times from 0, s; ``n = max(1, round(duration_s * rate_hz))``.
    command : np.ndarray, shape (n,)
        Normalised command in [-1, 1].

    Raises
    ------
    ValueError
        If the spec is not one of the accepted forms, or duration or rate are not positive.
    """
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise BadInputError(f"duration_s must be > 0, got {duration_s}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise BadInputError(f"rate_hz must be > 0, got {rate_hz}")
    n = max(1, round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    rng = np.random.default_rng(seed)
    if spec == "steps":
        idx = np.floor(t / STEP_HOLD_S).astype(int) % len(STEP_LEVELS)
        command = np.asarray(STEP_LEVELS)[idx]
    elif spec.startswith("sine:"):
        freq = _parse_frequency(spec, rate_hz)
        command = np.sin(2.0 * math.pi * freq * t)
    elif spec == "chirp":
        span = max(duration_s, 1.0 / rate_hz)
        phase = CHIRP_F0_HZ * t + 0.5 * (CHIRP_F1_HZ - CHIRP_F0_HZ) * t * t / span
        command = np.sin(2.0 * math.pi * phase)
    elif spec == "multilevel":
        command = _hold_pieces(t, lambda: (rng.uniform(-1.0, 1.0), rng.uniform(2.0, 15.0)))
    elif spec == "mission":
        command = _mission(t, rng)
    elif spec == "patrol":
        command = _patrol(t, rng)
    else:
        raise BadInputError(
            f"unknown signal spec {spec!r}; expected one of {', '.join(SIGNAL_FORMS)}"
        )
    return t, np.clip(command, -1.0, 1.0)


def _parse_frequency(spec: str, rate_hz: float) -> float:
    try:
        freq = float(spec.split(":", 1)[1])
    except ValueError as exc:
        raise BadInputError(f"bad sine spec {spec!r}; expected 'sine:F' with F in Hz") from exc
    if not (math.isfinite(freq) and 0 < freq < rate_hz / 2):
        raise BadInputError(
            f"sine frequency must be in (0, {rate_hz / 2}) Hz (Nyquist), got {freq}"
        )
    return freq


def _hold_pieces(t: np.ndarray, draw: Callable[[], tuple[float, float]]) -> np.ndarray:
    """Piecewise-constant signal: ``draw()`` gives (level, hold_s) until ``t`` is covered."""
    command = np.empty_like(t)
    start = 0.0
    while start <= t[-1]:
        level, hold = draw()
        command[(t >= start) & (t < start + hold)] = level
        start += hold
    return command


def _mission(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Mission-like pattern: random sequence of transit, station keeping, reversal and idle."""
    command = np.zeros_like(t)
    start = 0.0
    level = 0.0
    while start <= t[-1]:
        kind = rng.choice(["transit", "station", "reversal", "idle"], p=[0.35, 0.3, 0.15, 0.2])
        hold = rng.uniform(20.0, 60.0) if kind in ("transit", "station") else rng.uniform(5.0, 20.0)
        sel = (t >= start) & (t < start + hold)
        tau = t[sel] - start
        if kind == "transit":
            new = rng.choice([-1.0, 1.0], p=[0.2, 0.8]) * rng.uniform(0.4, 0.9)
            ramp = np.clip(tau / 5.0, 0.0, 1.0)  # thrusters are ramped up, not kicked
            command[sel] = level + (new - level) * ramp
            level = new
        elif kind == "station":
            bias = rng.uniform(-0.1, 0.1)
            freqs = rng.uniform(0.05, 0.3, size=3)
            phases = rng.uniform(0.0, 2.0 * math.pi, size=3)
            wave = np.sin(2.0 * math.pi * freqs[:, None] * tau[None, :] + phases[:, None])
            command[sel] = bias + 0.1 * wave.sum(axis=0)  # peaks near +-0.3, mostly +-0.15
            level = bias
        elif kind == "reversal":
            new = -math.copysign(rng.uniform(0.3, 0.8), level if level != 0.0 else 1.0)
            command[sel] = new
            level = new
        else:
            command[sel] = 0.0
            level = 0.0
        start += hold
    return command


PATROL_SLEW_PER_S = 0.1
"""Largest command change per second of ``patrol`` (a vehicle's controller ramps thrust)."""


def _patrol(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A long patrol: a random sequence of idle holds (10-90 s), creeping (|command| 0.05-0.2,
    20-120 s), cruise legs (0.35-0.85, 60-400 s), turns (a cruise level swung by up to 0.25
    every 4-15 s, 30-120 s) and short reversals (-0.25..-0.7, 3-12 s), slew-limited to
    ``PATROL_SLEW_PER_S``."""
    target = np.zeros_like(t)
    start = 0.0
    cruise = 0.6
    kinds = ["idle", "creep", "cruise", "turns", "reversal"]
    while start <= t[-1]:
        kind = rng.choice(kinds, p=[0.15, 0.2, 0.3, 0.2, 0.15])
        if kind == "idle":
            hold, level = rng.uniform(10.0, 90.0), 0.0
        elif kind == "creep":
            hold, level = rng.uniform(20.0, 120.0), rng.choice([-1, 1]) * rng.uniform(0.05, 0.2)
        elif kind == "cruise":
            cruise = rng.uniform(0.35, 0.85)
            hold, level = rng.uniform(60.0, 400.0), cruise
        elif kind == "reversal":
            hold, level = rng.uniform(3.0, 12.0), -rng.uniform(0.25, 0.7)
        else:
            hold, level = rng.uniform(30.0, 120.0), None
        sel = (t >= start) & (t < start + hold)
        if level is None:
            swings = _hold_pieces(
                t[sel] - start, lambda: (rng.uniform(-0.25, 0.25), rng.uniform(4.0, 15.0))
            )
            target[sel] = np.clip(cruise + swings, 0.0, 1.0)
        else:
            target[sel] = level
        start += hold
    command = np.empty_like(target)
    command[0] = target[0]
    steps = np.diff(t, prepend=t[0]) * PATROL_SLEW_PER_S
    for i in range(1, len(t)):
        command[i] = command[i - 1] + np.clip(target[i] - command[i - 1], -steps[i], steps[i])
    return command
