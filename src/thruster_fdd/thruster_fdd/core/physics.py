"""ROS-free thruster physics simulator (DESIGN.md "Reference thruster physics").

Signal path, in order: dead time -> deadband -> ESC duty (lag, slew limit) -> quasi-static motor
current -> rotor -> bus current (current limit) -> bus voltage (sag) -> thrust; then the
measurement model. ``ThrusterSimulator`` is the only stateful object; ``simulate`` runs it over a
command history and returns a ``Trace``; ``steady_state`` solves the noise-free static curves.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from thruster_fdd.core.data import CLASS_NAMES, Trace
from thruster_fdd.core.effects import (
    EFFECTS,
    CoulombFriction,
    CurrentLimit,
    Deadband,
    DeadTime,
    Effect,
    EscLag,
    SlewRateLimit,
    ViscousFriction,
    VoltageSag,
    make_effect,
)
from thruster_fdd.core.simconfig import (
    Measurement,
    SimConfig,
    ThrusterParams,
    add_effect,
    dump_config,
    load_config,
    perturb_unit,
    preset_names,
    remove_effect,
    replace_effect,
    set_effect,
)

__all__ = [
    "CONDITIONS",
    "EFFECTS",
    "MAX_SUBSTEP_S",
    "RAD_S_TO_RPM",
    "ConditionSpec",
    "CoulombFriction",
    "CurrentLimit",
    "DeadTime",
    "Deadband",
    "Effect",
    "EscLag",
    "Measurement",
    "Sample",
    "SimConfig",
    "SlewRateLimit",
    "StepMetrics",
    "ThrusterParams",
    "ThrusterSimulator",
    "ViscousFriction",
    "VoltageSag",
    "add_effect",
    "dump_config",
    "hysteresis_loop_area",
    "load_config",
    "make_effect",
    "perturb_unit",
    "preset_names",
    "remove_effect",
    "replace_effect",
    "set_effect",
    "simulate",
    "steady_state",
    "step_metrics",
]

MAX_SUBSTEP_S = 0.01
"""Longest internal integration substep, s (the rotor update is linearly implicit, so stable)."""

RAD_S_TO_RPM = 60.0 / (2.0 * math.pi)
_OMEGA_REF = 400.0  # rad/s; scale of the extra fouling friction, near full speed


@dataclass(frozen=True)
class ConditionSpec:
    """How a condition changes the healthy unit.

    Attributes
    ----------
    supply_v : float
        Default supply voltage, V.
    k_q_factor : float
        Multiplier of the propeller torque coefficient (load).
    k_thrust_factor : float
        Multiplier of the thrust coefficient.
    friction_frac : float
        Extra friction: Coulomb ``friction_frac * k_q * 400**2`` N m and viscous
        ``friction_frac * k_q * 400`` N m s/rad (fouled shaft and nozzle).
    ripple : float
        Once-per-revolution load torque ripple, as a fraction of the propeller torque.
    """

    supply_v: float
    k_q_factor: float = 1.0
    k_thrust_factor: float = 1.0
    friction_frac: float = 0.0
    ripple: float = 0.0


CONDITIONS: dict[str, ConditionSpec] = {
    "nominal_15v": ConditionSpec(15.0),
    "nominal_13v": ConditionSpec(13.0),
    "nominal_11v8": ConditionSpec(11.8),
    # Losing blades removes load (faster, less current) and unbalances the rotor (ripple).
    "broken_blade_1": ConditionSpec(15.0, k_q_factor=0.72, k_thrust_factor=0.65, ripple=0.12),
    "broken_blade_2": ConditionSpec(15.0, k_q_factor=0.45, k_thrust_factor=0.35, ripple=0.3),
    # Growth adds drag and friction (slower, more current) and spoils the blade profile.
    "biofouling": ConditionSpec(15.0, k_q_factor=1.35, k_thrust_factor=0.8, friction_frac=0.03),
}
"""Condition name (DESIGN.md class names) -> its effect on the unit."""

if set(CONDITIONS) != set(CLASS_NAMES):
    raise RuntimeError("CONDITIONS must cover exactly core.data.CLASS_NAMES")


@dataclass(frozen=True)
class Sample:
    """One measured telemetry sample.

    Attributes
    ----------
    t : float
        Simulator time, s.
    command : float
        Applied command (-1..1, after clamping).
    voltage : float
        Measured bus voltage, V.
    rpm : float
        Measured shaft speed, rpm, signed.
    current : float
        Measured bus current, A.
    temperature : float
        Winding/ESC temperature, C.
    thrust : float
        Thrust, N (not measured: noise-free).
    """

    t: float
    command: float
    voltage: float
    rpm: float
    current: float
    temperature: float
    thrust: float


def _check_condition(condition: str) -> ConditionSpec:
    if condition not in CONDITIONS:
        raise ValueError(
            f"unknown condition {condition!r}; expected one of {', '.join(CONDITIONS)}"
        )
    return CONDITIONS[condition]


def _check_voltage(voltage: float | None) -> None:
    if voltage is not None and not (math.isfinite(voltage) and 0.0 < voltage <= 60.0):
        raise ValueError(f"supply voltage must be in (0, 60] V, got {voltage}")


@dataclass(frozen=True)
class _Plant:
    """Flattened numbers of one unit in one condition (fast access in the integration loop)."""

    k_e: float
    r_ohm: float
    r_speed: float
    v_sat: float
    inertia: float
    k_q: float
    k_q_rev: float
    k_thrust: float
    k_thrust_rev: float
    i_idle: float
    coulomb: float
    viscous: float
    ripple: float
    delay: float
    width: float
    tau: float
    slew: float
    r_int: float
    i_max: float
    v_supply: float


def _plant(unit: SimConfig, spec: ConditionSpec, voltage: float | None) -> _Plant:
    p = unit.params
    eff = {e.name: e for e in unit.effects}
    k_q = p.k_q * spec.k_q_factor
    k_t = p.k_thrust * spec.k_thrust_factor

    def get(name: str, attr: str, default: float) -> float:
        return float(getattr(eff[name], attr)) if name in eff else default

    return _Plant(
        k_e=p.k_e,
        r_ohm=p.r_ohm,
        r_speed=p.r_speed_ohm_s,
        v_sat=p.esc_v_sat_v,
        inertia=p.inertia,
        k_q=k_q,
        k_q_rev=k_q * p.k_q_reverse_ratio,
        k_thrust=k_t,
        k_thrust_rev=k_t * p.reverse_thrust_ratio,
        i_idle=p.i_idle_a,
        coulomb=get("coulomb_friction", "torque_nm", 0.0)
        + spec.friction_frac * k_q * _OMEGA_REF**2,
        viscous=get("viscous_friction", "coeff", 0.0) + spec.friction_frac * k_q * _OMEGA_REF,
        ripple=spec.ripple,
        delay=get("dead_time", "delay_s", 0.0),
        width=get("deadband", "width", 0.0),
        tau=get("esc_lag", "tau_s", 0.0),
        slew=get("slew_rate_limit", "rate_per_s", math.inf),
        r_int=get("voltage_sag", "r_internal_ohm", 0.0),
        i_max=get("current_limit", "i_max_a", math.inf),
        v_supply=spec.supply_v if voltage is None else float(voltage),
    )


def _limited_duty(pl: _Plant, d: float, ve: float, w: float, reff: float) -> float:
    """Duty of the same sign as ``d`` at which the bus current equals ``pl.i_max``."""
    disc = (pl.k_e * w) ** 2 + 4.0 * ve * reff * (pl.i_max - pl.i_idle)
    root = math.sqrt(max(disc, 0.0))
    return (pl.k_e * w + math.copysign(root, d)) / (2.0 * ve)


class ThrusterSimulator:
    """One simulated thruster: the only stateful object of the simulator.

    Parameters
    ----------
    config : SimConfig
        Configuration of the nominal unit; with ``config.spread > 0`` the unit is drawn by seed.
    condition : str
        One of ``CONDITIONS`` (DESIGN.md class names).
    voltage : float or None
        Supply voltage in V; None uses the condition's (15.0 / 13.0 / 11.8 V; faults 15.0 V).
    seed : int
        Seed of the unit draw and of the measurement noise; equal seeds give equal runs.
    """

    def __init__(
        self,
        config: SimConfig,
        condition: str = "nominal_15v",
        *,
        voltage: float | None = None,
        seed: int = 0,
    ) -> None:
        if not isinstance(config, SimConfig):
            raise ValueError(f"config must be a SimConfig, got {type(config).__name__}")
        _check_condition(condition)
        _check_voltage(voltage)
        self.config = config
        self.seed = int(seed)
        self.unit = perturb_unit(config, self.seed)
        self._voltage = voltage
        self._condition = condition
        self._plant = _plant(self.unit, CONDITIONS[condition], voltage)
        self.reset()

    @property
    def condition(self) -> str:
        """The current condition name."""
        return self._condition

    @property
    def t(self) -> float:
        """Simulator time, s."""
        return self._t

    def set_condition(self, condition: str) -> None:
        """Switch condition mid-run (fault injection); the dynamic state is kept.

        The supply voltage follows the new condition unless one was given at construction.
        """
        self._plant = _plant(self.unit, _check_condition(condition), self._voltage)
        self._condition = condition

    def set_voltage(self, voltage: float | None) -> None:
        """Set the supply voltage in V (None: the condition's); the dynamic state is kept."""
        _check_voltage(voltage)
        self._voltage = voltage
        self._plant = _plant(self.unit, CONDITIONS[self._condition], voltage)

    def reset(self) -> None:
        """Return to rest at t = 0 and re-seed the measurement noise (condition is kept)."""
        pl = self._plant
        self._t = 0.0
        self._w = 0.0
        self._d = 0.0
        self._theta = 0.0
        self._vbus = pl.v_supply
        self._temp = self.unit.params.water_temp_c
        self._history: list[tuple[float, float]] = [(-math.inf, 0.0)]
        self._rng = np.random.default_rng([self.seed, 0xD1CE])
        self._buf_n: list[list[float]] = []
        self._buf_u: list[list[float]] = []
        self._buf_i = 0

    def step(self, command: float, dt: float) -> Sample:
        """Advance ``dt`` seconds with ``command`` held; return the measured sample at the end.

        Parameters
        ----------
        command : float
            Normalised command; clamped to [-1, 1].
        dt : float
            Duration in s, >= 0 (0 only measures).
        """
        return Sample(*self._advance(command, dt))

    def _advance(
        self, command: float, dt: float
    ) -> tuple[float, float, float, float, float, float, float]:
        if not math.isfinite(command):
            raise ValueError(f"command must be finite, got {command}")
        if not (math.isfinite(dt) and dt >= 0.0):
            raise ValueError(f"dt must be a finite duration >= 0 s, got {dt}")
        u = min(1.0, max(-1.0, float(command)))
        for value, length in self._delayed_segments(u, dt):
            self._integrate(value, length)
        self._t += dt
        return self._measure(u, dt)

    def _delayed_segments(self, u: float, dt: float) -> Iterator[tuple[float, float]]:
        """Yield (delayed command, duration) pieces covering [t, t + dt]."""
        delay = self._plant.delay
        if delay == 0.0:
            yield u, dt
            return
        t0, t1 = self._t, self._t + dt
        hist = self._history
        if hist[-1][1] != u:
            hist.append((t0, u))
        while len(hist) > 1 and hist[1][0] + delay <= t0:
            hist.pop(0)
        s = t0
        for i, (_, value) in enumerate(hist):
            end = hist[i + 1][0] + delay if i + 1 < len(hist) else math.inf
            seg_end = min(end, t1)
            if seg_end > s:
                yield value, seg_end - s
                s = seg_end
            if s >= t1:
                return

    def _integrate(self, u: float, duration: float) -> None:
        """Integrate the ESC, motor and rotor over ``duration`` s with delayed command ``u``."""
        if duration <= 0.0:
            return
        pl = self._plant
        mag = abs(u)
        target = 0.0 if mag <= pl.width else math.copysign((mag - pl.width) / (1.0 - pl.width), u)
        n = max(1, math.ceil(duration / MAX_SUBSTEP_S - 1e-9))
        h = duration / n
        alpha = 1.0 - math.exp(-h / pl.tau) if pl.tau > 0.0 else 1.0
        max_dd = pl.slew * h
        k_e, r0, rs, vsat, vs = pl.k_e, pl.r_ohm, pl.r_speed, pl.v_sat, pl.v_supply
        j_h = pl.inertia / h
        i_idle, i_max, r_int = pl.i_idle, pl.i_max, pl.r_int
        tc, b = pl.coulomb, pl.viscous
        w, d, vb, theta = self._w, self._d, self._vbus, self._theta
        for _ in range(n):
            dd = (target - d) * alpha
            d += max(-max_dd, min(max_dd, dd))
            ve = vb / (1.0 + vb / vsat)
            reff = r0 + rs * abs(w)
            de = d
            ibus = d * (d * ve - k_e * w) / reff + i_idle
            if ibus > i_max:
                de = _limited_duty(pl, d, ve, w, reff)
                ibus = i_max
            vb = vs - r_int * ibus
            aw = abs(w)
            kq = pl.k_q if w >= 0.0 else pl.k_q_rev
            a = j_h + k_e * k_e / reff + 2.0 * kq * aw + b
            rhs = j_h * w + k_e * de * ve / reff + kq * w * aw
            w_new = 0.0 if abs(rhs) <= tc else (rhs - math.copysign(tc, rhs)) / a
            theta += 0.5 * h * (w + w_new)
            w = w_new
        self._w, self._d, self._vbus = w, d, vb
        self._theta = math.fmod(theta, 2.0 * math.pi)

    def _noise(self) -> tuple[list[float], list[float]]:
        if self._buf_i >= len(self._buf_n):
            self._buf_n = self._rng.standard_normal((512, 3)).tolist()
            self._buf_u = self._rng.random((512, 3)).tolist()
            self._buf_i = 0
        i = self._buf_i
        self._buf_i += 1
        return self._buf_n[i], self._buf_u[i]

    def _measure(
        self, u: float, dt: float
    ) -> tuple[float, float, float, float, float, float, float]:
        pl = self._plant
        w, d = self._w, self._d
        ve = self._vbus / (1.0 + self._vbus / pl.v_sat)
        reff = pl.r_ohm + pl.r_speed * abs(w)
        de = d
        ibus = d * (d * ve - pl.k_e * w) / reff + pl.i_idle
        if ibus > pl.i_max:
            de = _limited_duty(pl, d, ve, w, reff)
            ibus = pl.i_max
        vbus = pl.v_supply - pl.r_int * ibus
        self._vbus = vbus
        i_m = (de * ve - pl.k_e * w) / reff
        kq = pl.k_q if w >= 0.0 else pl.k_q_rev
        rpm = w * RAD_S_TO_RPM
        if pl.ripple > 0.0:
            # Once-per-revolution load ripple: reflected into the bus current through the duty,
            # and a speed ripple of amplitude torque / (J * w) (an inertia driven at w rad/s).
            torque = pl.ripple * kq * w * w
            ibus += abs(de) * torque / pl.k_e * math.sin(self._theta)
            rpm -= torque / (pl.inertia * max(abs(w), 1.0)) * math.cos(self._theta) * RAD_S_TO_RPM
        p = self.unit.params
        if dt > 0.0:
            t_ss = p.water_temp_c + p.thermal_resistance_c_per_w * i_m * i_m * reff
            self._temp += (t_ss - self._temp) * (1.0 - math.exp(-dt / p.thermal_tau_s))
        thrust = (pl.k_thrust if w >= 0.0 else pl.k_thrust_rev) * w * abs(w)
        m = self.unit.measurement
        z, r = self._noise()
        rpm = _measured(rpm, z[0], r[0], m.rpm_noise, m.rpm_step, m.outlier_prob, m.outlier_rpm)
        cur = _measured(
            ibus,
            z[1],
            r[1],
            m.current_noise_a,
            m.current_step_a,
            m.outlier_prob,
            m.outlier_current_a,
        )
        volt = _measured(
            vbus,
            z[2],
            r[2],
            m.voltage_noise_v,
            m.voltage_step_v,
            m.outlier_prob,
            m.outlier_voltage_v,
        )
        if abs(rpm) < m.rpm_floor:
            rpm = 0.0
            if m.floor_zeroes_current:
                cur = 0.0
        return (self._t, u, volt, rpm, cur, self._temp, thrust)


def _measured(
    x: float, z: float, r: float, std: float, step: float, prob: float, size: float
) -> float:
    x += std * z
    if r < prob:
        # r is uniform on [0, prob) here, so its half decides the spike's sign.
        x += size if r < 0.5 * prob else -size
    if step > 0.0:
        x = round(x / step) * step
    return x


def simulate(
    config: SimConfig,
    t: np.ndarray,
    command: np.ndarray,
    condition: str = "nominal_15v",
    *,
    voltage: float | None = None,
    seed: int = 0,
) -> Trace:
    """Simulate one thruster over a command history.

    ``command[i]`` is held over ``(t[i-1], t[i]]`` and row ``i`` reports the measurement at
    ``t[i]``; row 0 is the state at rest at ``t[0]``. This is exactly what
    ``ThrusterSimulator.step(command[i], t[i] - t[i-1])`` returns (``dt = 0`` for row 0), so
    streaming and batch runs agree.

    Parameters
    ----------
    config : SimConfig
        Simulator configuration.
    t : np.ndarray, shape (n,)
        Sample times, s, strictly increasing.
    command : np.ndarray, shape (n,)
        Normalised commands; clamped to [-1, 1].
    condition : str
        Condition name (DESIGN.md classes).
    voltage : float or None
        Supply voltage, V; None uses the condition's.
    seed : int
        Unit and noise seed.

    Returns
    -------
    Trace
        Columns t, command (applied), voltage (V), rpm, current (A); ``extra`` holds
        ``temperature`` (C) and ``thrust`` (N), all shape (n,); ``condition`` is set.
    """
    t = np.asarray(t, dtype=float)
    command = np.asarray(command, dtype=float)
    if t.ndim != 1 or command.shape != t.shape or len(t) == 0:
        raise ValueError(
            f"t and command must be 1-D of equal non-zero length: {t.shape}, {command.shape}"
        )
    if not np.all(np.isfinite(t)) or not np.all(np.isfinite(command)):
        raise ValueError("t and command must be finite")
    if len(t) > 1 and not np.all(np.diff(t) > 0):
        raise ValueError("t must be strictly increasing")
    sim = ThrusterSimulator(config, condition, voltage=voltage, seed=seed)
    dts = np.diff(t, prepend=t[0]).tolist()
    rows = [sim._advance(c, dt) for c, dt in zip(command.tolist(), dts, strict=False)]
    out = np.array(rows, dtype=float).reshape(len(t), 7)
    return Trace(
        t=t.copy(),
        command=out[:, 1].copy(),
        voltage=out[:, 2].copy(),
        rpm=out[:, 3].copy(),
        current=out[:, 4].copy(),
        condition=condition,
        extra={"temperature": out[:, 5].copy(), "thrust": out[:, 6].copy()},
    )


def _static(
    pl: _Plant, d: np.ndarray, kq: np.ndarray, vb: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steady |w| (rad/s), duty magnitude after the current limit, bus current (A).

    Shapes (n,); ``d`` is the duty magnitude, ``kq`` the torque coefficient per point.
    """
    ve = vb / (1.0 + vb / pl.v_sat)

    def speed(duty: np.ndarray) -> np.ndarray:
        lo = np.zeros_like(duty)
        hi = duty * ve / pl.k_e
        moving = pl.k_e * duty * ve / pl.r_ohm > pl.coulomb
        for _ in range(60):
            w = 0.5 * (lo + hi)
            reff = pl.r_ohm + pl.r_speed * w
            f = pl.k_e * (duty * ve - pl.k_e * w) / reff - kq * w * w - pl.viscous * w - pl.coulomb
            up = f > 0.0
            lo = np.where(up, w, lo)
            hi = np.where(up, hi, w)
        return np.where(moving, 0.5 * (lo + hi), 0.0)

    def bus(duty: np.ndarray, w: np.ndarray) -> np.ndarray:
        return duty * (duty * ve - pl.k_e * w) / (pl.r_ohm + pl.r_speed * w) + pl.i_idle

    w = speed(d)
    ibus = bus(d, w)
    over = ibus > pl.i_max
    if np.any(over):
        lo = np.zeros_like(d)
        hi = d.copy()
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            high = bus(mid, speed(mid)) > pl.i_max
            lo = np.where(high, lo, mid)
            hi = np.where(high, mid, hi)
        d = np.where(over, lo, d)
        w = speed(d)
        ibus = np.where(over, pl.i_max, bus(d, w))
    return w, d, ibus


def steady_state(
    config: SimConfig,
    command: np.ndarray,
    voltage: float,
    *,
    condition: str = "nominal_15v",
    reported: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free steady speed and bus current of the nominal unit (spread is not applied).

    Parameters
    ----------
    config : SimConfig
        Simulator configuration.
    command : np.ndarray, shape (n,)
        Normalised commands held until steady; clamped to [-1, 1].
    voltage : float
        Supply voltage, V.
    condition : str
        Condition name; its voltage is overridden by ``voltage``.
    reported : bool
        Apply the measurement's reporting floor (``rpm_floor``, ``floor_zeroes_current``), as
        the telemetry would show it; noise, quantisation and outliers are never applied.

    Returns
    -------
    rpm : np.ndarray, shape (n,)
        Signed steady speed, rpm.
    current : np.ndarray, shape (n,)
        Steady bus current, A.
    """
    _check_voltage(voltage)
    pl = _plant(config, _check_condition(condition), voltage)
    u = np.clip(np.asarray(command, dtype=float), -1.0, 1.0)
    if u.ndim != 1:
        raise ValueError(f"command must be 1-D, got shape {u.shape}")
    mag = np.abs(u)
    d = np.where(mag <= pl.width, 0.0, (mag - pl.width) / (1.0 - pl.width))
    kq = np.where(u < 0.0, pl.k_q_rev, pl.k_q)
    vb = np.full_like(d, pl.v_supply)
    for _ in range(50):
        w, _, ibus = _static(pl, d, kq, vb)
        vb_new = pl.v_supply - pl.r_int * ibus
        converged = np.max(np.abs(vb_new - vb), initial=0.0) < 1e-9
        vb = vb_new
        if converged:
            break
    rpm = np.sign(u) * w * RAD_S_TO_RPM
    if reported:
        m = config.measurement
        below = np.abs(rpm) < m.rpm_floor
        rpm = np.where(below, 0.0, rpm)
        if m.floor_zeroes_current:
            ibus = np.where(below, 0.0, ibus)
    return rpm, ibus


@dataclass(frozen=True)
class StepMetrics:
    """Response of one command step (times from the command change, s).

    Attributes
    ----------
    t_step : float
        Time of the command change, s.
    command_from, command_to : float
        Command before and after the step.
    dead_time_s : float
        Until the speed has moved 2 % of the step's speed change.
    settling_time_s : float
        Until the speed stays within 2 % of the step's speed change around the final value.
    overshoot : float
        Largest excursion beyond the final value, as a fraction of the speed change (>= 0).
    """

    t_step: float
    command_from: float
    command_to: float
    dead_time_s: float
    settling_time_s: float
    overshoot: float


def step_metrics(
    t: np.ndarray, command: np.ndarray, rpm: np.ndarray, *, band: float = 0.02
) -> list[StepMetrics]:
    """Measure dead time, settling time and overshoot of every command step in a trace.

    Parameters
    ----------
    t, command, rpm : np.ndarray, shape (n,)
        Sample times (s), commands, speeds (rpm); each step must be held until settled.
    band : float
        Relative band for dead time and settling (0.02: the 2 % criterion).

    Returns
    -------
    list of StepMetrics
        One per step whose speed change exceeds 50 rpm; initial and final speeds are averages
        over the last second before the step and before the next step.
    """
    t, command, rpm = (np.asarray(a, dtype=float) for a in (t, command, rpm))
    changes = np.flatnonzero(np.diff(command) != 0.0) + 1
    bounds = [*list(changes), len(t)]
    out = []
    for k, start in enumerate(changes):
        end = bounds[k + 1]
        before = (t >= t[start] - 1.0) & (t < t[start])
        after = (t >= t[end - 1] - 1.0) & (np.arange(len(t)) < end)
        initial, final = rpm[before].mean(), rpm[after].mean()
        change = final - initial
        if abs(change) < 50.0:
            continue
        seg_t = t[start - 1 : end] - t[start - 1]
        seg = rpm[start - 1 : end]
        moved = np.flatnonzero(np.abs(seg - initial) > band * abs(change))
        outside = np.flatnonzero(np.abs(seg - final) > band * abs(change))
        settle = seg_t[min(outside[-1] + 1, len(seg) - 1)] if len(outside) else 0.0
        out.append(
            StepMetrics(
                t_step=float(t[start - 1]),
                command_from=float(command[start - 1]),
                command_to=float(command[start]),
                dead_time_s=float(seg_t[moved[0]]) if len(moved) else math.nan,
                settling_time_s=float(settle),
                overshoot=float(max(0.0, np.max(np.sign(change) * (seg - final)) / abs(change))),
            )
        )
    return out


def hysteresis_loop_area(command: np.ndarray, rpm: np.ndarray, rpm_scale: float) -> float:
    """Area enclosed by a command-rpm loop (shoelace), with rpm divided by ``rpm_scale``.

    Parameters
    ----------
    command, rpm : np.ndarray, shape (n,)
        One full period of a periodic command and the resulting speed.
    rpm_scale : float
        Speed normalisation, rpm (e.g. the full-scale speed), so the area is dimensionless.
    """
    x = np.asarray(command, dtype=float)
    y = np.asarray(rpm, dtype=float) / rpm_scale
    return float(0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))
