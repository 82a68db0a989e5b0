"""What a measured trace says, and where a model disagrees with it.

``prepare_measured`` turns a measured trace into ``Measured`` (despiked, per-channel noise
level, fit / held-out blocks); ``simulate_model`` and ``weighted_residuals`` compare a
configuration with it per channel (``where`` says where the difference lies).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import binary_dilation, median_filter

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.sim.config import SimConfig
from thruster_fdd_shore.core.sim.freerun import free_run

CHANNELS = ("rpm", "current", "voltage")
"""Compared signals; the voltage channel is the model's bus voltage (supply minus sag)."""


SUPPLY_WINDOW_S = 60.0
"""Rolling-median window of the supply-voltage reconstruction, s."""


N_BLOCKS = 10


HELD_BLOCKS = (2, 5, 8)


FOLDS = ((0, 5), (1, 6), (2, 7), (3, 8), (4, 9))
"""Held-out blocks of the cross-validation folds (``with_held``): each block held out once,
each fold two blocks half the trace apart."""


@dataclass(frozen=True)
class Measured:
    """A measured trace prepared for fitting.

    Attributes
    ----------
    t, command, voltage, rpm, current : np.ndarray, shape (n,)
        Despiked measurement (s, -1..1, V, rpm, A).
    fit, held : np.ndarray of bool, shape (n,)
        Fit and held-out samples (interleaved blocks; disjoint, together all samples).
    sigma : dict of str to float
        Noise standard deviation per channel (rpm, A, V), estimated from second differences.
    rpm_floor : float
        Reporting floor of the speed, rpm (measured zeros are censored below it), read from
        the data (``reporting_floor``).
    floor_zeroes_current : bool
        Whether the current is reported as 0 under the floor too (read from the data).
    window : int
        Supply reconstruction window in samples.
    """

    t: np.ndarray
    command: np.ndarray
    voltage: np.ndarray
    rpm: np.ndarray
    current: np.ndarray
    fit: np.ndarray
    held: np.ndarray
    sigma: dict[str, float]
    rpm_floor: float
    floor_zeroes_current: bool
    window: int

    def channel(self, name: str) -> np.ndarray:
        """Measured samples of channel ``name`` (one of ``CHANNELS``), shape (n,)."""
        return getattr(self, name)


def block_of(n: int) -> np.ndarray:
    """Block (0 .. ``N_BLOCKS`` - 1) of each of ``n`` samples, consecutive equal parts, shape
    (n,)."""
    return np.minimum((np.arange(n) * N_BLOCKS) // n, N_BLOCKS - 1)


def _held(n: int, blocks: tuple[int, ...]) -> np.ndarray:
    """Mask of shape (n,): the samples of ``blocks`` of ``N_BLOCKS`` equal interleaved ones."""
    return np.isin(block_of(n), blocks)


def with_held(data: Measured, blocks: tuple[int, ...]) -> Measured:
    """``data`` with ``blocks`` held out and the rest the fit samples (a fold of ``FOLDS``)."""
    held = _held(len(data.t), blocks)
    return replace(data, fit=~held, held=held)


MOVING = 0.05
"""Least share of samples in which a channel's value changes for its grid to be a sensor's."""


def _grid_step(x: np.ndarray) -> float:
    """Quantisation step of a channel read from its values, in its unit; 0 if it has none.

    The 10th percentile of the gaps between its distinct non-zero values: the grid step of a
    quantised sensor even where a few values lie off the grid (continuous data give a step
    near 0). A channel whose value changes in under ``MOVING`` of its samples (outside
    stretches of 0) holds set-points, exact on their levels (a bench supply): no grid.
    """
    live = (x[1:] != 0.0) | (x[:-1] != 0.0)
    levels = np.unique(x[x != 0.0])
    if len(levels) < 3 or np.mean((np.diff(x) != 0.0)[live]) < MOVING:
        return 0.0
    return float(np.percentile(np.diff(levels), 10))


def _noise_sigma(x: np.ndarray, floor: float) -> float:
    """Noise std of a channel, quantisation included, at least ``floor``.

    ``sqrt(s**2 + q**2 / 12)``: ``s`` from the MAD of second differences (robust to steps),
    ``q`` the grid step (``_grid_step``). A grid coarse against the noise holds a steady
    signal on one level, so its second differences are mostly exactly 0 and ``s`` misses the
    rounding error, which against the true signal is uniform over a step (variance
    ``q**2 / 12``); on a fine grid the term is negligible. Stretches that are exactly 0
    (under a reporting floor) are left out; averaged, noise-free data (second differences
    mostly exactly 0) gets the floor.
    """
    d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
    d2 = d2[(x[2:] != 0.0) | (x[1:-1] != 0.0) | (x[:-2] != 0.0)]
    if len(d2) < 10:
        return floor
    s = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)
    return max(math.sqrt(s**2 + _grid_step(x) ** 2 / 12.0), floor)


BEND_SAMPLES = 2
"""Samples after a command bend in which a deviation the way the command moved is kept."""


@dataclass(frozen=True)
class Follows:
    """How a channel follows the command, for despiking.

    Attributes
    ----------
    sign : float
        +1 if the channel moves with the command, -1 against it.
    magnitude : bool
        Whether it follows the command's magnitude rather than the signed command.
    peaks : bool
        Whether it can peak for a sample in a transient (after a step, when the rotor brakes),
        not only at a one-sample command pulse.
    """

    sign: float
    magnitude: bool
    peaks: bool


FOLLOWS: dict[str, Follows] = {
    "rpm": Follows(sign=1.0, magnitude=False, peaks=False),
    "current": Follows(sign=1.0, magnitude=True, peaks=True),
    "voltage": Follows(sign=-1.0, magnitude=True, peaks=True),
}
"""The speed follows the signed command and, through the rotor's inertia, is monotone after a
step; the bus current follows its magnitude and may peak for a sample after a step or dip when
the rotor brakes; the bus voltage sags against it."""


def _command_moves(command: np.ndarray, follows: Follows) -> np.ndarray:
    """Way a channel may move at each command bend, shape (n,): +1 or -1, 0 where it may not
    peak, 2 either way (a reversal: the magnitude says nothing of the braking in between).

    A bend is a second difference over 0.02. A one-sample pulse moves the way it deviates from
    its neighbours' median, a step the way the command changes across the sample.
    """
    padded = np.pad(command, 1, mode="edge")
    bend = _bends(command) > 0.02
    u = follows.sign * (np.abs(command) if follows.magnitude else command)
    pulse = u - median_filter(u, size=3, mode="nearest")
    padded_u = np.pad(u, 1, mode="edge")
    step = padded_u[2:] - padded_u[:-2] if follows.peaks else np.zeros_like(u)
    move = np.sign(np.where(pulse != 0.0, pulse, step))
    if follows.magnitude:
        move = np.where(padded[:-2] * padded[2:] < 0.0, 2.0, move)
    return np.where(bend, move, 0.0)


SHARP = 0.1
"""Share of a channel's full scale by which it must bend within a sample to count as moving
sharply (``_sharp``): above a coarse sensor's steps (up to 100 rpm, 2.5 % of a t100's
speed) and a reporting floor's jump, below a braking rotor's (t200: 1000-3000 rpm)."""


def _sharp(x: np.ndarray, sigma: float) -> np.ndarray:
    """Where ``x`` (shape (n,)) moves sharply, at the sample or one beside it: it bends by
    more than ``SHARP`` of its full scale and 8 noise std of a second difference (``sigma``
    times sqrt 6) with no spike (8 sigma off the 5-sample median) at or beside the sample, so
    the move lasts: a transient, not noise or a glitch."""
    limit = max(SHARP * float(np.max(np.abs(x))), 8.0 * math.sqrt(6.0) * sigma)
    spike = np.abs(x - median_filter(x, size=5, mode="nearest")) > 8.0 * sigma
    return binary_dilation((_bends(x) > limit) & ~binary_dilation(spike))


def _bends(x: np.ndarray) -> np.ndarray:
    """Size of the second difference at each sample of ``x`` (shape (n,), ends repeated)."""
    padded = np.pad(x, 1, mode="edge")
    return np.abs(padded[:-2] - 2.0 * padded[1:-1] + padded[2:])


def _despike(
    x: np.ndarray, sigma: float, command: np.ndarray, follows: Follows, transient: np.ndarray
) -> np.ndarray:
    """Replace isolated spikes (more than 8 sigma off the 5-sample median) by that median.

    Kept is a deviation the way the command (shape (n,)) moved at a bend up to
    ``BEND_SAMPLES`` samples before (``_command_moves``): a one-sample response to a
    one-sample command, as in a bench log with one rest row at neutral between two steps, or
    the current peak of a fast thruster a sample or two after a step. And, in a channel that
    ``peaks``, one where another channel moves sharply too (``transient``, shape (n,)): a
    glitch hits one channel, while the current's dip when a reversing rotor brakes shows in
    the speed as well, however long after the command a dead time puts it (the speed itself is
    monotone there). Ramps and holds are straight.
    """
    med = median_filter(x, size=5, mode="nearest")
    dev = x - med
    move = _command_moves(command, follows)
    kept = transient & follows.peaks
    for lag in range(BEND_SAMPLES + 1):
        m = np.concatenate([np.zeros(lag), move[: len(x) - lag]])
        kept |= (m == 2.0) | (m * dev > 0.0)
    spikes = ~kept & (np.abs(dev) > 8.0 * sigma)
    return np.where(spikes, med, x)


def reporting_floor(rpm: np.ndarray, current: np.ndarray) -> tuple[float, bool]:
    """Reporting floor of a measured speed and whether it zeroes the current too.

    A sensor that reports 0 under a floor reports every other speed at or above it, so the
    floor is the smallest non-zero |rpm| when the trace holds zeros at all (no zeros: 0, no
    censoring). Its current is zeroed too when at least 90 % of the zero-speed samples carry
    a current of exactly 0. Read from the data, not from the starting configuration: a
    sensor with a higher floor than the model assumes would otherwise make every measured 0
    between the two look like a flat zone (deadband, stiction).

    Parameters
    ----------
    rpm, current : np.ndarray, shape (n,)
        Measured speed (rpm) and bus current (A), before despiking.
    """
    zero = rpm == 0.0
    if not np.any(zero) or np.all(zero):
        return 0.0, False
    return float(np.min(np.abs(rpm[~zero]))), bool(np.mean(current[zero] == 0.0) >= 0.9)


def prepare_measured(trace: Trace, config: SimConfig) -> Measured:
    """Despike, estimate noise and split a measured trace.

    Parameters
    ----------
    trace : Trace
        Measured trace with at least 100 samples spanning at least 20 s.
    config : SimConfig
        Starting configuration (not used: the reporting floor is read from the data).

    Raises
    ------
    BadInputError
        If the trace is too short, holds non-finite values or never moves the thruster.
    """
    n = len(trace.t)
    if n < 100 or trace.t[-1] - trace.t[0] < 20.0:
        raise BadInputError(f"measured trace too short: {n} samples, need >= 100 over >= 20 s")
    cols = {c: np.asarray(getattr(trace, c), dtype=float) for c in ("t", "command", *CHANNELS)}
    for name, arr in cols.items():
        if not np.all(np.isfinite(arr)):
            raise BadInputError(f"measured trace column {name!r} holds non-finite values")
    if np.max(np.abs(cols["rpm"])) <= 0.0:
        raise BadInputError("measured trace never turns the thruster (rpm is 0 throughout)")
    if np.min(cols["voltage"]) <= 0.0:
        raise BadInputError("measured trace voltage must be > 0 V")
    floors = {
        "rpm": 2e-3 * float(np.max(np.abs(cols["rpm"]))),
        "current": max(2e-3 * float(np.max(np.abs(cols["current"]))), 1e-3),
        "voltage": 1e-3 * float(np.median(cols["voltage"])),
    }
    sigma = {c: _noise_sigma(cols[c], floors[c]) for c in CHANNELS}
    sharp = {c: _sharp(cols[c], sigma[c]) for c in CHANNELS}
    clean = {
        c: _despike(
            cols[c],
            sigma[c],
            cols["command"],
            FOLLOWS[c],
            np.any([sharp[o] for o in CHANNELS if o != c], axis=0),
        )
        for c in CHANNELS
    }
    held = _held(n, HELD_BLOCKS)
    dt = float(np.median(np.diff(cols["t"])))
    rpm_floor, floor_zeroes_current = reporting_floor(cols["rpm"], cols["current"])
    return Measured(
        t=cols["t"] - cols["t"][0],
        command=np.clip(cols["command"], -1.0, 1.0),
        voltage=clean["voltage"],
        rpm=clean["rpm"],
        current=clean["current"],
        fit=~held,
        held=held,
        sigma=sigma,
        rpm_floor=rpm_floor,
        floor_zeroes_current=floor_zeroes_current,
        window=max(3, round(SUPPLY_WINDOW_S / dt) | 1),
    )


def supply_voltage(data: Measured, r_internal_ohm: float) -> np.ndarray:
    """Supply voltage reconstructed from the measured bus voltage, V, shape (n,).

    ``V_supply = rolling median over SUPPLY_WINDOW_S of (V_bus + r_internal_ohm * I)``, rounded
    to 10 mV: slow supply changes (battery, bench set-points) are followed, the fast drop with
    current is left to the model's ``voltage_sag``. The window is mirrored at the trace's ends,
    so that no single end sample becomes the median of a half-window.
    """
    key = (hash(data.voltage.tobytes()), hash(data.current.tobytes()), data.window, r_internal_ohm)
    if key not in _SUPPLY:
        raw = data.voltage + r_internal_ohm * data.current
        if len(_SUPPLY) >= 16:
            _SUPPLY.pop(next(iter(_SUPPLY)))
        _SUPPLY[key] = np.round(median_filter(raw, size=data.window, mode="reflect"), 2)
    return _SUPPLY[key]


_SUPPLY: dict[tuple, np.ndarray] = {}
"""The last reconstructions by measurement and resistance: a search simulates thousands of
models that share one sag resistance."""


def simulate_model(config: SimConfig, data: Measured) -> dict[str, np.ndarray]:
    """Free-run, noise-free simulation driven by the measured command and supply voltage.

    The compiled ``core.sim.freerun.free_run``: equal (to rounding, tested) to the reference
    ``ThrusterSimulator`` of ``config`` without noise or spread, stepped through the measured
    command with the supply of ``supply_voltage`` set before each step.

    Returns
    -------
    dict of str to np.ndarray, each shape (n,)
        ``rpm`` (raw, no reporting floor), ``current`` (A) and ``voltage`` (bus, V).
    """
    sag = config.effect("voltage_sag")
    supply = supply_voltage(data, sag.params()["r_internal_ohm"] if sag else 0.0)
    return free_run(config, data.t, data.command, supply)  # noise-free: it ignores the noise


def reported(sim: dict[str, np.ndarray], data: Measured) -> dict[str, np.ndarray]:
    """Apply the reporting floor to a simulation, as the telemetry would show it."""
    below = np.abs(sim["rpm"]) < data.rpm_floor
    out = dict(sim)
    out["rpm"] = np.where(below, 0.0, sim["rpm"])
    if data.floor_zeroes_current:
        out["current"] = np.where(below, 0.0, sim["current"])
    return out


def _uncensored(data: Measured) -> dict[str, np.ndarray]:
    """Per channel, the samples the reporting floor leaves informative, shape ``(n,)`` bool:
    a reported 0 rpm says only "below the floor" (and 0 A too where the floor zeroes the
    current); the bus voltage is always measured."""
    below = data.rpm == 0.0 if data.rpm_floor > 0.0 else np.zeros(len(data.t), bool)
    return {
        "rpm": ~below,
        "current": ~below if data.floor_zeroes_current else np.ones(len(data.t), bool),
        "voltage": np.ones(len(data.t), bool),
    }


def weighted_residuals(sim: dict[str, np.ndarray], data: Measured) -> dict[str, np.ndarray]:
    """Measured minus simulated, per channel, shape (n,), with the floor treated as censoring.

    Where the measured speed is 0 under a reporting floor, the speed residual is the model's
    excess over the floor (0 if the model is under it too) and, if the floor also zeroes the
    current, the current residual is 0. Continuous in the parameters, unlike a hard floor.
    """
    res = {c: data.channel(c) - sim[c] for c in CHANNELS}
    if data.rpm_floor > 0.0:
        seen = _uncensored(data)
        excess = np.maximum(np.abs(sim["rpm"]) - data.rpm_floor, 0.0) * np.sign(sim["rpm"])
        res["rpm"] = np.where(seen["rpm"], res["rpm"], -excess)
        res["current"] = np.where(seen["current"], res["current"], 0.0)
    return res
