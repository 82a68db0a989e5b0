"""Calibration of a simulator configuration to a measured trace by simulation error.

The configuration's parameters (base motor/rotor parameters and the parameters of every present
effect) are fitted by a free-run, noise-free simulation over the whole trace, driven by the
measured command and the supply voltage reconstructed from the measured bus voltage, compared
with the measurement on the fit samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from thruster_fdd.core.discrepancy.measure import (
    CHANNELS,
    Gap,
    Measured,
    gap,
    simulate_model,
    weighted_residuals,
)
from thruster_fdd.core.sim.config import SimConfig, set_effect
from thruster_fdd.core.sim.effects import make_effect

BASE_FIT = ("k_e", "r_ohm", "k_q", "k_q_reverse_ratio", "inertia", "i_idle_a")
"""Base parameters (``ThrusterParams`` fields) fitted on every calibration."""


BASE_RANGE = 2.0
"""Base parameters are fitted within [start / BASE_RANGE, start * BASE_RANGE] of the user's
starting configuration (``calibrate``'s ``anchor``)."""


@dataclass(frozen=True)
class Fit:
    """A calibrated configuration.

    Attributes
    ----------
    config : SimConfig
        Configuration with the fitted values.
    names : tuple of str
        Fitted parameters as ``owner.name`` (owner ``params`` or an effect name).
    values, std : np.ndarray, shape (k,)
        Fitted values and their standard deviations (Jacobian, inflated for residual
        autocorrelation).
    bic : float
        Bayesian information criterion on the fit samples.
    gap : Gap
        Held-out gap.
    n_sims : int
        Simulations spent.
    """

    config: SimConfig
    names: tuple[str, ...]
    values: np.ndarray
    std: np.ndarray
    bic: float
    gap: Gap
    n_sims: int

    def uncertainty(self, key: str) -> float:
        """Standard deviation of parameter ``owner.name``."""
        return float(self.std[self.names.index(key)])


@dataclass(frozen=True)
class _Param:
    """One fitted parameter: value = start * exp(z) (log) or start + scale * z (linear)."""

    key: str
    start: float
    log: bool
    scale: float
    lower: float
    upper: float

    def value(self, z: float) -> float:
        if self.log:
            return self.start * math.exp(z)
        return self.start + self.scale * z


def _get(config: SimConfig, key: str) -> float:
    owner, name = key.split(".")
    if owner == "params":
        return float(getattr(config.params, name))
    effect = config.effect(owner)
    if effect is None:
        raise ValueError(f"configuration has no effect {owner!r}")
    return effect.params()[name]


def _set(config: SimConfig, values: dict[str, float]) -> SimConfig:
    base = {k.split(".")[1]: v for k, v in values.items() if k.startswith("params.")}
    if base:
        config = replace(config, params=replace(config.params, **base))
    for effect in config.effects:
        mine = {k.split(".")[1]: v for k, v in values.items() if k.startswith(f"{effect.name}.")}
        if mine:
            config = set_effect(config, make_effect(effect.name, {**effect.params(), **mine}))
    return config


def free_parameters(config: SimConfig) -> tuple[str, ...]:
    """Keys (``owner.name``) calibrated for ``config``: ``BASE_FIT`` and every effect parameter."""
    keys = [f"params.{n}" for n in BASE_FIT]
    keys += [f"{e.name}.{p}" for e in config.effects for p in e.params()]
    return tuple(keys)


def _spec(config: SimConfig, key: str, anchor: SimConfig) -> _Param:
    value = _get(config, key)
    if key == "params.i_idle_a":
        upper = _get(anchor, key) + 2.0
        return _Param(key, value, False, 0.05, -value / 0.05, max(upper - value, 0.0) / 0.05)
    if key == "deadband.width":
        start = max(value, 1e-3)
        return _Param(key, start, True, 1.0, math.log(1e-4 / start), math.log(0.5 / start))
    start = max(value, 1e-12)
    if not key.startswith("params."):
        # Effect parameters may move by a factor e**4 from their value in ``config``.
        return _Param(key, start, True, 1.0, -4.0, 4.0)
    # Base parameters stay within a factor BASE_RANGE of the anchor (the user's starting
    # configuration, a calibrated simulator). Bounds around each round's start let them drift
    # by that factor again in every round: on the T200 bench trace r_ohm went from 0.108 to
    # 0.0046 ohm over the rounds, and the deadband came out 0.021 instead of 0.033.
    anchored = max(_get(anchor, key), 1e-12)
    lo = math.log(anchored / BASE_RANGE / start)
    hi = math.log(anchored * BASE_RANGE / start)
    return _Param(key, start, True, 1.0, min(lo, 0.0), max(hi, 0.0))


def _bic(res: dict[str, np.ndarray], mask: np.ndarray, k: int) -> float:
    n = int(mask.sum())
    total = sum(n * math.log(max(float(np.mean(res[c][mask] ** 2)), 1e-300)) for c in CHANNELS)
    return total + k * math.log(n * len(CHANNELS))


def _autocorr_inflation(r: np.ndarray) -> float:
    if len(r) < 3 or not np.any(r):
        return 1.0
    rho = float(np.corrcoef(r[:-1], r[1:])[0, 1])
    rho = min(max(rho, 0.0), 0.99) if math.isfinite(rho) else 0.0
    return math.sqrt((1.0 + rho) / (1.0 - rho))


def _param_variance(jac: np.ndarray) -> np.ndarray:
    """Diagonal of (J^T J)^-1; inf for a parameter the residuals do not (or only jointly with
    others, in a null direction) depend on, where a pseudo-inverse would report 0."""
    jtj = jac.T @ jac
    norm = np.sqrt(np.diag(jtj))
    var = np.full(len(norm), math.inf)
    ok = norm > 0.0
    if not np.any(ok):
        return var
    w, v = np.linalg.eigh(jtj[np.ix_(ok, ok)] / np.outer(norm[ok], norm[ok]))
    small = w <= 1e-10 * max(float(w.max()), 1e-300)
    var_ok = np.sum(v[:, ~small] ** 2 / w[~small], axis=1)
    var_ok[np.any(np.abs(v[:, small]) > 1e-3, axis=1)] = math.inf
    var[ok] = var_ok / norm[ok] ** 2
    return var


def calibrate(
    config: SimConfig,
    data: Measured,
    keys: Sequence[str] | None = None,
    *,
    max_iter: int = 12,
    anchor: SimConfig | None = None,
) -> Fit:
    """Fit parameters of ``config`` by free-run simulation error on the fit samples.

    Parameters
    ----------
    config : SimConfig
        Starting configuration (its values are the initial guess).
    data : Measured
        Prepared measurement.
    keys : sequence of str or None
        Parameters to fit (``owner.name``); None fits ``free_parameters(config)``.
    max_iter : int
        Limit of least-squares iterations (function evaluations without the Jacobian's).
    anchor : SimConfig or None
        The user's starting configuration: base parameters stay within a factor
        ``BASE_RANGE`` of its values (None: of ``config``'s).

    Returns
    -------
    Fit
        With standard deviations of every key from the weighted Jacobian.
    """
    keys = tuple(free_parameters(config) if keys is None else keys)
    specs = [_spec(config, k, config if anchor is None else anchor) for k in keys]
    scale = np.array([data.sigma[c] for c in CHANNELS])
    fit_idx = np.flatnonzero(data.fit)
    count = [0]

    def build(z: np.ndarray) -> SimConfig:
        return _set(config, {s.key: s.value(float(zi)) for s, zi in zip(specs, z, strict=True)})

    def fun(z: np.ndarray) -> np.ndarray:
        count[0] += 1
        res = weighted_residuals(simulate_model(build(z), data), data)
        return np.concatenate([res[c][fit_idx] / s for c, s in zip(CHANNELS, scale, strict=True)])

    lower = np.array([s.lower for s in specs])
    upper = np.array([s.upper for s in specs])
    z0 = np.clip(np.zeros(len(specs)), lower + 1e-9, upper - 1e-9)
    # One BLAS thread: the SVD of the tall Jacobian (about 12600 x 12 on a 10-minute trace) takes
    # 4 ms on one OpenBLAS thread and 120 ms on two on a busy 2-core machine (measured).
    with threadpool_limits(limits=1, user_api="blas"):
        sol = least_squares(
            fun,
            z0,
            bounds=(lower, upper),
            diff_step=3e-3,
            max_nfev=max_iter,
            x_scale="jac",
            ftol=1e-3,
            xtol=1e-4,
        )
    best = build(sol.x)
    sim = simulate_model(best, data)
    res = weighted_residuals(sim, data)
    values = np.array([s.value(float(zi)) for s, zi in zip(specs, sol.x, strict=True)])
    dof = max(len(sol.fun) - len(specs), 1)
    s2 = float(np.sum(sol.fun**2)) / dof
    infl = max(_autocorr_inflation(res[c][fit_idx]) for c in ("rpm", "current"))
    dz = np.sqrt(_param_variance(sol.jac) * s2) * infl
    dvalue = np.array(
        [v * d if s.log else s.scale * d for s, v, d in zip(specs, values, dz, strict=True)]
    )
    return Fit(
        config=best,
        names=keys,
        values=values,
        std=dvalue,
        bic=_bic(res, data.fit, len(specs)),
        gap=gap(sim, data),
        n_sims=count[0] + 1,
    )
