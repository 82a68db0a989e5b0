"""Noise-free steady-state curves of a simulated unit: speed and bus current per command."""

from __future__ import annotations

import numpy as np

from thruster_fdd_shore.core.sim.config import SimConfig
from thruster_fdd_shore.core.sim.plant import (
    RAD_S_TO_RPM,
    ConditionSpec,
    Plant,
    check_voltage,
    condition_spec,
    make_plant,
)


def _static(
    pl: Plant, d: np.ndarray, kq: np.ndarray, vb: np.ndarray
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
        drawn = duty * (duty * ve - pl.k_e * w) / (pl.r_ohm + pl.r_speed * w)
        return drawn + pl.i_idle + pl.i_idle_speed * w

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
    spec: ConditionSpec | None = None,
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
    spec : ConditionSpec or None
        Physics of the condition instead of ``condition``'s (``plant.severity_spec``).

    Returns
    -------
    rpm : np.ndarray, shape (n,)
        Signed steady speed, rpm.
    current : np.ndarray, shape (n,)
        Steady bus current, A.
    """
    check_voltage(voltage)
    pl = make_plant(config, spec or condition_spec(condition), voltage)
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


def steady_curves(
    config: SimConfig, command: np.ndarray, voltage: float, specs: list[ConditionSpec]
) -> tuple[np.ndarray, np.ndarray, list[Plant]]:
    """``steady_state`` (noise-free, no reporting floor) of many conditions at once.

    The same arithmetic, evaluated on all conditions together (each ``Plant`` field an array
    over them): one solve instead of one per condition.

    Parameters
    ----------
    config : SimConfig
        Simulator configuration (spread not applied).
    command : np.ndarray, shape (n,)
        Normalised commands held until steady; clamped to [-1, 1].
    voltage : float
        Supply voltage, V (overrides the specs').
    specs : list of ConditionSpec, length K
        The conditions (``plant.severity_spec`` for a severity sweep).

    Returns
    -------
    rpm : np.ndarray, shape (K, n)
        Signed steady speed, rpm.
    current : np.ndarray, shape (K, n)
        Steady bus current, A.
    plants : list of Plant, length K
        The plant of each condition (thrust coefficients, supply resistance).
    """
    check_voltage(voltage)
    plants = [make_plant(config, spec, voltage) for spec in specs]
    # A plant whose fields are columns (K, 1): _static broadcasts them over the commands.
    pl = Plant(
        *(np.array([getattr(p, f) for p in plants], dtype=float)[:, None] for f in Plant._fields)
    )
    u = np.clip(np.asarray(command, dtype=float), -1.0, 1.0)[None, :]
    mag = np.abs(u)
    d = np.where(mag <= pl.width, 0.0, (mag - pl.width) / (1.0 - pl.width))
    kq = np.where(u < 0.0, pl.k_q_rev, pl.k_q)
    vb = np.broadcast_to(pl.v_supply, d.shape).copy()
    for _ in range(50):
        w, _, ibus = _static(pl, d, kq, vb)
        vb_new = pl.v_supply - pl.r_int * ibus
        # 1 uV: far below any voltage measurement; each pass costs a full solve.
        converged = np.max(np.abs(vb_new - vb), initial=0.0) < 1e-6
        vb = vb_new
        if converged:
            break
    return np.sign(u) * w * RAD_S_TO_RPM, ibus, plants
