"""Synthetic measured traces with hidden effects, for tests, the study and the benchmark.

A case hides effects from the model: the "measured" trace is simulated (with unit spread,
noise, quantisation and outliers) with the hidden effects set to random plausible values, and
the model starts without them. Three families:

- exact base (``make_case``): the measured unit is the t100 preset's (plus spread); only the
  hidden effects differ from the start;
- mismatch (``make_mismatch_case``): the measured thruster's base physics also differ from the
  start preset (``t100`` or ``t200``) by a random combination of structural switches outside
  the effect vocabulary (``MISMATCH_SWITCHES``), and the start may hold an effect the thruster
  lacks (superfluous);
- outside (``make_outside_case``): the measured t100 sits behind a structure neither the
  simulator nor the vocabulary has, on the command or on a sensor (``Structure``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import lfilter

from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.sim.config import (
    Measurement,
    SimConfig,
    load_config,
    perturb_unit,
    set_effect,
    without_effects,
)
from thruster_fdd_shore.core.sim.effects import make_effect
from thruster_fdd_shore.core.sim.physics import simulate
from thruster_fdd_shore.core.sim.plant import RAD_S_TO_RPM
from thruster_fdd_shore.core.sim.signals import make_signal
from thruster_fdd_shore.core.sim.steady import steady_state

PLAUSIBLE: dict[str, tuple[str, float, float]] = {
    "dead_time": ("delay_s", 0.3, 1.0),
    "deadband": ("width", 0.04, 0.12),
    "esc_lag": ("tau_s", 0.3, 1.0),
    "slew_rate_limit": ("rate_per_s", 0.5, 2.0),
    "coulomb_friction": ("torque_nm", 0.012, 0.025),
    "viscous_friction": ("coeff", 1.2e-4, 2.5e-4),
    "voltage_sag": ("r_internal_ohm", 0.1, 0.3),
    "current_limit": ("i_max_a", 6.0, 9.0),
}
"""Effect -> (parameter, low, high): uniform range of the hidden value for the t100 preset."""


SIGNALS = ("multilevel", "reversals", "lowspeed")
"""Command signals of the cases: ``multilevel`` (``core.sim.signals``: random levels held 2-15 s),
``reversals`` (fast large steps: alternating sign, |level| 0.6-1, held 3-8 s, so the duty is
asked to move by 1.2-2 at once) and ``lowspeed`` (linear ramps of 3-10 s between levels that
alternate between slow, |u| 0.08-0.35, and anywhere in -1..1: many zero crossings and a long
time at low speed, plus the full range)."""


EXCITING: dict[str, str] = {
    "slew_rate_limit": "reversals",
    "coulomb_friction": "lowspeed",
    "viscous_friction": "lowspeed",
    "current_limit": "reversals",
}
"""Effects that the default ``multilevel`` command does not excite, and the signal that does.

With the t100 ESC lag (0.61 s) a duty slew limit only binds on steps of more than
``rate * tau`` (1.2 at 2 /s), rare in ``multilevel``; there the lag absorbs it. Friction torques
are a few % of the propeller load at speed, where a re-fitted ``k_q`` and the other friction term
absorb them; they differ from it at low speed and around zero crossings. A current limit of
6-9 A binds only above |command| 0.75-0.9 (11 A at full command), which a 60 s ``multilevel``
command may never reach."""


@dataclass(frozen=True)
class Case:
    """One synthetic case.

    Attributes
    ----------
    trace : Trace
        The "measured" trace (noisy, one unit of the spread).
    start : SimConfig
        The model's starting configuration (t100 without the hidden effects).
    hidden : dict of str to dict of str to float
        Hidden effect -> its parameters in the simulated unit (after spread).
    signal : str
        The command signal (one of ``SIGNALS``, or ``mixed``).
    clean : Trace
        The same unit's response to the same command without measurement noise, outliers,
        quantisation or reporting floor: what a perfect model would output. Measured against
        it, a model's error has no noise floor (the study's "model error" column).
    superfluous : tuple of str
        Effects the start holds and the measured thruster lacks (mismatch family).
    switches : dict of str to str
        Structural switches of the measured thruster that differ from the start preset, with
        their values (mismatch family; empty for the exact base).
    unit : SimConfig or None
        The simulated unit itself (after spread): the truth a named parameter is checked
        against, with its base (a friction torque is identified only relative to ``k_e``).
    structure : Structure or None
        The structure outside the simulator and the vocabulary between the vehicle and the
        unit (outside family; ``make_outside_case``).
    """

    trace: Trace
    start: SimConfig
    hidden: dict[str, dict[str, float]]
    signal: str
    clean: Trace
    superfluous: tuple[str, ...] = ()
    switches: dict[str, str] = field(default_factory=dict)
    unit: SimConfig | None = None
    structure: Structure | None = None


ABSENT: dict[str, tuple[str, ...]] = {
    "coulomb_friction": ("viscous_friction",),
    "viscous_friction": ("coulomb_friction",),
}
"""Effects removed from both the truth and the model when the key is hidden.

The two friction torques absorb each other: over the measured speeds (above the 300 rpm
reporting floor) a viscous torque ``b w`` is matched within a few % by a re-fitted Coulomb
torque plus a re-fitted ``k_q w**2``, and a Coulomb torque by a viscous one. Measured (120 s):
hidden ``viscous_friction`` 4.9e-5 N m s/rad against t100 with its Coulomb term free, or hidden
``coulomb_friction`` 0.0065 N m against t100 with its viscous term free, leave the calibrated
model at the noise level (held-out score 0.97-1.10): nothing to find. So a friction case hides
one friction term from a model that has none (the t100 preset's other term is 1e-6 N m s/rad or
0.002 N m, removed from the truth too)."""


MIXED = ("steps", "chirp", "multilevel", "reversals", "lowspeed")
"""Segments of the ``mixed`` signal, equal lengths in this order: the paper's 0.25 steps, a
0.01-0.1 Hz chirp, then the three ``SIGNALS``, so every effect is excited in every case."""


def case_signal(
    spec: str, duration_s: float, rate_hz: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Command of a case: one of ``SIGNALS`` or ``mixed`` (times from 0 s, command in -1..1)."""
    if spec == "multilevel":
        return make_signal("multilevel", duration_s, rate_hz, seed=seed)
    if spec == "mixed":
        n = max(len(MIXED), round(duration_s * rate_hz))
        bounds = np.linspace(0, n, len(MIXED) + 1).round().astype(int)
        parts = []
        for k, part in enumerate(MIXED):
            length = int(bounds[k + 1] - bounds[k])
            if part in ("steps", "chirp"):
                parts.append(make_signal(part, length / rate_hz, rate_hz)[1][:length])
            else:
                parts.append(case_signal(part, length / rate_hz, rate_hz, seed + k)[1][:length])
        return np.arange(n) / rate_hz, np.concatenate(parts)
    if spec not in SIGNALS:
        raise ValueError(
            f"unknown case signal {spec!r}; expected one of {', '.join(SIGNALS)}, mixed"
        )
    n = max(1, round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    rng = np.random.default_rng([seed, 0x5161])
    knots_t, knots_u = [0.0], [0.0]
    sign = 1.0 if rng.random() < 0.5 else -1.0
    slow = True
    while knots_t[-1] < duration_s:
        if spec == "reversals":
            level = sign * rng.uniform(0.6, 1.0)
            sign = -sign
            knots_t += [knots_t[-1] + 1.0 / rate_hz, knots_t[-1] + rng.uniform(3.0, 8.0)]
            knots_u += [level, level]
        else:
            if slow:
                level = sign * rng.uniform(0.08, 0.35)
                sign = -sign
            else:
                level = rng.uniform(-1.0, 1.0)
            slow = not slow
            ramp = rng.uniform(3.0, 10.0)
            knots_t += [knots_t[-1] + ramp, knots_t[-1] + ramp + rng.uniform(1.0, 5.0)]
            knots_u += [level, level]
    return t, np.clip(np.interp(t, knots_t, knots_u), -1.0, 1.0)


def make_case(
    hidden: tuple[str, ...],
    seed: int,
    *,
    duration_s: float = 180.0,
    rate_hz: float = 10.0,
    signal: str | None = None,
    absent: tuple[str, ...] | None = None,
) -> Case:
    """Build a case hiding ``hidden`` effects (may be empty: a null case).

    Parameters
    ----------
    hidden : tuple of str
        Effect names to hide (keys of ``PLAUSIBLE``).
    seed : int
        Seed of the hidden values, the unit, the noise and the multilevel command.
    duration_s, rate_hz : float
        Trace length (s) and sample rate (Hz).
    signal : str or None
        One of ``SIGNALS``; None: the one ``EXCITING`` gives the first hidden effect listed
        there, else ``multilevel``.
    absent : tuple of str or None
        Effects removed from both the truth and the model; None: ``ABSENT`` of the hidden
        effects (minus hidden ones).
    """
    if absent is None:
        absent = tuple(
            dict.fromkeys(a for n in hidden for a in ABSENT.get(n, ()) if a not in hidden)
        )
    base = without_effects(load_config("t100"), absent)
    rng = np.random.default_rng([seed, 0xCA5E])
    truth = base
    for name in hidden:
        if name not in PLAUSIBLE:
            raise ValueError(f"unknown effect {name!r}; expected one of {', '.join(PLAUSIBLE)}")
        attr, lo, hi = PLAUSIBLE[name]
        truth = set_effect(truth, make_effect(name, {attr: float(rng.uniform(lo, hi))}))
    if signal is None:
        signal = next((EXCITING[n] for n in hidden if n in EXCITING), "multilevel")
    t, command = case_signal(signal, duration_s, rate_hz, seed)
    trace = simulate(truth, t, command, seed=seed)
    # The unit depends on the seed alone (perturb_unit), not on the measurement model.
    clean = simulate(replace(truth, measurement=Measurement()), t, command, seed=seed)
    unit = perturb_unit(truth, seed)
    start = without_effects(base, hidden)
    values = {}
    for name in hidden:
        effect = unit.effect(name)
        if effect is None:
            raise ValueError(f"hidden effect {name!r} missing from the simulated unit")
        values[name] = effect.params()
    return Case(trace=trace, start=start, hidden=values, signal=signal, clean=clean, unit=unit)


MISMATCH_SWITCHES = (
    "asymmetric_load",
    "drive_saturation",
    "winding_loss",
    "idle_law",
    "second_order_esc",
    "base_out_of_bounds",
    "coarse_rpm_sensor",
    "no_regen",
)
"""Structural differences of a mismatch case's thruster from its start preset, each drawn on
with probability 1/2 (``draw_mismatch``): propeller load asymmetric between forward and reverse
(``k_q_reverse_ratio`` x 0.7-0.85 or 1.15-1.35); ESC drive saturation toggled (``esc_v_sat_v``
45-120 V where the preset has none, none where it has one); a speed-dependent winding loss
(``r_speed_ohm_s`` giving +20-60 % of ``r_ohm`` at 400 rad/s where the preset has none, else
its value x 0.6-0.8 or 1.25-1.6: switching it off would double the t200's current); idle current
growing with speed (0.03-0.15 A per 1000 rpm); a second ESC stage (0.05-0.2 s); one of
``r_ohm``, ``k_q``, ``inertia`` outside the calibration's factor-2 bounds (x or / 2.2-3); an rpm
sensor with a reporting floor of 350-700 rpm and 20-100 rpm quantisation; coasting instead of
regenerative braking."""


MISMATCH_HIDDEN = tuple(n for n in PLAUSIBLE if n != "esc_lag")
"""Effects a mismatch case may hide: the start keeps ``esc_lag`` (a
``--start t100`` with every effect but ``esc_lag`` dropped)."""


MISMATCH_PAIRS = (
    ("dead_time", "current_limit"),
    ("deadband", "voltage_sag"),
    ("coulomb_friction", "slew_rate_limit"),
)
"""Hidden pairs of the mismatch study."""


SUPERFLUOUS = ("dead_time", "deadband")
"""Effects a mismatch case's start may hold although the thruster lacks them."""


SUPERFLUOUS_VALUES: dict[str, tuple[str, float]] = {
    "dead_time": ("delay_s", 0.55),
    "deadband": ("width", 0.0625),
}
"""Value a superfluous effect has in the start when its preset lacks it (the t100 values)."""


MISMATCH_DURATION_S = 600.0
"""Default length of a mismatch case, s (600 s at 10 Hz)."""


def _full_command(config: SimConfig) -> tuple[float, float, float]:
    """Steady full-command speed (rad/s), propeller torque (N m) and bus current (A) at 15 V."""
    rpm, current = steady_state(replace(config, spread=0.0), np.array([1.0]), 15.0)
    w = float(rpm[0]) / RAD_S_TO_RPM
    return w, config.params.k_q * w * w, float(current[0])


def peak_duty_rate(config: SimConfig) -> float:
    """Peak rate of the duty's response to a unit step of the command through the ESC of
    ``config`` (its ``esc_lag``, then the second stage ``structure.esc_tau2_s`` if any), 1/s;
    inf without an ``esc_lag``."""
    lag = config.effect("esc_lag")
    if lag is None:
        return math.inf
    t1, t2 = lag.tau_s, config.structure.esc_tau2_s
    if t2 <= 0.0:
        return 1.0 / t1
    if math.isclose(t1, t2):
        return 1.0 / (math.e * t1)
    peak = math.log(t1 / t2) * t1 * t2 / (t1 - t2)  # the impulse response's maximum, s
    return (math.exp(-peak / t1) - math.exp(-peak / t2)) / (t1 - t2)


def plausible_ranges(config: SimConfig) -> dict[str, tuple[str, float, float]]:
    """``PLAUSIBLE`` (t100 ranges) scaled to the thruster of ``config``.

    Friction torques scale with the full-command propeller torque (viscous also with the
    inverse speed), the supply resistance with the inverse and the current limit with the
    full-command current (all at 15 V); the slew rate with the peak duty rate of the ESC
    (``peak_duty_rate``) against that of its first stage alone, so that a second ESC stage,
    which slows the duty, does not leave a drawn limit above any rate the duty reaches (on
    t100 with a 0.13 s second stage a limit of 1.9 per s changed the noise-free response by
    0.01 noise variances); times and widths stay.
    """
    w0, torque0, current0 = _full_command(load_config("t100"))
    w1, torque1, current1 = _full_command(config)
    scale = {
        "coulomb_friction": torque1 / torque0,
        "viscous_friction": (torque1 / w1) / (torque0 / w0),
        "voltage_sag": current0 / current1,
        "current_limit": current1 / current0,
    }
    lag = config.effect("esc_lag")
    if lag is not None:  # the lag alone peaks at 1 / tau_s
        scale["slew_rate_limit"] = peak_duty_rate(config) * lag.tau_s
    return {
        name: (attr, lo * scale.get(name, 1.0), hi * scale.get(name, 1.0))
        for name, (attr, lo, hi) in PLAUSIBLE.items()
    }


def draw_mismatch(base: SimConfig, rng: np.random.Generator) -> tuple[SimConfig, dict[str, str]]:
    """Apply a random combination of ``MISMATCH_SWITCHES`` to ``base``.

    Returns
    -------
    (SimConfig, dict of str to str)
        The changed configuration and, per switch drawn on, a description of its value.
    """
    p, m = base.params, base.measurement
    params: dict[str, float] = {}
    structure: dict[str, float | bool] = {}
    measurement: dict[str, float] = {}
    on: dict[str, str] = {}
    for switch in MISMATCH_SWITCHES:
        draw_on = rng.random() < 0.5
        u1, u2, u3 = rng.random(3)  # drawn always, so one switch does not shift the others
        if not draw_on:
            continue
        if switch == "asymmetric_load":
            factor = 0.7 + 0.15 * u2 if u1 < 0.5 else 1.15 + 0.2 * u2
            params["k_q_reverse_ratio"] = p.k_q_reverse_ratio * factor
            on[switch] = f"k_q_reverse_ratio x {factor:.3f}"
        elif switch == "drive_saturation":
            value = float("inf") if np.isfinite(p.esc_v_sat_v) else 45.0 + 75.0 * u1
            params["esc_v_sat_v"] = value
            on[switch] = f"esc_v_sat_v {value:.1f} V"
        elif switch == "winding_loss":
            if p.r_speed_ohm_s > 0.0:
                value = p.r_speed_ohm_s * (0.6 + 0.2 * u2 if u1 < 0.5 else 1.25 + 0.35 * u2)
            else:
                value = (0.2 + 0.4 * u1) * p.r_ohm / 400.0
            params["r_speed_ohm_s"] = value
            on[switch] = f"r_speed_ohm_s {value:.3g} ohm s/rad"
        elif switch == "idle_law":
            structure["i_idle_per_krpm_a"] = 0.03 + 0.12 * u1
            on[switch] = f"i_idle_per_krpm_a {structure['i_idle_per_krpm_a']:.3f} A"
        elif switch == "second_order_esc":
            structure["esc_tau2_s"] = 0.05 + 0.15 * u1
            on[switch] = f"esc_tau2_s {structure['esc_tau2_s']:.3f} s"
        elif switch == "base_out_of_bounds":
            name = ("r_ohm", "k_q", "inertia")[min(int(u1 * 3), 2)]
            factor = (2.2 + 0.8 * u2) ** (1.0 if u3 < 0.5 else -1.0)
            params[name] = getattr(p, name) * factor
            on[switch] = f"{name} x {factor:.3f}"
        elif switch == "coarse_rpm_sensor":
            measurement["rpm_floor"] = 350.0 + 350.0 * u1
            measurement["rpm_step"] = 20.0 + 80.0 * u2
            on[switch] = (
                f"rpm floor {measurement['rpm_floor']:.0f}, step {measurement['rpm_step']:.0f}"
            )
        elif switch == "no_regen":
            structure["regen"] = False
            on[switch] = "coasts instead of regenerating"
    config = replace(
        base,
        params=replace(p, **params),
        structure=replace(base.structure, **structure),
        measurement=replace(m, **measurement),
    )
    return config, on


def make_mismatch_case(
    hidden: tuple[str, ...],
    seed: int,
    *,
    preset: str = "t100",
    superfluous: tuple[str, ...] = (),
    duration_s: float = MISMATCH_DURATION_S,
    rate_hz: float = 10.0,
) -> Case:
    """Build a mismatch case: base physics differ from the start preset, effects hidden.

    The measured thruster is ``preset`` with ``esc_lag`` as its only effect besides the hidden
    ones (values from ``plausible_ranges`` of the changed thruster), changed by
    ``draw_mismatch`` and drawn with the preset's unit spread and noise; the
    start is ``preset`` with ``esc_lag`` only, plus the ``superfluous`` effects (at the
    preset's value, else ``SUPERFLUOUS_VALUES``). Driven by the ``mixed`` signal.

    Parameters
    ----------
    hidden : tuple of str
        Effects hidden from the start (``MISMATCH_HIDDEN``); may be empty (a null case).
    seed : int
        Seed of the switches, the hidden values, the unit, the noise and the command.
    preset : str
        ``t100`` or ``t200``.
    superfluous : tuple of str
        Effects of ``SUPERFLUOUS`` the start holds and the thruster lacks.
    duration_s, rate_hz : float
        Trace length (s) and sample rate (Hz).
    """
    unknown = [n for n in hidden if n not in MISMATCH_HIDDEN]
    unknown += [n for n in superfluous if n not in SUPERFLUOUS or n in hidden]
    if unknown:
        raise ValueError(f"effect(s) {unknown} cannot be hidden or superfluous here")
    source = load_config(preset)
    lag = source.effect("esc_lag")
    if lag is None:
        raise ValueError(f"preset {preset!r} has no esc_lag")
    base = replace(source, effects=(lag,))
    rng = np.random.default_rng([seed, 0x3157])
    truth, switches = draw_mismatch(base, rng)
    # Scaled to the measured thruster itself, so a current limit binds and a friction torque
    # weighs the same share of its load whatever the switches did to its current and speed.
    ranges = plausible_ranges(truth)
    for name in hidden:
        attr, lo, hi = ranges[name]
        truth = set_effect(truth, make_effect(name, {attr: float(rng.uniform(lo, hi))}))
    start = base
    for name in superfluous:
        attr, value = SUPERFLUOUS_VALUES[name]
        effect = source.effect(name) or make_effect(name, {attr: value})
        start = set_effect(start, effect)
    t, command = case_signal("mixed", duration_s, rate_hz, seed)
    trace = simulate(truth, t, command, seed=seed)
    clean = simulate(replace(truth, measurement=Measurement()), t, command, seed=seed)
    unit = perturb_unit(truth, seed)
    values = {name: unit.effect(name).params() for name in hidden}
    return Case(
        trace=trace,
        start=start,
        hidden=values,
        signal="mixed",
        clean=clean,
        superfluous=tuple(superfluous),
        switches=switches,
        unit=unit,
    )


OUTSIDE_RANGES: dict[str, tuple[str, float, float]] = {
    "throttle_curve": ("a", 0.15, 0.4),
    "rpm_filter": ("tau", 0.2, 0.6),
    "command_hysteresis": ("width", 0.04, 0.12),
    "reverse_limit": ("reverse max", 0.55, 0.8),
    "command_steps": ("step", 0.04, 0.08),
    "rpm_delay": ("delay", 0.2, 0.5),
    "current_filter": ("tau", 0.2, 0.6),
}
"""Structure -> (its parameter, low, high): the uniform range ``make_outside_case`` draws from
(``a`` and ``width``, ``reverse max`` and ``step`` in command units; ``tau`` and ``delay`` in s)."""


OUTSIDE = tuple(OUTSIDE_RANGES)
"""Structures neither the simulator nor the vocabulary has (``make_outside_case``)."""


def play(u: np.ndarray, width: float) -> np.ndarray:
    """The play (backlash) operator: the output follows ``u`` only once ``u`` has moved
    ``width / 2`` beyond it, shape of ``u``; it starts at ``u[0]``."""
    out = np.empty_like(u)
    y, half = float(u[0]), width / 2.0
    for k, x in enumerate(u):
        y = min(max(y, x - half), x + half)
        out[k] = y
    return out


@dataclass(frozen=True)
class Structure:
    """A structure outside the simulator and the vocabulary, between the vehicle and the
    thruster (``OUTSIDE_RANGES``): the ESC receives ``received(u)`` for the command ``u`` the
    vehicle sent, or a sensor reports a channel through a filter or a delay (``sensed``).

    ``throttle_curve``: ``u + a u (1 - |u|)``; ``command_hysteresis``: a play of ``width``
    (``play``); ``reverse_limit``: reverse commands capped at ``-reverse max`` (a firmware
    limit on reverse power); ``command_steps``: the command resolved in steps of ``step`` (a
    coarse command protocol); ``rpm_filter`` / ``current_filter``: the channel reported through
    a first-order filter of time constant ``tau``; ``rpm_delay``: the speed reported ``delay``
    late (rounded to whole samples).
    """

    kind: str
    value: float

    def received(self, u: np.ndarray) -> np.ndarray:
        """The command the ESC acts on, shape of ``u``."""
        v = self.value
        if self.kind == "throttle_curve":
            return np.clip(u + v * u * (1.0 - np.abs(u)), -1.0, 1.0)
        if self.kind == "command_hysteresis":
            return play(u, v)
        if self.kind == "reverse_limit":
            return np.maximum(u, -v)
        if self.kind == "command_steps":
            return np.clip(np.round(u / v) * v, -1.0, 1.0)
        return u

    @property
    def channel(self) -> str | None:
        """The channel a sensor structure reports (None: a command structure)."""
        return {"rpm_filter": "rpm", "rpm_delay": "rpm", "current_filter": "current"}.get(self.kind)

    def sensed(self, trace: Trace, measurement: Measurement | None = None) -> Trace:
        """``trace`` as the structure's sensor reports it, on the grid of ``measurement``'s
        step for that channel (the sensor digitises after its filter; None: no grid)."""
        if self.channel is None:
            return trace
        x = getattr(trace, self.channel)
        dt = float(np.median(np.diff(trace.t)))
        if self.kind == "rpm_delay":
            k = max(1, round(self.value / dt))
            y = np.concatenate([np.full(k, x[0]), x[:-k]])
        else:
            alpha = 1.0 - math.exp(-dt / self.value)
            y = lfilter([alpha], [1.0, alpha - 1.0], x)
        if measurement is not None:
            step = measurement.rpm_step if self.channel == "rpm" else measurement.current_step_a
            y = np.round(y / step) * step if step > 0.0 else y
        return replace(trace, **{self.channel: y})

    def respond(self, config: SimConfig, t: np.ndarray, u: np.ndarray, seed: int = 0) -> Trace:
        """``config`` simulated behind the structure for the sent command ``u`` (recorded as
        the trace's command), its sensor on ``config.measurement``'s grid."""
        trace = replace(simulate(config, t, self.received(u), seed=seed), command=u)
        return self.sensed(trace, config.measurement)

    def describe(self) -> str:
        """``parameter value`` as the study's switches record it."""
        unit = "" if self.channel is None else " s"
        return f"{OUTSIDE_RANGES[self.kind][0]} {self.value:.3f}{unit}"


def make_outside_case(kind: str, hidden: tuple[str, ...], seed: int, duration_s: float = 240.0):
    """A t100 case (``make_case``, ``multilevel``) whose thruster has a structure outside the
    simulator and the vocabulary (``Structure``, its parameter uniform in ``OUTSIDE_RANGES``;
    the trace records the command the vehicle sent). A command structure's unit is simulated
    behind it; a sensor structure reports ``make_case``'s traces through it. The case's
    ``structure`` holds it."""
    if kind not in OUTSIDE:
        raise ValueError(f"unknown structure {kind!r}; expected one of {OUTSIDE}")
    case = make_case(hidden, seed, duration_s=duration_s, signal="multilevel")
    rng = np.random.default_rng([seed, 0x0575])
    structure = Structure(kind, float(rng.uniform(*OUTSIDE_RANGES[kind][1:])))
    t, u = case.trace.t, case.trace.command
    if structure.channel is None:
        truth = replace(case.unit, spread=0.0, measurement=load_config("t100").measurement)
        trace = structure.respond(truth, t, u, seed=seed)
        clean = structure.respond(replace(truth, measurement=Measurement()), t, u)
    else:
        trace = structure.sensed(case.trace, case.unit.measurement)
        clean = structure.sensed(case.clean)
    switches = {kind: structure.describe()}
    return replace(case, trace=trace, clean=clean, switches=switches, structure=structure)
