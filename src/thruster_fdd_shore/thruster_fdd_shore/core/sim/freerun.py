"""Compiled noise-free free run of one thruster over a whole command history (numba).

``free_run`` computes what ``ThrusterSimulator`` (the reference, ``sim.physics``) reports when
it is stepped through a command history without measurement noise: the same dead-time segments,
deadband, ESC lag and slew limit, current limit (``plant.limited_duty``), voltage sag,
Coulomb and viscous friction, reverse ``k_q``, speed-dependent resistance and ESC drive loss,
and every switch of ``SimConfig.structure`` (second ESC stage, speed-dependent idle current,
coasting instead of regeneration), with the same 10 ms substeps and the same arithmetic up to
divisions taken as products with reciprocals, so the two agree to about 1e-13 relative. The
discrepancy workflow calls it thousands of times per run (least-squares Jacobians by finite
differences), where the reference's Python loop costs about 0.2 s per 6000 samples.

Not covered (the workflow does not need them): conditions other than a healthy unit (the
once-per-revolution ripple of a broken blade), unit spread, the winding temperature, thrust and
the measurement model (noise, quantisation, outliers, reporting floor). A test checks the kernel
against ``ThrusterSimulator`` over random configurations and command histories.

numba compiles the kernel on first use (a few seconds) and caches the machine code next to this
file (``__pycache__/``), so later processes load it in well under a second.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from thruster_fdd_shore.core.sim.config import SimConfig
from thruster_fdd_shore.core.sim.physics import MAX_SUBSTEP_S
from thruster_fdd_shore.core.sim.plant import (
    CONDITION_SPECS,
    RAD_S_TO_RPM,
    Plant,
    limited_duty,
    make_plant,
)

_limited_duty = njit(cache=True)(limited_duty)
"""``sim.plant.limited_duty``, compiled for the kernel."""


@njit(cache=True)
def _integrate(
    pl: Plant,
    v_supply: float,
    u: float,
    duration: float,
    w: float,
    d: float,
    d1: float,
    vb: float,
) -> tuple[float, float, float, float]:
    """``ThrusterSimulator._integrate``: state (w rad/s, duty, first ESC stage, bus V) after
    ``duration`` s."""
    if duration <= 0.0:
        return w, d, d1, vb
    k_e, r0, rs, vsat, inertia = pl.k_e, pl.r_ohm, pl.r_speed, pl.v_sat, pl.inertia
    k_q, k_q_rev, i_idle, tc, b = pl.k_q, pl.k_q_rev, pl.i_idle, pl.coulomb, pl.viscous
    width, tau, slew, r_int, i_max = pl.width, pl.tau, pl.slew, pl.r_int, pl.i_max
    tau2, i_idle_speed, regen = pl.tau2, pl.i_idle_speed, pl.regen
    mag = abs(u)
    target = 0.0 if mag <= width else math.copysign((mag - width) / (1.0 - width), u)
    n = max(1, math.ceil(duration / MAX_SUBSTEP_S - 1e-9))
    h = duration / n
    alpha = 1.0 - math.exp(-h / tau) if tau > 0.0 else 1.0
    alpha2 = 1.0 - math.exp(-h / tau2) if tau2 > 0.0 else 1.0
    max_dd = slew * h
    j_h = inertia / h
    # Fewer divisions than the reference (1 / v_sat as a factor, the speed update multiplied
    # through by R): about 20 % faster, equal to about 1e-13 relative.
    inv_vsat = 1.0 / vsat
    k_e2 = k_e * k_e
    for _ in range(n):
        if tau2 > 0.0:
            d1 += (target - d1) * alpha
            dd = (d1 - d) * alpha2
        else:
            dd = (target - d) * alpha
        # Python's max(-max_dd, min(max_dd, dd)), argument order kept
        step = dd if dd < max_dd else max_dd
        d += step if step > -max_dd else -max_dd
        ve = vb / (1.0 + vb * inv_vsat)
        aw = abs(w)
        r = r0 + rs * aw
        de = d
        motor = 1.0
        drawn = d * (d * ve - k_e * w) / r
        if regen == 0.0 and drawn < 0.0:
            motor = 0.0
            drawn = 0.0
        ibus = drawn + i_idle + i_idle_speed * aw
        if ibus > i_max:
            de = _limited_duty(pl, d, ve, w, r)
            ibus = i_max
        vb = v_supply - r_int * ibus
        kq = k_q if w >= 0.0 else k_q_rev
        # The reference's a and rhs times R: one division on the speed's chain.
        a_r = (j_h + 2.0 * kq * aw + b) * r + motor * k_e2
        rhs_r = (j_h * w + kq * w * aw) * r + motor * k_e * de * ve
        tc_r = tc * r
        w = 0.0 if abs(rhs_r) <= tc_r else (rhs_r - math.copysign(tc_r, rhs_r)) / a_r
    return w, d, d1, vb


@njit(cache=True)
def _free_run(pl: Plant, t: np.ndarray, command: np.ndarray, supply: np.ndarray) -> np.ndarray:
    """The whole run of the unit ``pl``; returns rpm, bus A, bus V, shape (3, n)."""
    k_e, r0, rs, vsat, i_idle = pl.k_e, pl.r_ohm, pl.r_speed, pl.v_sat, pl.i_idle
    delay, r_int, i_max = pl.delay, pl.r_int, pl.i_max
    i_idle_speed, regen = pl.i_idle_speed, pl.regen
    n = len(t)
    out = np.empty((3, n))
    # Dead-time history: (time the command was set, command); entries before `head` expired.
    hist_t = np.empty(n + 1)
    hist_u = np.empty(n + 1)
    hist_t[0] = -math.inf
    hist_u[0] = 0.0
    head, count = 0, 1
    w, d, d1, vb = 0.0, 0.0, 0.0, supply[0]
    now = 0.0
    previous = t[0]
    for i in range(n):
        dt = t[i] - previous
        previous = t[i]
        u = min(1.0, max(-1.0, command[i]))
        vs = supply[i]
        if delay == 0.0:
            w, d, d1, vb = _integrate(pl, vs, u, dt, w, d, d1, vb)
        else:
            t1 = now + dt
            if hist_u[count - 1] != u:
                hist_t[count] = now
                hist_u[count] = u
                count += 1
            while count - head > 1 and hist_t[head + 1] + delay <= now:
                head += 1
            s = now
            for j in range(head, count):
                end = hist_t[j + 1] + delay if j + 1 < count else math.inf
                seg_end = t1 if t1 < end else end
                if seg_end > s:
                    w, d, d1, vb = _integrate(pl, vs, hist_u[j], seg_end - s, w, d, d1, vb)
                    s = seg_end
                if s >= t1:
                    break
        now += dt
        # ThrusterSimulator._measure, noise-free: the bus state at the end of the step.
        ve = vb / (1.0 + vb / vsat)
        reff = r0 + rs * abs(w)
        drawn = d * (d * ve - k_e * w) / reff
        if regen == 0.0 and drawn < 0.0:
            drawn = 0.0
        ibus = drawn + i_idle + i_idle_speed * abs(w)
        if ibus > i_max:
            ibus = i_max
        vb = vs - r_int * ibus
        out[0, i] = w * RAD_S_TO_RPM
        out[1, i] = ibus
        out[2, i] = vb
    return out


def free_run(
    config: SimConfig, t: np.ndarray, command: np.ndarray, supply: np.ndarray
) -> dict[str, np.ndarray]:
    """Noise-free free run of the nominal unit of ``config`` (healthy, spread not applied).

    Equals ``ThrusterSimulator(config, voltage=supply[0])`` with measurement noise and spread
    off, stepped with ``step(command[i], t[i] - t[i-1])`` (``dt = 0`` for row 0), with
    ``set_voltage(supply[i])`` before step ``i`` whenever the supply changes, to rounding.

    Parameters
    ----------
    config : SimConfig
        Configuration; its measurement model and ``spread`` are ignored.
    t : np.ndarray, shape (n,)
        Sample times, s, non-decreasing.
    command : np.ndarray, shape (n,)
        Normalised commands, clamped to [-1, 1]; ``command[i]`` is held over ``(t[i-1], t[i]]``.
    supply : np.ndarray, shape (n,)
        Supply voltage during each step, V, in (0, 60].

    Returns
    -------
    dict of str to np.ndarray, each shape (n,)
        ``rpm`` (signed, no reporting floor), ``current`` (bus, A) and ``voltage`` (bus, V).

    Raises
    ------
    ValueError
        If the arrays are not 1-D of one non-zero length, hold non-finite values, ``t``
        decreases or a supply voltage is outside (0, 60] V.
    """
    t, command, supply = (np.ascontiguousarray(a, dtype=np.float64) for a in (t, command, supply))
    if t.ndim != 1 or len(t) == 0 or command.shape != t.shape or supply.shape != t.shape:
        raise ValueError(
            "t, command and supply must be 1-D of one non-zero length, got shapes "
            f"{t.shape}, {command.shape}, {supply.shape}"
        )
    for name, arr in (("t", t), ("command", command), ("supply", supply)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite")
    if np.any(np.diff(t) < 0.0):
        raise ValueError("t must be non-decreasing")
    if np.any(supply <= 0.0) or np.any(supply > 60.0):
        raise ValueError("supply voltage must be in (0, 60] V")
    pl = make_plant(config, CONDITION_SPECS["nominal_15v"], float(supply[0]))
    out = _free_run(pl, t, command, supply)
    return {"rpm": out[0], "current": out[1], "voltage": out[2]}
