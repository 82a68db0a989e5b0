"""The cross-validated score of a model and the evidence of a gain (docs/discrepancy.md).

A model is calibrated on every fold of ``Policy.folds`` (``evaluate``); every sample is
predicted by the fold that held it out, and its Gaussian log-likelihood in noise units, each
channel weighted by its effective sample share, is the score. ``gain_of`` compares two models
per block with the noise variance of the difference; ``evidence`` is the one acceptance test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

from thruster_fdd_shore.core.discrepancy.correction import GROUPS, basis, corrected
from thruster_fdd_shore.core.discrepancy.fit import (
    FULL_ITER,
    Fit,
    calibrate,
    free_parameters,
)
from thruster_fdd_shore.core.discrepancy.measure import (
    CHANNELS,
    FOLDS,
    N_BLOCKS,
    Measured,
    _uncensored,
    block_of,
    simulate_model,
    weighted_residuals,
    with_held,
)
from thruster_fdd_shore.core.discrepancy.moves import Spec, cold, undo
from thruster_fdd_shore.core.sim.config import SimConfig, set_effect, without_effects


@dataclass(frozen=True)
class Policy:
    """Every setting of the search; written into report.json.

    Attributes
    ----------
    alpha : float
        False-acceptance rate of one step, shared by its moves (Bonferroni).
    min_gain : float
        Least gain taken as evidence, nats (ESS-weighted): "positive" evidence on the scale of
        Kass & Raftery (1995), whatever the standard error.
    max_steps : int
        Most forward steps.
    active_sigma : float
        Where a move acts: undoing it moves a channel by more than this many noise std.
    structured : float
        Held-out residual variance, in noise variances, above which a rest is structure
        whatever the generic correction finds (``excess``): a difference none of its groups
        can express is still not noise. Also the bound within which the model without a start
        effect must explain the data where the effect's claim acts for the effect to be
        called superfluous.
    rest_least : float
        Least reduction of the held-out mean-square residual, in noise variances, for which a
        group of the generic correction with evidence marks a structured rest: a systematic
        error below 0.22 noise std RMS is evidence on a long trace but invisible in a plot of
        the residual (the simulator's own model, replayed on its trace, leaves about 0.02).
    bootstrap : int
        Block-bootstrap replicates of the recorded gains.
    seed : int
        Seed of the bootstrap.
    folds : tuple of tuple of int
        Held-out blocks of each cross-validation fold (``measure.FOLDS``: each block once, two
        half the trace apart).
    """

    alpha: float = 0.05
    min_gain: float = 3.0
    max_steps: int = 4
    active_sigma: float = 1.0
    structured: float = 2.0
    rest_least: float = 0.05
    bootstrap: int = 400
    seed: int = 0
    folds: tuple[tuple[int, ...], ...] = FOLDS

    def critical(self, moves: int) -> float:
        """Normal quantile a gain must exceed, in its own standard errors."""
        return float(ndtri(1.0 - self.alpha / max(moves, 1)))

    def test(self, sv: np.ndarray, moves: int = 1) -> tuple[float, float, bool]:
        """``evidence`` with this policy, ``moves`` sharing ``alpha``."""
        return evidence(sv, self.critical(moves), self.min_gain)


DEFAULT_POLICY = Policy()
"""The policy of ``thruster-fdd discrepancy``."""


RACE = 2
"""Least-squares iterations each origin of a move's re-fit is given before the better one is
fitted on (``evaluate``)."""


@dataclass(frozen=True)
class Scored:
    """A model calibrated on every fold.

    Attributes
    ----------
    spec : Spec
        The model.
    folds : tuple of Fit
        Its calibration on each fold of ``Policy.folds``.
    r, r_g : np.ndarray, shape (3, n)
        Normalised residual of every sample from the fold holding it out, without and with
        the static generic correction.
    active : np.ndarray of bool, shape (n,), or None
        For an addition or a base change, where it acts: the held-out samples it acts on in
        each fold whose own fit samples it acts on too; for a claim (``evaluate``'s
        ``fixed``), where the claimed effect acts.
    """

    spec: Spec
    folds: tuple[Fit, ...]
    r: np.ndarray
    r_g: np.ndarray
    active: np.ndarray | None = None


def _seen(data: Measured, mask: np.ndarray | None = None) -> np.ndarray:
    """Samples each channel's residual says something about (not censored), and ``mask``
    selects (shape (n,)), shape (3, n)."""
    seen = _uncensored(data)
    out = np.stack([seen[c] for c in CHANNELS])
    return out if mask is None else out & mask[None, :]


def weights(r: np.ndarray, data: Measured) -> np.ndarray:
    """Effective sample share of each channel's residual, ``(1 - rho) / (1 + rho)``, shape (3,)."""
    out = np.ones(len(CHANNELS))
    same = block_of(len(data.t))[1:] == block_of(len(data.t))[:-1]
    for c in range(len(CHANNELS)):
        a, b = r[c, :-1][same], r[c, 1:][same]
        if np.std(a) > 0.0 and np.std(b) > 0.0:
            rho = min(max(float(np.corrcoef(a, b)[0, 1]), 0.0), 0.99)
            out[c] = (1.0 - rho) / (1.0 + rho)
    return out


def effective_samples(r: np.ndarray, data: Measured) -> float:
    """Informative samples of all channels, each weighted by its channel's ``weights``: a gain
    of ``x`` nats lowers the mean-square residual by ``2 x / effective_samples`` noise
    variances."""
    seen, w = _seen(data), weights(r, data)
    return float(np.sum(w * seen.sum(axis=1)))


def sample_ll(r: np.ndarray, data: Measured, w: np.ndarray, mask: np.ndarray | None = None):
    """Held-out log-likelihood of each sample, nats (constant terms dropped), shape (n,)."""
    seen = _seen(data, mask)
    return -0.5 * np.sum(np.where(seen, r, 0.0) ** 2 * w[:, None], axis=0)


def gain_of(better: np.ndarray, worse: np.ndarray, data: Measured, w, mask=None) -> np.ndarray:
    """Per-block sum and variance of the log-likelihood gain of residuals ``better`` over
    ``worse`` (both shape (3, n)), shape (2, N_BLOCKS).

    The variance is the noise's: a sample whose two residuals differ by ``delta`` (noise
    std) contributes ``w * delta**2``, ``w`` its channel's effective sample share.
    """
    seen = _seen(data, mask)
    d = sample_ll(better, data, w, mask) - sample_ll(worse, data, w, mask)
    var = np.sum(np.where(seen, better - worse, 0.0) ** 2 * w[:, None], axis=0)
    blocks = block_of(len(d))
    return np.stack([np.bincount(blocks, d, N_BLOCKS), np.bincount(blocks, var, N_BLOCKS)])


def evidence(sv: np.ndarray, crit: float, least: float) -> tuple[float, float, bool]:
    """Sum, standard error and significance of a gain given per block (``gain_of``): above
    ``crit`` standard errors and ``least`` nats."""
    gain = float(sv[0].sum())
    se = float(math.sqrt(sv[1].sum()))
    return gain, se, bool(gain > least and gain > crit * se)


def _sse_train(config: SimConfig, data: Measured) -> float:
    res = weighted_residuals(simulate_model(config, data), data)
    with np.errstate(over="ignore", invalid="ignore"):
        s = sum(float(np.sum(res[c][data.fit] ** 2)) / data.sigma[c] ** 2 for c in CHANNELS)
    return s if math.isfinite(s) else math.inf


def _residuals(config: SimConfig, data: Measured, sim: dict | None = None) -> np.ndarray:
    """Normalised residuals of ``config`` (simulated as ``sim`` if given), shape (3, n)."""
    res = weighted_residuals(simulate_model(config, data) if sim is None else sim, data)
    with np.errstate(over="ignore", invalid="ignore"):
        r = np.stack([res[c] / data.sigma[c] for c in CHANNELS])
    return np.clip(np.nan_to_num(r, nan=1e6), -1e6, 1e6)


def _keys(config: SimConfig, anchor: SimConfig, spec: Spec, fixed: str | None):
    keys = free_parameters(config, anchor, spec.ranges)
    return tuple(k for k in keys if fixed is None or not k.startswith(f"{fixed}."))


def evaluate(job: tuple) -> Scored:
    """Calibrate a model on every fold; ``job`` = (move or None, parent or None, data, anchor,
    policy, fixed): the parent's model with ``move`` made, from the parent's fold fits and
    from them with the anchor's base (``moves.cold``), the better kept; with ``fixed`` (an
    effect name) that effect is held at the anchor's values (its claim), and ``active`` says
    where it acts."""
    move, parent, data, anchor, policy, fixed = job
    phi = basis(data)
    n = len(data.t)
    r, r_g = np.zeros((3, n)), np.zeros((3, n))
    seen = _seen(data)
    acting = fixed is not None or (move is not None and move.kind in ("add", "base", "joint"))
    active = np.zeros(n, bool) if acting else None
    folds = []
    spec = Spec() if parent is None else parent.spec
    if parent is not None and move is not None:
        spec = move.spec(spec, parent.folds[0].config, anchor)
    for i, held in enumerate(policy.folds):
        fold = with_held(data, held)
        if parent is None:
            fit = calibrate(anchor, fold, anchor=anchor)
        else:
            base = parent.folds[i].config
            if fixed is not None:
                origins = [set_effect(base, anchor.effect(fixed))]
            else:
                add = move is not None and move.kind in ("add", "joint")
                origins = [base, cold(base, anchor)] if add else [base]
            starts = [
                min(
                    move.starts(o, fold, anchor) if move is not None else [o],
                    key=lambda c: _sse_train(c, fold),
                )
                for o in origins
            ]
            keys = _keys(starts[0], anchor, spec, fixed)
            iters = FULL_ITER
            if len(starts) > 1:  # a short race of the origins; the better one goes on
                raced = [
                    calibrate(c, fold, keys, max_iter=RACE, anchor=anchor, ranges=spec.ranges)
                    for c in starts
                ]
                starts = [min(raced, key=lambda f: f.bic).config]
                iters -= RACE
            fit = calibrate(
                starts[0], fold, keys, max_iter=iters, anchor=anchor, ranges=spec.ranges
            )
        folds.append(fit)
        sim = simulate_model(fit.config, data)
        res = _residuals(fit.config, data, sim)
        r[:, fold.held] = res[:, fold.held]
        r_g[:, fold.held] = corrected(res, seen, fold.fit, fold.held, phi)[:, fold.held]
        if active is not None:
            other = without_effects(fit.config, (fixed,)) if fixed else undo(move, fit.config, base)
            where = acts(sim, other, data, policy)
            # A fitted move predicts its held-out samples only if its fold saw it act.
            shown = fixed is not None or bool(where[fold.fit].any())
            active[fold.held] = where[fold.held] & shown
    return Scored(spec, tuple(folds), r, r_g, active)


def acts(sim: dict, other: SimConfig, data: Measured, policy: Policy) -> np.ndarray:
    """Where the simulation ``sim`` and that of ``other`` differ by more than
    ``Policy.active_sigma`` noise std in a channel, shape (n,)."""
    sim0 = simulate_model(other, data)
    moved = np.stack([np.abs(sim[c] - sim0[c]) / data.sigma[c] for c in CHANNELS])
    return np.any(moved > policy.active_sigma, axis=0)


def excess(
    current: Scored, data: Measured, policy: Policy, where: np.ndarray | None = None
) -> float:
    """Held-out residual variance of ``current`` in noise variances (1 is noise), the mean over
    channels of a mean square over the held-out samples the reporting floor leaves informative.

    Over the whole trace, the median over the folds of each fold's mean square, so that one fold
    whose training blocks do not hold an operating point of its held-out ones (a short trace
    reversing once) does not make a good model's rest look structured. Over a region (the
    samples ``where`` selects, shape (n,)), the mean square over all its samples: a region sits
    in few blocks, and folds holding a handful of its samples must not outvote the fold holding
    most. 0 when no sample is selected.
    """
    seen = _seen(data, where)
    if where is not None:
        region = _mean_square(current.r, seen)
        return 0.0 if region is None else region
    per_fold = [
        _mean_square(current.r, seen & with_held(data, h).held[None, :]) for h in policy.folds
    ]
    per_fold = [m for m in per_fold if m is not None]
    return float(np.median(per_fold)) if per_fold else 0.0


def _mean_square(r: np.ndarray, mask: np.ndarray) -> float | None:
    """Mean over the channels ``mask`` (shape (3, n)) selects any sample of, of ``r``'s mean
    square over them; None when it selects none."""
    chans = [c for c in range(len(CHANNELS)) if mask[c].any()]
    return float(np.mean([np.mean(r[c][mask[c]] ** 2) for c in chans])) if chans else None


def rest_of(current: Scored, data: Measured, policy: Policy) -> dict[str, tuple]:
    """What each group of the generic correction (``correction.GROUPS``) explains of
    ``current``'s residual, cross-validated on its folds: group -> (gain, se, evidence)."""
    seen, w = _seen(data), weights(current.r, data)
    folds = [
        (with_held(data, h), _residuals(f.config, data))
        for h, f in zip(policy.folds, current.folds, strict=True)
    ]
    out = {}
    for group in GROUPS:
        phi, r_k = basis(data, group), np.array(current.r, copy=True)
        for fold, res in folds:
            r_k[:, fold.held] = corrected(res, seen, fold.fit, fold.held, phi)[:, fold.held]
        out[group] = policy.test(gain_of(r_k, current.r, data, w), len(GROUPS))
    return out
