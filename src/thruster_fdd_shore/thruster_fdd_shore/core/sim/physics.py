"""The reference thruster simulator (docs/simulator.md; docs/contracts.md, "Reference physics").

Signal path, in order: dead time -> deadband -> ESC duty (lag, optional second stage, slew
limit) -> quasi-static motor current -> rotor -> bus current (current limit) -> bus voltage
(sag) -> thrust; then the measurement model (``SimConfig.structure`` switches the second ESC
stage, a speed-dependent idle current and coasting instead of regeneration).
``ThrusterSimulator`` is the only stateful object; ``simulate`` runs it over a command history
and returns a ``Trace``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.sim.config import SimConfig, perturb_unit
from thruster_fdd_shore.core.sim.plant import (
    CONDITION_SPECS,
    RAD_S_TO_RPM,
    ConditionSpec,
    check_voltage,
    condition_spec,
    limited_duty,
    make_plant,
)

MAX_SUBSTEP_S = 0.01
"""Longest internal integration substep, s (the rotor update is linearly implicit, so stable)."""


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


class ThrusterSimulator:
    """One simulated thruster: the only stateful object of the simulator.

    Parameters
    ----------
    config : SimConfig
        Configuration of the nominal unit; with ``config.spread > 0`` the unit is drawn by seed.
    condition : str
        One of ``labels.CLASS_NAMES``.
    voltage : float or None
        Supply voltage in V; None uses the condition's (15.0 / 13.0 / 11.8 V; faults 15.0 V).
    seed : int
        Seed of the unit draw and of the measurement noise; equal seeds give equal runs.
    spec : ConditionSpec or None
        Physics of the condition instead of ``condition``'s (``plant.severity_spec``: half a
        blade, heavy fouling); ``condition`` then only names it. Its ``supply_v`` applies
        unless ``voltage`` is given.
    """

    def __init__(
        self,
        config: SimConfig,
        condition: str = "nominal_15v",
        *,
        voltage: float | None = None,
        seed: int = 0,
        spec: ConditionSpec | None = None,
    ) -> None:
        if not isinstance(config, SimConfig):
            raise BadInputError(f"config must be a SimConfig, got {type(config).__name__}")
        condition_spec(condition)
        check_voltage(voltage)
        self.config = config
        self.seed = int(seed)
        self.unit = perturb_unit(config, self.seed)
        self._voltage = voltage
        self._condition = condition
        self._spec = spec or CONDITION_SPECS[condition]
        self._plant = make_plant(self.unit, self._spec, voltage)
        self.reset()

    @property
    def condition(self) -> str:
        """The current condition name."""
        return self._condition

    @property
    def t(self) -> float:
        """Simulator time, s."""
        return self._t

    def set_condition(self, condition: str, spec: ConditionSpec | None = None) -> None:
        """Switch condition mid-run (fault injection); the dynamic state is kept.

        The supply voltage follows the new condition unless one was given at construction;
        ``spec``, when given, is its physics (as in the constructor).
        """
        self._spec = spec or condition_spec(condition)
        self._plant = make_plant(self.unit, self._spec, self._voltage)
        self._condition = condition

    def set_voltage(self, voltage: float | None) -> None:
        """Set the supply voltage in V (None: the condition's); the dynamic state is kept."""
        check_voltage(voltage)
        self._voltage = voltage
        self._plant = make_plant(self.unit, self._spec, voltage)

    def reset(self) -> None:
        """Return to rest at t = 0 and re-seed the measurement noise (condition is kept)."""
        pl = self._plant
        self._t = 0.0
        self._w = 0.0
        self._d = 0.0
        self._d1 = 0.0
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
            raise BadInputError(f"command must be finite, got {command}")
        if not (math.isfinite(dt) and dt >= 0.0):
            raise BadInputError(f"dt must be a finite duration >= 0 s, got {dt}")
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
        alpha2 = 1.0 - math.exp(-h / pl.tau2) if pl.tau2 > 0.0 else 1.0
        max_dd = pl.slew * h
        k_e, r0, rs, vsat, vs = pl.k_e, pl.r_ohm, pl.r_speed, pl.v_sat, pl.v_supply
        j_h = pl.inertia / h
        i_idle, i_max, r_int = pl.i_idle, pl.i_max, pl.r_int
        tc, b = pl.coulomb, pl.viscous
        w, d, d1, vb, theta = self._w, self._d, self._d1, self._vbus, self._theta
        for _ in range(n):
            if pl.tau2 > 0.0:
                # Second-order ESC: the lag's output d1 drives a second stage.
                d1 += (target - d1) * alpha
                dd = (d1 - d) * alpha2
            else:
                dd = (target - d) * alpha
            d += max(-max_dd, min(max_dd, dd))
            ve = vb / (1.0 + vb / vsat)
            reff = r0 + rs * abs(w)
            de = d
            motor = 1.0
            drawn = d * (d * ve - k_e * w) / reff
            if pl.regen == 0.0 and drawn < 0.0:
                # No regeneration: the motor would feed the bus, so the ESC lets it coast.
                motor = 0.0
                drawn = 0.0
            ibus = drawn + i_idle + pl.i_idle_speed * abs(w)
            if ibus > i_max:
                de = limited_duty(pl, d, ve, w, reff)
                ibus = i_max
            vb = vs - r_int * ibus
            aw = abs(w)
            kq = pl.k_q if w >= 0.0 else pl.k_q_rev
            a = j_h + motor * k_e * k_e / reff + 2.0 * kq * aw + b
            rhs = j_h * w + motor * k_e * de * ve / reff + kq * w * aw
            w_new = 0.0 if abs(rhs) <= tc else (rhs - math.copysign(tc, rhs)) / a
            theta += 0.5 * h * (w + w_new)
            w = w_new
        self._w, self._d, self._d1, self._vbus = w, d, d1, vb
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
        drawn = d * (d * ve - pl.k_e * w) / reff
        coasting = pl.regen == 0.0 and drawn < 0.0
        if coasting:
            drawn = 0.0
        ibus = drawn + pl.i_idle + pl.i_idle_speed * abs(w)
        if ibus > pl.i_max:
            de = limited_duty(pl, d, ve, w, reff)
            ibus = pl.i_max
        vbus = pl.v_supply - pl.r_int * ibus
        self._vbus = vbus
        i_m = 0.0 if coasting else (de * ve - pl.k_e * w) / reff
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
    spec: ConditionSpec | None = None,
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
        Condition name (``labels.CLASS_NAMES``).
    voltage : float or None
        Supply voltage, V; None uses the condition's.
    seed : int
        Unit and noise seed.
    spec : ConditionSpec or None
        Physics of the condition instead of ``condition``'s (see ``ThrusterSimulator``).

    Returns
    -------
    Trace
        Columns t, command (applied), voltage (V), rpm, current (A); ``extra`` holds
        ``temperature`` (C) and ``thrust`` (N), all shape (n,); ``condition`` is set.
    """
    t = np.asarray(t, dtype=float)
    command = np.asarray(command, dtype=float)
    if t.ndim != 1 or command.shape != t.shape or len(t) == 0:
        raise BadInputError(
            f"t and command must be 1-D of equal non-zero length: {t.shape}, {command.shape}"
        )
    if not np.all(np.isfinite(t)) or not np.all(np.isfinite(command)):
        raise BadInputError("t and command must be finite")
    if len(t) > 1 and not np.all(np.diff(t) > 0):
        raise BadInputError("t must be strictly increasing")
    sim = ThrusterSimulator(config, condition, voltage=voltage, seed=seed, spec=spec)
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
