"""Calibration of a simulator configuration to a measured trace by simulation error.

The configuration's parameters (base motor/rotor parameters and the parameters of every present
effect) are fitted by a free-run, noise-free simulation over the whole trace, driven by the
measured command and the supply voltage reconstructed from the measured bus voltage, compared
with the measurement on the fit samples.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from thruster_fdd_shore.core.discrepancy.measure import (
    CHANNELS,
    Measured,
    simulate_model,
    weighted_residuals,
)
from thruster_fdd_shore.core.sim.config import SimConfig
from thruster_fdd_shore.core.sim.effects import make_effect

BASE_FIT = ("k_e", "r_ohm", "k_q", "k_q_reverse_ratio", "inertia", "i_idle_a")
"""Base parameters (``ThrusterParams`` fields) fitted on every calibration."""


STRUCTURE_FIT: dict[str, float] = {
    "params.esc_v_sat_v": math.inf,
    "params.r_speed_ohm_s": 0.0,
    "structure.i_idle_per_krpm_a": 0.0,
    "structure.esc_tau2_s": 0.0,
}
"""Structural base terms (``owner.name`` -> the value that means absent) the anchor may lack:
drive saturation (fitted as ``1 / esc_v_sat_v``, so none is 0), a speed-dependent winding loss
and idle current growing with speed (``DRIVE_LOSSES``), and a second ESC stage, each fitted
only once the search adopted it (a base change, ``moves.BASE_CHANGES``): free, they trade with
the effects (the drive losses with friction and the deadband, the second stage with the delays).
The second stage sits behind an ``esc_lag`` and is never slower than it (two stages in cascade
commute: ordering them removes a symmetry of the fit). A term the anchor has was calibrated
with it and is kept, unless the search adopted its re-fit (``ranges`` holds its key)."""


DRIVE_LOSSES = ("params.esc_v_sat_v", "params.r_speed_ohm_s", "structure.i_idle_per_krpm_a")
"""``STRUCTURE_FIT`` terms of the static drive and loss curves. One the anchor lacks is fitted
only when ``calibrate``'s ``ranges`` holds its key (the value is unused: their bounds are
physical), which the search's drive-loss base change sets."""


FULL_ITER = 30
"""Least-squares iterations of a calibration (``calibrate``'s default; most stop earlier, on
``ftol``), enough from a far start (a superfluous dead time, ``k_q`` outside its range)."""


BLOWN_UP = 1e6
"""Weighted residual (noise standard deviations) that a sample of a simulation which blew up
counts as, and the most any sample counts as in a calibration."""


BASE_RANGE = 2.0
"""Base parameters are fitted within [anchor / BASE_RANGE, anchor * BASE_RANGE] of the user's
starting configuration (``calibrate``'s ``anchor``), unless ``ranges`` widens them."""


@dataclass(frozen=True)
class Fit:
    """A calibrated configuration.

    Attributes
    ----------
    config : SimConfig
        Configuration with the fitted values.
    names : tuple of str
        Fitted parameters as ``owner.name`` (owner ``params``, ``structure`` or an effect name).
    values, std : np.ndarray, shape (k,)
        Fitted values and their standard deviations (Jacobian, inflated for residual
        autocorrelation).
    bic : float
        Bayesian information criterion on the fit samples.
    n_sims : int
        Simulations spent.
    """

    config: SimConfig
    names: tuple[str, ...]
    values: np.ndarray
    std: np.ndarray
    bic: float
    n_sims: int

    def uncertainty(self, key: str) -> float:
        """Standard deviation of parameter ``owner.name``."""
        return float(self.std[self.names.index(key)])


@dataclass(frozen=True)
class _Param:
    """One fitted parameter: value = start * exp(z) (``log``), max(start + scale * z, 0)
    (``linear``) or 1 / (1 / start + scale * z) (``inverse``, inf where that is <= 0), z in
    [lower, upper]; z = 0 is the start."""

    key: str
    start: float
    kind: str
    scale: float
    lower: float
    upper: float

    def value(self, z: float) -> float:
        if self.kind == "log":
            return self.start * math.exp(z)
        if self.kind == "inverse":
            g = (1.0 / self.start) + self.scale * z
            return math.inf if g <= 0.0 else 1.0 / g
        return max(self.start + self.scale * z, 0.0)


def _get(config: SimConfig, key: str) -> float:
    owner, name = key.split(".")
    if owner == "params":
        return float(getattr(config.params, name))
    if owner == "structure":
        return float(getattr(config.structure, name))
    effect = config.effect(owner)
    if effect is None:
        raise ValueError(f"configuration has no effect {owner!r}")
    return effect.params()[name]


def _set(config: SimConfig, values: dict[str, float]) -> SimConfig:
    """``config`` with ``values`` (by ``owner.name``; keys of absent effects are ignored), made
    in one step: a fit builds a configuration per simulation."""
    groups: dict[str, dict[str, float]] = {}
    for key, value in values.items():
        owner, name = key.split(".")
        groups.setdefault(owner, {})[name] = value
    changes: dict[str, object] = {}
    if "params" in groups:
        changes["params"] = replace(config.params, **groups.pop("params"))
    if "structure" in groups:
        changes["structure"] = replace(config.structure, **groups.pop("structure"))
    if groups:
        changes["effects"] = tuple(
            make_effect(e.name, {**e.params(), **groups[e.name]}) if e.name in groups else e
            for e in config.effects
        )
    return replace(config, **changes) if changes else config


_TAU2 = "structure.esc_tau2_s"


def _lag(config: SimConfig) -> float:
    """The ``esc_lag`` time constant of ``config``, s (0 without one)."""
    lag = config.effect("esc_lag")
    return lag.tau_s if lag is not None else 0.0


def _second_stage(config: SimConfig) -> bool:
    """Whether ``config`` has a second ESC stage to fit: adopted by the search (a base change,
    ``moves.BASE_CHANGES``), behind an ``esc_lag``."""
    return _lag(config) > 0.0 and config.structure.esc_tau2_s > 0.0


def lacking_drive_losses(anchor: SimConfig) -> tuple[str, ...]:
    """The ``DRIVE_LOSSES`` terms ``anchor`` lacks."""
    return tuple(k for k in DRIVE_LOSSES if _get(anchor, k) == STRUCTURE_FIT[k])


def free_parameters(
    config: SimConfig, anchor: SimConfig | None = None, ranges: Collection[str] = ()
) -> tuple[str, ...]:
    """Keys (``owner.name``) calibrated for ``config``: ``BASE_FIT``, the ``STRUCTURE_FIT``
    terms ``anchor`` (default ``config``) lacks and the search adopted (``DRIVE_LOSSES`` in
    ``ranges``, a second ESC stage in ``config``), and every effect parameter."""
    anchor = config if anchor is None else anchor

    def free(key: str, absent: float) -> bool:
        if _get(anchor, key) != absent:
            # Kept unless the search freed it (a factor around the anchor in ``ranges``).
            return key in ranges
        return _second_stage(config) if key == _TAU2 else key in ranges

    keys = [f"params.{n}" for n in BASE_FIT]
    keys += [k for k, absent in STRUCTURE_FIT.items() if free(k, absent)]
    keys += [f"{e.name}.{p}" for e in config.effects for p in e.params()]
    return tuple(keys)


_BELOW_ZERO = 1e-3
"""How far (z units) a linear or inverse parameter may go below its physical 0 (clamped there),
so that a start at 0 is inside the bounds (``calibrate``)."""


def _linear(key: str, value: float, scale: float, hi: float) -> _Param:
    """A linear parameter in [0, hi] with step ``scale``, starting at ``value``."""
    return _Param(
        key, value, "linear", scale, -value / scale - _BELOW_ZERO, max(hi - value, 0.0) / scale
    )


def _bounded_log(key: str, value: float, anchor: float, factor: float) -> _Param:
    """A log-scale parameter within [anchor / factor, anchor * factor] (widened to include
    ``value``)."""
    start = max(value, 1e-12)
    anchored = max(anchor, 1e-12)
    lo = math.log(anchored / factor / start)
    hi = math.log(anchored * factor / start)
    return _Param(key, start, "log", 1.0, min(lo, 0.0), max(hi, 0.0))


def _spec(config: SimConfig, key: str, anchor: SimConfig, factor: float) -> _Param:
    """How ``key`` is fitted; base parameters within ``factor`` of ``anchor``'s value."""
    value = _get(config, key)
    r_ohm = _get(anchor, "params.r_ohm")
    if key == "params.i_idle_a":
        return _linear(key, value, 0.05, _get(anchor, key) + 2.0)
    present = key in STRUCTURE_FIT and _get(anchor, key) != STRUCTURE_FIT[key]
    if present and key.startswith("params."):
        return _bounded_log(key, value, _get(anchor, key), factor)
    if key == "params.esc_v_sat_v":
        # Fitted as g = 1 / v_sat in [0, 1/20] per V (v_sat >= 20 V: 43 % drive loss at 15 V).
        g = 1.0 / value
        return _Param(key, value, "inverse", 1e-3, -g / 1e-3 - _BELOW_ZERO, (0.05 - g) / 1e-3)
    if key == "params.r_speed_ohm_s":
        # Up to 4 x r_ohm more at 400 rad/s.
        return _linear(key, value, 0.1 * r_ohm / 400.0, 4.0 * r_ohm / 400.0)
    if key == "structure.i_idle_per_krpm_a":
        return _linear(key, value, 0.01, 0.5)
    if key == "structure.esc_tau2_s":
        # Fitted as the fraction of the esc_lag time constant, in [0, 1] (``_TAU2``).
        tau = _lag(config)
        return _linear(key, value / tau if tau > 0.0 else 0.0, 0.1, 1.0)
    if key == "deadband.width":
        start = max(value, 1e-3)
        return _Param(key, start, "log", 1.0, math.log(1e-4 / start), math.log(0.5 / start))
    if not key.startswith("params."):
        # Effect parameters may move by a factor e**4 from their value in ``config``.
        start = max(value, 1e-12)
        return _Param(key, start, "log", 1.0, -4.0, 4.0)
    # Base parameters stay within a factor of the anchor (the user's starting configuration,
    # a calibrated simulator), not of each fit's start, from which they would drift again on
    # every re-fit.
    return _bounded_log(key, value, _get(anchor, key), factor)


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


def _value_std(spec: _Param, value: float, dz: float) -> float:
    """Standard deviation of a parameter's value from that of its fitted z."""
    if spec.kind == "log":
        return value * dz
    if spec.kind == "inverse":
        return value * value * spec.scale * dz if math.isfinite(value) else math.inf
    return spec.scale * dz


def calibrate(
    config: SimConfig,
    data: Measured,
    keys: Sequence[str] | None = None,
    *,
    max_iter: int | None = None,
    anchor: SimConfig | None = None,
    ranges: Mapping[str, float] | None = None,
) -> Fit:
    """Fit parameters of ``config`` by free-run simulation error on the fit samples.

    Parameters
    ----------
    config : SimConfig
        Starting configuration (its values are the initial guess).
    data : Measured
        Prepared measurement.
    keys : sequence of str or None
        Parameters to fit (``owner.name``); None fits ``free_parameters(config, anchor, ranges)``.
    max_iter : int or None
        Limit of least-squares iterations (function evaluations without the Jacobian's);
        None: ``FULL_ITER``.
    anchor : SimConfig or None
        The user's starting configuration: base parameters stay within a factor
        ``BASE_RANGE`` of its values, and its structural terms are kept (None: ``config``).
    ranges : mapping of str to float, or None
        Other factors than ``BASE_RANGE`` for some base parameters (``params.NAME``); a key
        of ``DRIVE_LOSSES`` frees that term.

    Returns
    -------
    Fit
        With standard deviations of every key from the weighted Jacobian.
    """
    anchor = config if anchor is None else anchor
    max_iter = FULL_ITER if max_iter is None else max_iter
    ranges = ranges or {}
    keys = tuple(free_parameters(config, anchor, ranges) if keys is None else keys)
    specs = [_spec(config, k, anchor, ranges.get(k, BASE_RANGE)) for k in keys]
    scale = np.array([data.sigma[c] for c in CHANNELS])
    fit_idx = np.flatnonzero(data.fit)
    count = [0]

    def values_of(z: np.ndarray) -> dict[str, float]:
        values = {s.key: s.value(float(zi)) for s, zi in zip(specs, z, strict=True)}
        if _TAU2 in values:  # fitted as a fraction of the esc_lag time constant
            values[_TAU2] *= values.get("esc_lag.tau_s", _lag(config))
        return values

    def build(z: np.ndarray) -> SimConfig:
        return _set(config, values_of(z))

    def fun(z: np.ndarray) -> np.ndarray:
        count[0] += 1
        res = weighted_residuals(simulate_model(build(z), data), data)
        out = np.concatenate([res[c][fit_idx] / s for c, s in zip(CHANNELS, scale, strict=True)])
        # A simulation that blows up (a trial step far out: a supply resistance much larger
        # than the motor's makes the bus voltage oscillate) is a very bad, finite fit; clipped
        # everywhere, as huge finite residuals overflow the finite-difference Jacobian.
        out[np.isnan(out)] = BLOWN_UP
        return np.clip(out, -BLOWN_UP, BLOWN_UP, out=out)

    # z = 0 (the start) strictly inside the bounds, so the first trust region is sized 1: a
    # start nudged off a bound (z = 1e-9) makes it vanish, the fit then stops at once.
    lower = np.minimum([s.lower for s in specs], -1e-6)
    upper = np.maximum([s.upper for s in specs], 1e-6)
    z0 = np.zeros(len(specs))
    # One BLAS thread: the SVD of the tall, narrow Jacobian is many times slower on two
    # threads of a busy 2-core machine.
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
    res = weighted_residuals(simulate_model(best, data), data)
    fitted = values_of(sol.x)
    values = np.array([fitted[s.key] for s in specs])
    dof = max(len(sol.fun) - len(specs), 1)
    s2 = float(np.sum(sol.fun**2)) / dof
    infl = max(_autocorr_inflation(res[c][fit_idx]) for c in ("rpm", "current"))
    dz = np.sqrt(_param_variance(sol.jac) * s2) * infl
    dvalue = np.array([_value_std(s, v, d) for s, v, d in zip(specs, values, dz, strict=True)])
    if _TAU2 in keys:  # the std of the fraction, in s
        dvalue[keys.index(_TAU2)] *= _lag(best)
    return Fit(
        config=best,
        names=keys,
        values=values,
        std=dvalue,
        bic=_bic(res, data.fit, len(specs)),
        n_sims=count[0] + 1,
    )
