"""Discrepancy workflow: calibrate the simulator to a measured trace and name missing effects.

Steps of ``thruster-fdd discrepancy`` (docs/discrepancy.md; report keys in docs/contracts.md):

1. ``prepare_measured``: the measured trace is despiked, its per-channel noise level estimated,
   and its samples split into interleaved fit / held-out blocks (10 blocks; 2, 5 and 8 held out).
2. ``calibrate``: the configuration's parameters (base motor/rotor parameters and the parameters
   of every present effect) are fitted by *simulation error*: a free-run, noise-free simulation
   over the whole trace, driven by the measured command and by the supply voltage reconstructed
   from the measured bus voltage, compared with the measurement on the fit samples.
3. ``localize`` / ``signatures``: where the residuals lie (signal, operating region, share of the
   squared error) and the signatures that point to causes (lag, flat zone, clipping, offsets).
4. ``search``: every effect of the vocabulary the configuration lacks is added (to the calibrated
   model and to the uncalibrated start), grid-initialised and re-fitted; it is accepted if its
   BIC on the fit samples is lower and it (and the effect itself, by ablation) removes at least
   ``MIN_GAIN`` of the held-out error. The best accepted are fully calibrated and, between
   two or more, the one with the best cross-validated score (``FOLDS``) is taken. Repeated
   while an addition helps, so two missing effects are both named.

Measurement noise is handled explicitly: the model is simulated noise-free (noise, outliers and
quantisation off), the measured trace is despiked, residuals are weighted by the estimated noise
level of each channel, and the reporting floor (``rpm_floor``) is treated as censoring: a measured
zero only says the model's speed should be under the floor.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from multiprocessing import get_context
from typing import TypeVar

import numpy as np
from tqdm import tqdm

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.discrepancy.fit import (
    BASE_FIT,
    BASE_RANGE,
    Fit,
    calibrate,
    free_parameters,
    lacking_drive_losses,
    without_effects,
)
from thruster_fdd_shore.core.discrepancy.measure import (
    CHANNELS,
    FOLDS,
    Measured,
    gap,
    prepare_measured,
    simulate_model,
    weighted_residuals,
    with_held,
)
from thruster_fdd_shore.core.sim.config import SimConfig, set_effect
from thruster_fdd_shore.core.sim.effects import EFFECTS, make_effect
from thruster_fdd_shore.core.sim.plant import RAD_S_TO_RPM

VERDICTS = ("effects_found", "nothing_missing", "unexplained")
"""Values of ``report.json``'s ``verdict`` (docs/contracts.md)."""


MIN_GAIN = 0.15
"""Fraction of the held-out error (in noise units, above the noise floor) an addition must
remove to be accepted."""


STRUCTURED = 2.0
"""Held-out mean squared residual, in units of the noise variance (per channel, averaged), above
which the residual still holds structure (``unexplained`` when no candidate helps)."""


CANDIDATE_ITER = 6
"""Least-squares iterations of each candidate re-fit and of the control re-fit of a round."""


MAX_ROUNDS = 3


RIGHT_SPREAD = 0.3
"""Least excess over the noise level (held-out score 1) a gain is counted against. A right
model's score scatters around 1 by about this much (the simulated thruster itself, without
noise: standard deviation 0.19 on exact-base tuning traces 100-139, 0.12 on t100 null traces
1075-1114, 0.16 on t200 null traces 1170-1229 but 1193, whose current peaks no model follows,
at 3.3; 90th percentiles 1.16-1.22), so an excess smaller than that is no measure of what a
model lacks, and a fraction of it no evidence of an effect: on t200 trace 631 (inertia 2.45
times the start's, the truth at 1.18) a viscous torque taking 1.165 to 1.14 removed 15 % of
the excess and was named beside a hidden deadband; counted against 0.3 it removes 8 %."""


BIC_EVIDENCE = 2.0
"""Amount by which a candidate must lower the BIC on the fit samples to be accepted. A
difference under 2 is "not worth more than a bare mention" (Kass & Raftery 1995, Bayes
factors, J. Am. Stat. Assoc. 90: 773-795): an exact-base null trace, nothing missing, had a
slew limit named at dBIC -0.5 where the held-out score, 1.16 for the start, went to 1.05."""


N_FINALS = 3
"""Accepted candidates of a round fully calibrated before the choice (the best by their short
re-fit's held-out score). An effect fitted about as well as a base change may come third
after a short re-fit and only a full calibration shows it (an exact-base Coulomb torque
beside a voltage sag: the drive losses 0.84, a viscous torque 0.94 and the torque 0.96 after
the short re-fit; fully calibrated 0.84, 0.87 and 0.81)."""


WIDE_RANGE = 4.0
"""Factor around the start to which a base parameter found on its ``BASE_RANGE`` bound may be
widened (``base_changes``)."""


SECOND_STAGE = (0.03, 0.06, 0.12, 0.2, 0.3, 0.45)
"""Starting time constants of a second ESC stage, as fractions of the calibrated ``esc_lag``'s,
which is shortened by as much (the cascade keeps the lag's mean delay); the start that fits the
fit samples best is calibrated, as ``candidate_grid`` for an effect (the stages commute, so the
second is taken as the faster). From a single start with the lag kept, the calibration can
stop at a worse fit than a dead time standing in for the stage (a 0.085 s stage behind a
0.6 s lag: held-out score 5.55 against the dead time's 5.30; from this grid, the lag
shortened, 4.91, the stage at 0.088 s)."""


BASE_GAIN = 0.5
"""Fraction of the held-out excess error a widened bound must remove to be accepted
(``try_base_change``) unless it is the round's best candidate (``_best_widening``); the other
base changes, terms or switches of the model's own form, are held to an effect's
``MIN_GAIN``."""


@dataclass(frozen=True)
class Candidate:
    """One candidate effect after its re-fit.

    Attributes
    ----------
    name : str
        Effect name (``sim.effects.EFFECTS``).
    fit : Fit
        The re-fitted configuration with the effect added.
    delta_bic : float
        BIC change against the configuration without it (negative: better).
    gain : float
        Fraction of the held-out excess error (above noise) removed.
    accepted : bool
        Whether it passed all three tests.
    own_gain : float
        Score of the re-fit with the effect removed again, minus that with it, as a fraction
        of the base's excess error, on the fit samples or the held-out blocks, whichever is
        larger: what the effect itself accounts for.
    joint : BaseChange or None
        The base change the effect was re-fitted with, if any (a widened bound,
        ``search``; the other braking law, ``BRAKING_PARTNERS``).
    """

    name: str
    fit: Fit
    delta_bic: float
    gain: float
    accepted: bool
    own_gain: float = math.nan
    joint: BaseChange | None = None

    @property
    def label(self) -> str:
        """The effect's name, with the base change it was re-fitted with, if any."""
        return f"{self.name} + {self.joint.label}" if self.joint else self.name


@dataclass(frozen=True)
class Round:
    """One search round.

    Attributes
    ----------
    before : Fit
        The calibrated model it starts from.
    candidates : tuple of Candidate
        Every candidate's result.
    chosen : str or None
        The candidate taken (an effect name or a base change's label), if any.
    finals : tuple of (str, float, float, float)
        The fully calibrated candidates the choice was between: name, held-out score,
        cross-validated score (``_cross_validated``; the held-out score when alone), BIC.
    chosen_with : str or None
        The label of the base change the chosen effect was re-fitted with
        (``Candidate.joint``), if any.
    pairs : tuple of Pair
        Effects fitted in pairs when none passed alone (``_paired``).
    """

    before: Fit
    candidates: tuple[Candidate, ...]
    chosen: str | None
    finals: tuple[tuple[str, float, float, float], ...] = ()
    chosen_with: str | None = None
    pairs: tuple[Pair, ...] = ()

    @property
    def rivals(self) -> tuple[tuple[str, float, float, float], ...]:
        """Finals not chosen whose cross-validated score is within ``SAME_CHOICE`` of the
        best: the data fit them about as well as the chosen one (``_tied``)."""
        return tuple(f for f in _tied(self.finals, lambda f: f[2]) if f[0] != self.chosen)


@dataclass(frozen=True)
class Pair:
    """Two effects fitted together when none passed alone (``_paired``).

    Attributes
    ----------
    lead, partner : str
        Effect names; the partner was re-fitted on the lead's re-fit.
    delta_bic : float
        BIC of the pair's re-fit minus the round's model's, on the fit samples.
    gain : float
        Fraction of the round's model's held-out excess the pair removes.
    score : float
        Held-out score of the pair's re-fit.
    accepted : bool
        Whether the pair passes (its lead is then accepted).
    """

    lead: str
    partner: str
    delta_bic: float
    gain: float
    score: float
    accepted: bool


@dataclass(frozen=True)
class Superfluous:
    """The superfluity test of one effect the start holds (``test_superfluous``).

    Attributes
    ----------
    name : str
        Effect name.
    start_params : dict of str to float
        Its parameters in the start configuration (what the start claims).
    fitted : dict of str to float
        Its parameters as the calibration fitted them freely.
    fitted_std : dict of str to float
        Their standard deviations.
    contradicted : bool
        Whether the fit puts every parameter more than ``CONTRADICTED`` standard deviations
        from the start's value, towards none, or at none (``AT_NONE``).
    score_with : float
        Held-out score of the model with it (fitted freely).
    without : Fit or None
        The model re-fitted without it (only if ``contradicted`` or tested as stuck,
        ``test_superfluous``).
    delta_bic : float
        BIC without it minus BIC with it (negative: it does not pay; nan if not re-fitted).
    superfluous : bool
        Whether it passed: contradicted (or tested as stuck), ``delta_bic < 0`` and a held-out
        score without it no higher than with it (within ``SAME_SCORE``) or, when
        contradicted, not enough to be named missing against the model without it
        (``_kept``), and the start's claim clearly worse than none (``score_claim``).
    score_claim : float
        Held-out score with the effect held at the start's values, the rest re-fitted (nan if
        not tried): more than ``SAME_CHOICE`` above the score without it, or removing it
        shrinks no gap.
    change : BaseChange or None
        The base change ``without`` holds in the effect's place (a second ESC stage for a
        dead time), if any.
    """

    name: str
    start_params: dict[str, float]
    fitted: dict[str, float]
    fitted_std: dict[str, float]
    contradicted: bool
    score_with: float
    without: Fit | None
    delta_bic: float
    superfluous: bool
    score_claim: float = math.nan
    change: BaseChange | None = None


@dataclass(frozen=True)
class Result:
    """Outcome of the whole workflow.

    Attributes
    ----------
    verdict : str
        One of ``VERDICTS``.
    start : Fit
        The calibrated starting configuration.
    final : Fit
        The calibrated final configuration (start plus the named effects).
    added : tuple of str
        Named missing effects, in the order found.
    rounds : tuple of Round
        Search rounds.
    warnings : tuple of str
        Non-fatal problems (e.g. a dropped effect the configuration lacks).
    base_changes : tuple of str
        Changes of the base model the search made (``base_changes``), one line each.
    superfluous : tuple of Superfluous
        The superfluity test of every effect of the start that was not named; those that
        passed are removed from ``final``.
    anchor : SimConfig or None
        The starting configuration (after ``--drop``), the anchor of the base bounds.
    ranges : dict of str to float
        Bound factors of base parameters widened by the search (others: ``BASE_RANGE``).
    replaced : tuple of (str, str)
        Named effects a later base change re-opened and a rival of their round replaced
        (``_revisit``): the effect and what took its place (an effect or a base change).
    """

    verdict: str
    start: Fit
    final: Fit
    added: tuple[str, ...]
    rounds: tuple[Round, ...]
    warnings: tuple[str, ...]
    base_changes: tuple[str, ...] = ()
    superfluous: tuple[Superfluous, ...] = ()
    anchor: SimConfig | None = None
    ranges: dict[str, float] = field(default_factory=dict)
    replaced: tuple[tuple[str, str], ...] = ()

    def report(self) -> dict:
        """The report.json mapping, exactly the keys of docs/contracts.md (strict JSON: a
        spread the data do not bound, infinite, is None)."""

        def spread(x: float) -> float | None:
            return x if math.isfinite(x) else None

        missing = []
        for name in self.added:
            effect = self.final.config.effect(name)
            params = effect.params() if effect is not None else {}
            missing.append(
                {
                    "name": name,
                    "params": params,
                    "uncertainty": {
                        p: spread(self.final.uncertainty(f"{name}.{p}")) for p in params
                    },
                }
            )
        superfluous = [
            {
                "name": sup.name,
                "params": sup.start_params,
                "uncertainty": {p: spread(x) for p, x in sup.fitted_std.items()},
            }
            for sup in self.superfluous
            if sup.superfluous
        ]
        return {
            "verdict": self.verdict,
            "missing_effects": missing,
            "superfluous_effects": superfluous,
            "gap_before": self.start.gap.public(),
            "gap_after": self.final.gap.public(),
        }


def start_config(source: SimConfig, drop: Sequence[str]) -> tuple[SimConfig, tuple[str, ...]]:
    """Remove ``drop`` from the starting configuration.

    Returns
    -------
    (SimConfig, tuple of str)
        The configuration and warnings (one per dropped effect it did not hold).

    Raises
    ------
    ValueError
        If a name is not in the effect vocabulary.
    """
    warnings = []
    config = source
    for name in drop:
        if name not in EFFECTS:
            raise BadInputError(f"unknown effect {name!r}; expected one of {', '.join(EFFECTS)}")
        if config.effect(name) is None:
            warnings.append(f"--drop {name}: configuration {config.name!r} has no such effect")
            continue
        config = replace(config, effects=tuple(e for e in config.effects if e.name != name))
    return config, tuple(warnings)


def candidate_grid(name: str, config: SimConfig, data: Measured) -> list[dict[str, float]]:
    """Initial values tried for effect ``name`` (plausible range, scaled to this thruster).

    The slew limit's grid is dense (20 rates, 20 % apart): a limit binds only while the duty
    moves faster than it, so the fit has a narrow valley below the duty's peak rate and a
    plateau above it (exact-base 1244, a 1.52 per s limit behind a 0.61 s lag, fit samples:
    1.2 per s scores 149, 1.4 31, 1.7 9.5, 2.0 26, 2.5 and above 34 as without it; from the
    old grid's best, 2.5, the calibration had nothing to follow and the limit went unnamed).
    The Coulomb torque's grid, scaled by the load torque at the trace's top speed, reaches 0.6
    of it: on a ``lowspeed`` trace that torque is small, and a hidden 0.016-0.021 N m torque
    was 0.2-0.5 of it; from the old grid's top (0.15) the re-fit beside a voltage sag stopped
    short (exact-base 1649: held-out 1.26, BIC -3323 behind the drive losses' -3325; with
    the grid to 0.6, 1.17 and -3374, and the torque was named).
    """
    p = config.params
    w_max = max(float(np.max(np.abs(data.rpm))) / RAD_S_TO_RPM, 1.0)
    torque = p.k_q * w_max * w_max
    i_max = float(np.max(data.current))
    grids: dict[str, tuple[str, list[float]]] = {
        "dead_time": ("delay_s", [0.05, 0.15, 0.3, 0.6, 1.0, 1.5]),
        "deadband": ("width", [0.01, 0.025, 0.045, 0.07, 0.1, 0.15]),
        "esc_lag": ("tau_s", [0.05, 0.15, 0.3, 0.6, 1.0, 2.0]),
        "slew_rate_limit": ("rate_per_s", [float(r) for r in np.geomspace(0.3, 10.0, 20)]),
        "coulomb_friction": (
            "torque_nm",
            [torque * f for f in (0.003, 0.01, 0.02, 0.04, 0.08, 0.15, 0.3, 0.6)],
        ),
        "viscous_friction": (
            "coeff",
            [torque / w_max * f for f in (0.01, 0.03, 0.06, 0.12, 0.25, 0.5)],
        ),
        "voltage_sag": ("r_internal_ohm", [0.01, 0.03, 0.06, 0.1, 0.2, 0.4]),
        "current_limit": ("i_max_a", [i_max * f for f in (0.5, 0.65, 0.8, 0.9, 0.97)]),
    }
    attr, values = grids[name]
    return [{attr: v} for v in values]


def _score_config(config: SimConfig, data: Measured) -> float:
    """Mean squared residual on the fit samples, noise units (inf if the simulation blows up)."""
    res = weighted_residuals(simulate_model(config, data), data)
    with np.errstate(over="ignore", invalid="ignore"):
        score = float(sum(np.mean(res[c][data.fit] ** 2) / data.sigma[c] ** 2 for c in CHANNELS))
    return score if math.isfinite(score) else math.inf


def try_candidate(
    name: str,
    base: Fit,
    data: Measured,
    origin: SimConfig | None = None,
    max_iter: int = CANDIDATE_ITER,
    anchor: SimConfig | None = None,
    ranges: Mapping[str, float] | None = None,
    change: BaseChange | None = None,
) -> Candidate:
    """Add effect ``name`` to ``base``, grid-initialise it, re-fit, and test it.

    The effect is added to ``base``'s calibrated configuration and, if given, to ``origin``
    (the uncalibrated starting configuration plus the effects named so far), each at the best
    of its ``candidate_grid`` values; both are re-fitted (every parameter free, ``max_iter``
    iterations) and the re-fit with the lower BIC is kept. The second origin matters: the
    calibrated base has distorted its parameters to make up for the missing effect, and from
    there the effect at its true value may fit worse than not binding at all (a slew limit
    above every duty step has no gradient to follow).

    Acceptance needs a BIC lower by ``BIC_EVIDENCE`` on the fit samples (penalising the added
    parameters) and a held-out gain of at least ``MIN_GAIN`` of the excess error (above
    noise), and the effect itself must account for at least ``MIN_GAIN`` of the excess on the
    fit samples or on the held-out blocks: removing it from the re-fit must cost that much
    there (so a candidate is not credited with a better fit of the other parameters). A
    re-fit that lowers the BIC (by any amount) and has the own gain but not the held-out gain
    is fitted on to a full calibration (``FULL_ITER``) and judged again.

    With ``change`` (a base change tried jointly with the effect, ``Candidate.joint``) both
    origins get the change first (a widened bound changes only the bounds, ``ranges``); the
    candidate is still judged against ``base``.
    """
    starts = []
    n_trials = 0
    for config in (base.config,) if origin is None else (base.config, origin):
        if change is not None:
            config = change.apply(config, data)
        grid = candidate_grid(name, config, data)
        trials = [set_effect(config, make_effect(name, g)) for g in grid]
        scores = [_score_config(c, data) for c in trials]
        starts.append(trials[int(np.argmin(scores))])
        n_trials += len(trials)
    # The anchor of the base parameters' bounds: the user's start (``origin`` holds its base
    # values).
    anchor = origin if anchor is None else anchor
    fits = [
        calibrate(start, data, max_iter=max_iter, anchor=anchor, ranges=ranges) for start in starts
    ]
    fit = min(fits, key=lambda f: f.bic)
    fit = replace(fit, n_sims=sum(f.n_sims for f in fits) + n_trials)
    delta_bic, gain, own_gain = _judge(name, fit, base, data)
    fit = replace(fit, n_sims=fit.n_sims + 3)
    if delta_bic < 0.0 and own_gain >= MIN_GAIN and gain < MIN_GAIN:
        # The effect carries the re-fit on the fit samples but the held-out error has not
        # followed yet: the short re-fit is unfinished, not the effect refuted (a 0.66 s dead
        # time behind a second-order ESC, t100 mismatch: held-out 47 after 6 iterations, 1.1
        # after 12). It is judged after a full calibration from there.
        more = calibrate(fit.config, data, anchor=anchor, ranges=ranges)
        delta_bic, gain, own_gain = _judge(name, more, base, data)
        fit = replace(more, n_sims=more.n_sims + fit.n_sims + 3)
    accepted = _passes(delta_bic, gain, MIN_GAIN) and own_gain >= MIN_GAIN
    return Candidate(
        name=name,
        fit=fit,
        delta_bic=delta_bic,
        gain=gain,
        accepted=accepted,
        own_gain=own_gain,
        joint=change,
    )


def _above_noise(fit: Fit) -> bool:
    """Whether ``fit``'s held-out score leaves an excess over the noise level (score 1) for a
    search round to explain."""
    return fit.gap.score > 1.0 + 1e-9


def _passes(delta_bic: float, gain: float, min_gain: float) -> bool:
    """The acceptance rule of a candidate: a BIC lower by ``BIC_EVIDENCE`` on the fit samples
    and a held-out gain of at least ``min_gain`` of the excess (an effect's own gain is
    checked beside it, ``try_candidate``)."""
    return delta_bic < -BIC_EVIDENCE and gain >= min_gain


def _excess(score: float) -> float:
    """Excess of ``score`` over the noise level (score 1), counted as at least
    ``RIGHT_SPREAD``."""
    return max(score - 1.0, RIGHT_SPREAD)


def _excess_gain(before: float, after: float) -> float:
    """Fraction of ``before``'s excess over the noise level (``_excess``) that a model scoring
    ``after`` removes."""
    return (before - after) / _excess(before)


def _judge(name: str, fit: Fit, base: Fit, data: Measured) -> tuple[float, float, float]:
    """BIC change of ``fit`` over ``base``, its held-out gain (fraction of ``base``'s excess
    error) and the gain effect ``name`` accounts for itself, on the fit samples or on the
    held-out blocks, whichever is larger."""
    delta_bic = fit.bic - base.bic  # both penalise all their parameters
    gain = _excess_gain(base.gap.score, fit.gap.score)
    # Ablation: the re-fitted model with the effect taken out again. The effect itself must
    # account for the gain, not the further re-fit of the other parameters that came with it.
    # An effect active in few places shows where it is active: a current limit binding for 2 s
    # of a 60 s trace may bind in none of the held-out blocks, and another mostly in them
    # (exact-base seed 1852: removing it from the re-fit costs 0.12 of the excess on the fit
    # samples and 1.05 on the held-out blocks, where the re-fit went from 23.9 to 0.72).
    ablated = simulate_model(without_effects(fit.config, (name,)), data)
    base_fit = gap(simulate_model(base.config, data), data, data.fit).score
    fit_score = gap(simulate_model(fit.config, data), data, data.fit).score
    own_fit = (gap(ablated, data, data.fit).score - fit_score) / _excess(base_fit)
    own_held = (gap(ablated, data).score - fit.gap.score) / _excess(base.gap.score)
    return delta_bic, gain, max(own_fit, own_held)


def _run_candidate(args: tuple) -> Candidate:
    what, base, data, origin, anchor, ranges = args
    if isinstance(what, BaseChange):
        return try_base_change(what, base, data, anchor, origin)
    if isinstance(what, tuple):
        name, change = what
        return try_candidate(name, base, data, origin, anchor=anchor, ranges=ranges, change=change)
    return try_candidate(what, base, data, origin, anchor=anchor, ranges=ranges)


def _recalibrate(
    config: SimConfig,
    origin: SimConfig,
    added: Sequence[str],
    chosen: Candidate,
    data: Measured,
    ranges: Mapping[str, float],
) -> Fit:
    """Full calibration with ``added`` and ``chosen`` effects, from the better of two origins.

    The origins: ``origin`` (the start's values, with the base changes made so far)
    plus the effects (the start's fit may have drifted to compensate for what was missing)
    and the candidate's re-fit; whichever fits better to begin with is calibrated, and the
    candidate's re-fit is kept if that does not improve its BIC. ``config`` is the anchor.
    """
    origins = (_start_with(origin, chosen.fit, (*added, chosen.name)), chosen.fit.config)
    best = min(origins, key=lambda c: _score_config(c, data))
    fit = calibrate(best, data, anchor=config, ranges=ranges)
    if fit.bic > chosen.fit.bic:
        fit = calibrate(chosen.fit.config, data, anchor=config, ranges=ranges)
    return fit


AT_BOUND = math.log(1.05)
"""A base parameter within 5 % of its bound counts as on it (the optimizer approaches a bound
it is pushed against, and may stop short: k_q at 0.979 of a factor 2 below the start)."""


def _at_bound(fit: Fit, anchor: SimConfig, ranges: Mapping[str, float]) -> list[str]:
    """Base parameters (``params.NAME`` of ``BASE_FIT``) of ``fit`` on their ``BASE_RANGE``
    bound (not yet widened)."""
    out = []
    for name in BASE_FIT:
        key = f"params.{name}"
        if key == "params.i_idle_a" or key in ranges:
            continue  # i_idle_a: linear from 0, its bounds are physical, not around the start
        ratio = abs(math.log(getattr(fit.config.params, name) / getattr(anchor.params, name)))
        if ratio >= math.log(BASE_RANGE) - AT_BOUND:
            out.append(key)
    return out


@dataclass(frozen=True)
class BaseChange:
    """A change of the base model, tried beside the effects in a search round.

    Attributes
    ----------
    label : str
        What it changes (``base: ...``).
    ranges : dict of str to float
        Bound factors of base parameters with the change.
    regen : bool or None
        The braking law it switches to (None: unchanged).
    second_stage : bool
        Whether it adds a second ESC stage (``starts``: ``SECOND_STAGE`` times the
        ``esc_lag``).
    no_drive_saturation : bool
        Whether it removes the start's ESC drive saturation (``esc_v_sat_v`` to inf).
    drive_losses : tuple of str
        The ``fit.DRIVE_LOSSES`` terms it frees (by their keys in ``ranges``).
    widened : bool
        Whether it widens the bounds of base parameters found on them (``base_changes``).
    """

    label: str
    ranges: dict[str, float]
    regen: bool | None = None
    second_stage: bool = False
    no_drive_saturation: bool = False
    drive_losses: tuple[str, ...] = ()
    widened: bool = False

    @property
    def min_gain(self) -> float:
        """Fraction of the held-out excess it must remove to be accepted
        (``try_base_change``): ``BASE_GAIN`` for a widened bound (``MIN_GAIN`` when it is the
        round's best candidate, ``_best_widening``), an effect's ``MIN_GAIN`` for the rest,
        terms or switches of the model's own form."""
        return BASE_GAIN if self.widened else MIN_GAIN

    def starts(self, config: SimConfig) -> list[SimConfig]:
        """``config`` with the change (its bounds aside), once per starting value of what it
        adds (the ``SECOND_STAGE`` grid; one otherwise)."""
        structure = config.structure
        if self.regen is not None:
            structure = replace(structure, regen=self.regen)
        params = config.params
        if self.no_drive_saturation:
            params = replace(params, esc_v_sat_v=math.inf)
        changed = replace(config, params=params, structure=structure)
        lag = config.effect("esc_lag")
        if not self.second_stage or lag is None:
            return [changed]
        # The cascade's mean delay, tau1 + tau2, is kept at the calibrated lag's: the slow
        # response the first stage was fitted to stays.
        return [
            set_effect(
                replace(changed, structure=replace(structure, esc_tau2_s=f * lag.tau_s)),
                make_effect("esc_lag", {"tau_s": (1.0 - f) * lag.tau_s}),
            )
            for f in SECOND_STAGE
        ]

    def apply(self, config: SimConfig, data: Measured) -> SimConfig:
        """``config`` with the change, from the start that fits ``data`` best."""
        return _best_start(self.starts(config), data)


def _adopt(
    change: BaseChange, origin: SimConfig, data: Measured, before: Fit, after: Fit, note: str
) -> tuple[dict[str, float], SimConfig, str]:
    """Take base change ``change``: its bounds, ``origin`` with it, and the line of
    ``Result.changed`` (held-out score ``before`` -> ``after``, then ``note``)."""
    line = (
        f"{change.label.removeprefix('base: ')} (held-out score {before.gap.score:.2f} -> "
        f"{after.gap.score:.2f}{note})"
    )
    return change.ranges, change.apply(origin, data), line


def _best_start(starts: Sequence[SimConfig], data: Measured) -> SimConfig:
    """The one of ``starts`` that fits the fit samples best (a single one is not simulated)."""
    if len(starts) == 1:
        return starts[0]
    return min(starts, key=lambda c: _score_config(c, data))


def base_changes(current: Fit, config: SimConfig, ranges: Mapping[str, float]) -> list[BaseChange]:
    """Base changes a round may try, each once: base parameters the calibration left on their
    ``BASE_RANGE`` bound re-fitted within ``WIDE_RANGE`` (a thruster of the same class outside
    the usual range: another propeller, wiring, rotor), a second ESC stage behind the
    ``esc_lag`` (a second-order ESC), the other braking law (coasting instead of
    regeneration, or the reverse), a switch least squares cannot fit, and, where the start has
    an ESC drive saturation, none: a structural term the start has is kept by the calibration
    (``fit.STRUCTURE_FIT``), so a thruster without it was otherwise fitted with stand-ins (a
    deadband on t200 mismatch cases whose drive saturation was switched off); and the drive
    losses the start lacks (``fit.DRIVE_LOSSES``: drive saturation, speed-dependent winding
    loss, idle current growing with speed), fitted from then on; where the start has a winding
    loss, that loss re-fitted within ``WIDE_RANGE``."""
    out = []
    edge = _at_bound(current, config, ranges)
    if edge:
        names = ", ".join(k.split(".")[1] for k in edge)
        wide = {**ranges, **dict.fromkeys(edge, WIDE_RANGE)}
        out.append(BaseChange(f"base: {names} within x{WIDE_RANGE:g}", wide, widened=True))
    structure = current.config.structure
    if (
        current.config.effect("esc_lag") is not None
        and config.structure.esc_tau2_s == 0.0
        and structure.esc_tau2_s == 0.0
    ):
        out.append(BaseChange("base: second ESC stage", dict(ranges), second_stage=True))
    if structure.regen == config.structure.regen:
        regen = not config.structure.regen
        label = "base: regenerative braking" if regen else "base: coasting, no regeneration"
        # A switch of the model's own form with no parameter: accepted like an effect (t200
        # mismatch null trace 919, a coasting thruster: coasting removed 50 % of the excess,
        # under BASE_GAIN, and a dead time was named in the same round at 17 %).
        out.append(BaseChange(label, dict(ranges), regen=regen))
    if math.isfinite(config.params.esc_v_sat_v) and math.isfinite(
        current.config.params.esc_v_sat_v
    ):
        # Removing a term of the model's own form: accepted like an effect (t200 mismatch null
        # traces whose thruster lacks the drive saturation: removing it gained 0.43-0.48 after a
        # deadband had stood in for it, and the deadband was named).
        out.append(BaseChange("base: no drive saturation", dict(ranges), no_drive_saturation=True))
    absent = lacking_drive_losses(config)
    winding = "params.r_speed_ohm_s"
    if winding not in ranges and winding not in absent:
        # A term the start has is kept by the calibration; re-fitted here, like the drive
        # losses, by an effect's rule (t200 mismatch seed 586: the start's winding loss 1.7
        # times the thruster's, r_ohm on its bound and a 0.038 deadband named in its place at
        # held-out 5.4; re-fitted, 1.00 and the deadband fits to nothing).
        out.append(
            BaseChange(
                f"base: r_speed_ohm_s within x{WIDE_RANGE:g}", {**ranges, winding: WIDE_RANGE}
            )
        )
    lacking = tuple(k for k in absent if k not in ranges)
    if lacking:
        names = ", ".join(k.split(".")[1] for k in lacking)
        free = {**ranges, **dict.fromkeys(lacking, math.inf)}
        # Terms of the model's own form: accepted like an effect (``try_base_change``).
        out.append(BaseChange(f"base: drive losses ({names})", free, drive_losses=lacking))
    return out


def try_base_change(
    change: BaseChange, base: Fit, data: Measured, config: SimConfig, named: SimConfig
) -> Candidate:
    """Re-fit ``base`` with ``change``, from two origins like ``try_candidate``: the current
    model and ``named`` (the uncalibrated start plus the effects named so far), each with the
    change; the lower BIC is kept. Accepted on a BIC lower by ``BIC_EVIDENCE`` and a held-out
    gain of at least the change's ``min_gain``: ``BASE_GAIN`` (stricter than an effect's
    ``MIN_GAIN``: a parameter that leaves its range to explain only part of the gap is more
    likely making up for something else; on the T200 bench trace ``r_ohm`` would go to a
    quarter of the preset's, remove 27 % of the excess and leave the deadband 21 % small;
    the search lowers it to ``MIN_GAIN`` for a widening that is the round's best candidate,
    ``_best_widening``); the drive losses, terms of the model's own form, by an effect's
    rules (``MIN_GAIN``: held to ``BASE_GAIN``, a drive loss removing 49 % lost to a viscous
    friction standing in for it with 42 %), and so are a second ESC stage, the removal of the
    start's drive saturation, the re-fit of its winding loss and the other braking law."""
    # Full calibrations (FULL_ITER, not CANDIDATE_ITER): a base change re-shapes the whole
    # model, and from a model distorted by a parameter on its bound 6 iterations fall short
    # (an out-of-range k_q and a hidden dead time: 6 remove 43 % of the excess, 12 most of it).
    starts = [change.starts(c) for c in (base.config, named)]
    fits = [
        calibrate(_best_start(s, data), data, anchor=config, ranges=change.ranges) for s in starts
    ]
    fit = min(fits, key=lambda f: f.bic)
    scored = sum(len(s) for s in starts if len(s) > 1)
    fit = replace(fit, n_sims=sum(f.n_sims for f in fits) + scored)
    delta_bic = fit.bic - base.bic
    gain = _excess_gain(base.gap.score, fit.gap.score)
    accepted = _passes(delta_bic, gain, change.min_gain)
    return Candidate(change.label, fit, delta_bic, gain, accepted, gain)


def _best_widening(results: list[Candidate], widen: BaseChange | None) -> list[Candidate]:
    """``results`` with the widened bound ``widen`` accepted by an effect's rules when its
    held-out score is the round's best or within ``SAME_CHOICE`` of it: ``BASE_GAIN`` holds a
    widening back where it removes only part of the excess while another candidate removes
    more (on the T200 bench trace ``r_ohm`` widened removes 23 % in the round where the start's
    winding loss re-fitted removes 62 % and the deadband 45 %, and nothing once they are
    taken), not where it is as good an explanation as the round has (t200 mismatch null trace
    1017, ``k_q`` 2.77 times the start's: widened, 39 %, the round's best; a viscous torque was
    named in its place at 25 %. t200 mismatch 631, inertia 2.45 times the start's, a hidden
    dead time: after the dead time the inertia widened 1.36, a deadband 1.33, and the deadband
    was named; as a final the widening is cross-validated at 1.31 against the deadband's 1.34,
    taken, and nothing more is named)."""
    if widen is None:
        return results
    tied = _tied(results, lambda c: c.fit.gap.score)
    top = next((c for c in tied if c.name == widen.label), None)
    if top is None or top.accepted:
        return results
    passes = _passes(top.delta_bic, top.gain, MIN_GAIN)
    return [replace(c, accepted=passes) if c is top else c for c in results]


BRAKING_PARTNERS = ("coulomb_friction",)
"""Effects also tried jointly with the other braking law (``_with_braking``): a coasting
rotor's spin-down is its drag and a Coulomb torque, which stops it in finite time. A coasting
rotor with a Coulomb torque was fitted worse by coasting alone (nothing but drag stops it)
and by the torque alone (the regenerative braking the model has does part of the torque's
work), so neither was taken (t100 mismatch 835, a hidden Coulomb torque and slew limit on a
coasting thruster: in the first round coasting alone held-out 15.5, the torque alone 7.3,
the two together 5.5; without the joint re-fit a deadband was named and the search ended
at 1.43, with it at 1.17). Not the viscous torque: a viscous drag adds to the propeller's,
and paired with coasting it took the place of the idle current growing with speed that it
already stands in for (t100 mismatch 715: a viscous torque with coasting cross-validated
1.23 against the drive losses' 1.30 and was named beside the hidden Coulomb torque)."""


def _with_braking(results: list[Candidate], braking: BaseChange | None) -> list[Candidate]:
    """``results`` with each effect re-fitted jointly with the other braking law ``braking``
    accepted only if, besides an effect's rules against the current model, the braking law
    alone lowers the BIC by ``BIC_EVIDENCE`` (the fit samples prefer it of their own, though
    its held-out gain may be negative while the friction is missing) and the joint re-fit
    removes ``MIN_GAIN`` of the held-out excess that the effect alone and the braking law
    alone leave: each part must earn its place beside the other. Without the braking law's
    own evidence coasting stood in for other slow decelerations (t100 mismatch 836, a
    regenerating thruster with a hidden Coulomb torque and slew limit: coasting alone raised
    the BIC by 1694; with the torque it was 18 % better than the torque alone, taken before
    the slew limit, and a viscous torque was named after it)."""
    if braking is None:
        return results
    alone = {c.name: c for c in results if c.joint is None}
    switch = alone[braking.label]
    out = []
    for c in results:
        if c.joint is braking and c.accepted:
            parts = (alone[c.name], switch)
            gains = all(_excess_gain(p.fit.gap.score, c.fit.gap.score) >= MIN_GAIN for p in parts)
            c = replace(c, accepted=gains and switch.delta_bic < -BIC_EVIDENCE)
        out.append(c)
    return out


PAIR_TOP = 3
"""Effects, by the BIC they lower, paired when none passes alone (``_paired``)."""


def _paired(
    results: list[Candidate],
    current: Fit,
    data: Measured,
    origin: SimConfig,
    added: Sequence[str],
    anchor: SimConfig,
    ranges: Mapping[str, float],
    workers: int,
    progress: bool,
    say: Callable[[str], None],
) -> tuple[list[Candidate], tuple[Pair, ...]]:
    """``results`` with one effect accepted that passes only together with another, when none
    passes alone, and the pairs fitted.

    Of the ``PAIR_TOP`` effects that lower the BIC most (each by ``BIC_EVIDENCE``), each pair
    is fitted: the partner re-fitted on the re-fit of the effect that alone leaves less
    held-out error (the lead; ``origin`` is the uncalibrated start with the effects
    ``added``). A pair passes by an effect's rules against ``current`` and if each part
    removes ``MIN_GAIN`` of the held-out excess the other alone leaves and accounts for
    ``MIN_GAIN`` of the excess on the fit samples. The lead of the best pair that passes is
    accepted; the next round finds its partner by the usual rules. Two effects can each make
    the held-out error worse alone (exact-base 267, a hidden 0.78 s ESC lag and a deadband on
    a 60 s trace, after coasting was adopted as a stand-in: the lag alone 5.2 -> 40.8, the
    deadband alone 120, the two together 1.05).
    """
    singles = sorted(
        (
            c
            for c in results
            if c.joint is None and c.name in EFFECTS and c.delta_bic < -BIC_EVIDENCE
        ),
        key=lambda c: c.delta_bic,
    )[:PAIR_TOP]
    pairs = [
        sorted(pair, key=lambda c: c.fit.gap.score) for pair in itertools.combinations(singles, 2)
    ]
    if not pairs:
        return results, ()
    jobs = [
        (b.name, a.fit, data, _start_with(origin, a.fit, (*added, a.name)), anchor, ranges)
        for a, b in pairs
    ]
    fitted = []
    for (a, b), c in zip(
        pairs, _run_jobs(jobs, workers, progress, "pairs of effects"), strict=True
    ):
        delta_bic, gain, _ = _judge(b.name, c.fit, current, data)
        own_lead = _judge(a.name, c.fit, current, data)[2]
        lead_earns = _excess_gain(b.fit.gap.score, c.fit.gap.score) >= MIN_GAIN
        passes = (
            c.accepted
            and lead_earns
            and own_lead >= MIN_GAIN
            and _passes(delta_bic, gain, MIN_GAIN)
        )
        fitted.append(Pair(a.name, b.name, delta_bic, gain, c.fit.gap.score, passes))
        say(
            f"  {a.name} + {b.name:17s} dBIC {delta_bic:12.1f} gain {gain:6.2f} "
            f"held-out score {c.fit.gap.score:9.2f}{'  accepted' if passes else ''}"
        )
    best = min((p for p in fitted if p.accepted), key=lambda p: p.score, default=None)
    if best is None:
        return results, tuple(fitted)
    lead = next(a for a, _ in pairs if a.name == best.lead)
    return [replace(c, accepted=True) if c is lead else c for c in results], tuple(fitted)


T = TypeVar("T")


SAME_CHOICE = 0.05
"""Relative tolerance of cross-validated scores within which ``_choose`` decides by BIC (and
a round's other candidates count as ``Round.rivals``: the data fit them about as well)."""


SAME_SCORE = 0.01
"""Relative tolerance within which two held-out scores count as the same (re-fits of equal
models land that close)."""


CONTRADICTED = 3.0
"""Standard deviations between the start's value of an effect and the fitted one, towards
none, for the start's value to count as contradicted by the data (``test_superfluous``)."""


AT_NONE = 1e-3
"""Distance of a fitted parameter from its value of none, as a fraction of the start's, within
which the fit has moved it all the way to none: the start's value counts as contradicted
whatever its spread (``test_superfluous``)."""


NEUTRAL: dict[str, float] = {
    "dead_time": 0.0,
    "deadband": 0.0,
    "esc_lag": 0.0,
    "slew_rate_limit": math.inf,
    "coulomb_friction": 0.0,
    "viscous_friction": 0.0,
    "voltage_sag": 0.0,
    "current_limit": math.inf,
}
"""The parameter value at which each effect does nothing (its direction of 'none')."""


def test_superfluous(
    name: str,
    final: Fit,
    config: SimConfig,
    data: Measured,
    ranges: Mapping[str, float],
    named: SimConfig,
    *,
    stuck: bool,
) -> Superfluous:
    """Whether effect ``name`` of the start is one the thruster lacks.

    Superfluous when (1) the calibration, fitting the effect freely, moved every parameter more
    than ``CONTRADICTED`` standard deviations from the start's value towards none, or all the
    way to none (within ``AT_NONE``; the data contradict the start's claim, not merely fail to
    confirm it: a current limit that never binds, a friction torque under the noise, stay),
    or ``stuck`` (``search`` asks when the model still holds structure and no effect is
    superfluous: a calibration may be stuck with the effect, and then its spread says
    nothing), (2) the model re-fitted without it is no worse: a lower BIC and a held-out score
    no higher than with it (within ``SAME_SCORE``), or, once contradicted, what is left of the
    effect would not be named if the model lacked it (``_kept``: an effect's rules, and none
    is named at the noise level; a short re-fit that keeps it is repeated in full from two
    origins), and (3) removing it shrinks the gap against the start's claim:
    held at the start's values, the rest re-fitted, the held-out score is more than
    ``SAME_CHOICE`` above that without it.

    A contradicted dead time is removed also with a second ESC stage in its place (when the
    search offers one, ``base_changes``); that re-fit is the model without it when the stage
    passes a base change's rules against the plain removal: a short delay is what a
    second-order ESC looks like to a model with one stage (t200 mismatch 672, a 0.14 s second
    stage: the start's 0.55 s dead time fitted to 0.059 s, and without it the held-out score
    11.1 against 1.8), and offered beside the dead time the stage gains next to nothing. The
    stage is then ``Superfluous.change``, fitted like any base change (``try_base_change``)
    from the model without the dead time and from ``named`` (the uncalibrated start with the
    search's base changes and named effects) without it. Any other contradicted effect that
    the model without it would keep is removed also with each base change the search offers
    on that model in its place; of those that pass a base change's rules against the plain
    removal, the one ``_choose`` takes on held-out scores (the lowest BIC within
    ``SAME_CHOICE`` of the best) is then the model without it, and its change
    ``Superfluous.change``.
    """
    claimed = config.effect(name).params()
    effect = final.config.effect(name)
    fitted = effect.params()
    std = {p: final.uncertainty(f"{name}.{p}") for p in claimed}
    neutral = NEUTRAL[name]
    # At none a delay, a band or a limit has no slope (a 7 A current limit the thruster lacks
    # fitted to 10.27 A, above every current of the trace: std inf), so there its spread says
    # nothing and the move itself decides.
    contradicted = all(
        abs(fitted[p] - neutral) <= AT_NONE * abs(claimed[p] - neutral)
        or (
            math.isfinite(std[p])
            and (fitted[p] - claimed[p]) * (neutral - claimed[p]) > 0.0
            and abs(fitted[p] - claimed[p]) > CONTRADICTED * std[p]
        )
        for p in claimed
    )
    if not contradicted and not stuck:
        return Superfluous(
            name, claimed, fitted, std, False, final.gap.score, None, math.nan, False
        )
    lean = without_effects(final.config, (name,))
    without = calibrate(lean, data, max_iter=CANDIDATE_ITER, anchor=config, ranges=ranges)
    lean_start = without_effects(named, (name,))
    change = None
    if contradicted and name == "dead_time":
        stage = next((c for c in base_changes(without, config, ranges) if c.second_stage), None)
        if stage is not None:
            staged = try_base_change(stage, without, data, config, lean_start)
            if staged.accepted:
                without = replace(staged.fit, n_sims=staged.fit.n_sims + without.n_sims)
                change = stage
    if contradicted and change is None:
        # The short re-fit from the model around the effect may stop short: re-fitted in full
        # from two origins, as ``drop_superfluous`` does (t200 mismatch 741: a 0.014 deadband,
        # held-out 0.87; without it 1.02 after the short re-fit, 0.98 in full).
        if _left_in(final, without):
            full = _without_in_full((name,), final.config, named, config, data, ranges)
            if full.bic < without.bic:
                without = replace(full, n_sims=full.n_sims + without.n_sims)
        # What the effect stood in for may be a base change the search never offered while
        # the effect was there (t200 mismatch 20: a 0.0035 deadband the thruster lacks,
        # held-out 0.96, kept against its plain removal; with the winding loss re-fitted
        # within x4 in its place, 0.93).
        if _left_in(final, without):
            offered = {c.label: c for c in base_changes(without, config, ranges)}
            tried = [
                try_base_change(c, without, data, config, lean_start) for c in offered.values()
            ]
            chosen, best = _choose([(t, t.fit, t.fit.gap.score) for t in tried if t.accepted])
            if best is not None and not _kept(final, best, contradicted=True):
                without = replace(best, n_sims=without.n_sims + sum(t.fit.n_sims for t in tried))
                change = offered[chosen.name]
    delta_bic = without.bic - final.bic
    ok = not _kept(final, without, contradicted=contradicted)
    score_claim = math.nan
    if ok:
        # Removing it must shrink the gap against what the start claims: the effect held at
        # its start values, everything else re-fitted, must score clearly worse than none (on
        # an exact-base null trace on the low-current signal, the unit's 14 A current limit,
        # never reached, sits where it does nothing: held at 14 A, the same score).
        claim = set_effect(final.config, config.effect(name))
        keys = [k for k in free_parameters(claim, config, ranges) if not k.startswith(f"{name}.")]
        held = calibrate(claim, data, keys, max_iter=CANDIDATE_ITER, anchor=config, ranges=ranges)
        score_claim = held.gap.score
        ok = score_claim > without.gap.score * (1.0 + SAME_CHOICE)
    return Superfluous(
        name, claimed, fitted, std, contradicted, final.gap.score, without, delta_bic, ok,
        score_claim, change,
    )  # fmt: skip


def _kept(final: Fit, without: Fit, *, contradicted: bool) -> bool:
    """Whether a start effect stays in ``final`` against ``without``, the model re-fitted
    without it (``test_superfluous``, step 2): unless ``without`` has a lower BIC and a
    held-out score no higher (within ``SAME_SCORE``), and, once the data contradict the
    start's claim, only if what the calibration kept of the effect would be named missing
    against ``without`` (t100 mismatch 730, no deadband: the start's 0.0625 fitted to 0.012 +-
    0.001, lowering the BIC by 291 and the held-out score by 0.005, a thruster whose coarse
    speed sensor blurs its slow region): an effect's rules (``_passes``), and no round begins
    at the noise level (t200 mismatch 738: a 0.013 deadband held-out 0.92, without it 0.97 and
    0.86 in full, standing in for the drive saturation the thruster lacks: better current at
    high commands, worse speed at small ones)."""
    if without.bic < final.bic and without.gap.score <= final.gap.score * (1.0 + SAME_SCORE):
        return False
    if not contradicted:
        return True
    gain = _excess_gain(without.gap.score, final.gap.score)
    return _above_noise(without) and _passes(final.bic - without.bic, gain, MIN_GAIN)


def _left_in(final: Fit, without: Fit) -> bool:
    """Whether a contradicted start effect stays in ``final`` against ``without``, the model
    re-fitted without it (``_kept``), while ``without`` holds no structure (held-out score up
    to ``STRUCTURED``): then another re-fit without it is worth trying (``test_superfluous``);
    a model without it that far off says the effect is doing work (a lag the thruster has:
    11-140)."""
    return without.gap.score <= STRUCTURED and _kept(final, without, contradicted=True)


def _one_at_a_time(
    tests: Sequence[Superfluous],
    config: SimConfig,
    data: Measured,
    ranges: Mapping[str, float],
    named: SimConfig,
) -> tuple[Superfluous, ...]:
    """``tests`` with superfluous effects taken one at a time: of two or more, the one whose
    removal leaves the lowest held-out score, and the others tested again in the model
    without it (``test_superfluous``; its ``without`` is then the model without both). Each
    was tested in a model holding the others, where one may do the other's work: t200
    mismatch 631, a 0.55 s dead time the thruster lacks fitted to 0.50 s beside its 0.1 s lag
    fitted to none; removed together, held-out 13.9, the dead time alone (a second ESC stage
    in its place) 1.39."""
    out = {t.name: t for t in tests}
    taken: list[str] = []
    pending = [t for t in tests if t.superfluous]
    while pending:
        first = min(pending, key=lambda t: t.without.gap.score)
        taken.append(first.name)
        lean = without_effects(named, taken)
        pending = [
            test_superfluous(t.name, first.without, config, data, ranges, lean, stuck=False)
            for t in pending
            if t is not first
        ]
        out.update((t.name, t) for t in pending)
        pending = [t for t in pending if t.superfluous]
    return tuple(out.values())


def _retest(
    current: Fit,
    names: Sequence[str],
    config: SimConfig,
    data: Measured,
    ranges: Mapping[str, float],
    say: Callable[[str], None],
    held_out: bool = True,
) -> tuple[Fit, list[str]]:
    """Re-test effects named before a base change or another effect by ablation: each is
    removed and the model fully re-calibrated; it stays if it still lowers the BIC (by any
    amount; adding it needed ``BIC_EVIDENCE``) and, with ``held_out`` (after a base change),
    removes ``MIN_GAIN`` of the excess held-out error of the model without it. Returns the
    model and the effects dropped (a Coulomb friction named on a t100 mismatch trace before
    the drive losses were adopted explained nothing once they were: held-out score 1.11
    either way).

    After an effect the BIC alone decides: the new effect may explain what an earlier one
    stood in for (t200 mismatch 630, a hidden viscous torque: a Coulomb torque named at 1.35,
    the viscous torque after it at 0.96; without the Coulomb torque the BIC is lower by 84),
    while three held-out blocks of a short trace move too much to drop an effect the fit
    still wants (exact-base 1241, a Coulomb torque beside a sag: without the torque, named
    first, held-out 1.19 against 1.31, but the BIC higher by 217)."""
    gone: list[str] = []
    for name in names:
        without = calibrate(
            without_effects(current.config, (name,)), data, anchor=config, ranges=ranges
        )
        gain = _excess_gain(without.gap.score, current.gap.score)
        keep = without.bic > current.bic and (gain >= MIN_GAIN or not held_out)
        say(
            f"  re-test {name}: without it dBIC {without.bic - current.bic:.1f}, held-out score "
            f"{without.gap.score:.2f} (its gain {gain:.2f}){'' if keep else '  dropped'}"
        )
        if not keep:
            gone.append(name)
            current = replace(without, n_sims=without.n_sims + current.n_sims)
    return current, gone


def _fold_fit(args: tuple) -> Fit:
    """``calibrate`` on one cross-validation fold (a job of ``_run_jobs``)."""
    config, data, blocks, anchor, ranges = args
    return calibrate(config, with_held(data, blocks), anchor=anchor, ranges=ranges)


def _cross_validated(fits: Sequence[Fit]) -> float:
    """Held-out score over the ``FOLDS`` from the re-fits on each (``_fold_fit``): the median
    of the folds' scores. Not the mean: a fold whose held-out blocks hold what the rest of the
    trace hardly excites scores far off for every model and would decide it (exact-base seed
    666, a Coulomb torque beside a sag: one fold 4.6-10.2, the other four 0.8-1.9; the torque
    best on those four and the mean taking a viscous torque)."""
    return float(np.median([f.gap.score for f in fits]))


def _start_with(origin: SimConfig, current: Fit, added: Sequence[str]) -> SimConfig:
    """The uncalibrated start ``origin`` with the named effects ``added`` as ``current`` has
    them: the second origin a re-fit starts from besides ``current`` itself."""
    named = origin
    for name in added:
        named = set_effect(named, current.config.effect(name))
    return named


def _without_in_full(
    names: Collection[str],
    model: SimConfig,
    named: SimConfig,
    config: SimConfig,
    data: Measured,
    ranges: Mapping[str, float],
) -> Fit:
    """``model`` without the effects ``names``, fully calibrated from ``model`` and from
    ``named`` (the uncalibrated start with the base changes and the named effects), the lower
    BIC kept: a base fitted around an effect may not find its way back without it
    (``drop_superfluous``)."""
    return min(
        (
            calibrate(without_effects(c, names), data, anchor=config, ranges=ranges)
            for c in (model, named)
        ),
        key=lambda f: f.bic,
    )


def drop_superfluous(
    current: Fit,
    names: Collection[str],
    added: Sequence[str],
    origin: SimConfig,
    config: SimConfig,
    data: Measured,
    ranges: Mapping[str, float],
    say: Callable[[str], None],
) -> tuple[Fit, list[str]]:
    """The model without the start's effects ``names``, and the named effects (``added``)
    that no longer earn their place without them.

    Calibrated from the current model and, as a candidate is, from the uncalibrated start
    (``origin``, with any base change) plus the named effects; the lower BIC is kept: a base
    fitted around a superfluous 0.55 s dead time did not find its way back without it (t200
    mismatch trace 631: held-out 9.9 from the current model, 1.6 from the start). The named
    effects are then re-tested like after a base change (``_retest``): named while the start
    still held the superfluous effect, one may have stood in for it (631: a slew limit).
    """
    named = _start_with(origin, current, added)
    current = _without_in_full(names, current.config, named, config, data, ranges)
    say(f"dropped {', '.join(sorted(names))}: held-out score {current.gap.score:.2f}")
    return _retest(current, added, config, data, ranges, say) if added else (current, [])


def _score_finals(
    finals: Sequence[tuple[Candidate, Fit, Mapping[str, float]]],
    data: Measured,
    config: SimConfig,
    workers: int,
    progress: bool,
) -> tuple[list[tuple[Candidate, Fit, float]], int]:
    """``finals`` (candidate, full calibration, its bounds) with their cross-validated scores
    (``_cross_validated``; a single final keeps its held-out score), and the simulations the
    folds took. ``config`` is the anchor."""
    scores = [full.gap.score for _c, full, _wide in finals]
    n_folds = 0
    if len(finals) > 1:
        jobs = [
            (full.config, data, blocks, config, wide)
            for _c, full, wide in finals
            for blocks in FOLDS
        ]
        folds = _run_jobs(jobs, workers, progress, "cross-validation", _fold_fit, "fit")
        k = len(FOLDS)
        scores = [_cross_validated(folds[i * k : (i + 1) * k]) for i in range(len(finals))]
        n_folds = sum(f.n_sims for f in folds)
    return [(c, full, cv) for (c, full, _wide), cv in zip(finals, scores, strict=True)], n_folds


def _revisit(
    name: str,
    passed: Sequence[str],
    current: Fit,
    origin: SimConfig,
    added: Sequence[str],
    config: SimConfig,
    data: Measured,
    ranges: Mapping[str, float],
    workers: int,
    progress: bool,
    say: Callable[[str], None],
) -> tuple[str, Fit, BaseChange | None] | None:
    """The choice of the round that named effect ``name`` made again after a base change:
    between the current model and, in its place, each accepted candidate it was chosen over
    (``passed``, effects or base changes still on offer), by the round's rules (accepted
    against the model without it, then ``_choose``). A rival base change taken since is no
    longer one.
    Returns the rival taken (its name, calibration and base change, None for an effect), or
    None if ``name`` stays.

    The round chose on the base of its time: on a thruster with a second-order ESC and a
    coasting rotor a dead time can be named over the second stage while the model still
    regenerates; once coasting is adopted the dead time still pays against nothing, but the
    stage in its place fits better (t100 mismatch 912 likewise: a Coulomb torque named
    first, a viscous torque in its place once the second stage and ``k_q`` are widened).
    A rival must cross-validate at least as well as ``name`` (a widening or second stage
    excepted, as in ``_choose``): the round already broke the tie by the BIC, and breaking it
    again on another base flips on noise (t100 mismatch 715, a hidden Coulomb torque and slew
    limit: once the drive losses were adopted the torque cross-validated 1.30, a deadband in
    its place 1.33 with a lower BIC, and the deadband was named).
    """
    rest = [n for n in added if n != name]
    lean = calibrate(without_effects(current.config, (name,)), data, anchor=config, ranges=ranges)
    named = _start_with(origin, lean, rest)
    offered = {ch.label: ch for ch in base_changes(lean, config, ranges)}
    finals: list[tuple[Candidate, Fit, Mapping[str, float]]] = [
        (Candidate(name, current, 0.0, 0.0, True), current, ranges)
    ]
    for rival in passed:
        if rival in offered:
            c = try_base_change(offered[rival], lean, data, config, named)
            full, wide = c.fit, offered[rival].ranges
        elif rival in EFFECTS and lean.config.effect(rival) is None:
            c = try_candidate(rival, lean, data, named, anchor=config, ranges=ranges)
            full = _recalibrate(config, origin, rest, c, data, ranges) if c.accepted else c.fit
            wide = ranges
        else:
            continue
        say(f"  revisit {name}: {rival} in its place, held-out score {full.gap.score:.2f}")
        if c.accepted:
            finals.append((c, full, wide))
    if len(finals) == 1:
        return None
    scored, n_folds = _score_finals(finals, data, config, workers, progress)
    first = _first(offered.values())
    held = scored[0][2]  # the named effect's: ``finals`` begins with it
    chosen, best = _choose([s for s in scored if s[2] <= held or s[0].name in first], first)
    if chosen is None or best is None:
        return None
    scores = ", ".join(f"{c.name} cross-validated {cv:.2f}" for c, _f, cv in scored)
    say(f"  revisit {name}: {scores}; {chosen.name}")
    if chosen.name == name:
        return None
    return chosen.name, replace(best, n_sims=best.n_sims + n_folds), offered.get(chosen.name)


def _choices_again(
    names: Sequence[str],
    passed_over: Mapping[str, Sequence[str]],
    current: Fit,
    origin: SimConfig,
    ranges: Mapping[str, float],
    added: Sequence[str],
    config: SimConfig,
    data: Measured,
    workers: int,
    progress: bool,
    say: Callable[[str], None],
) -> tuple[Fit, SimConfig, dict[str, float], list[str], list[tuple[str, str]], list[str]]:
    """Each named effect of ``names`` still in ``added`` whose round passed over rivals
    (``passed_over``) faces them again on the current base (``_revisit``).

    Returns
    -------
    tuple
        The model, the uncalibrated start and the parameter bounds (a rival base change taken
        is adopted), the named effects, the pairs (effect, rival taken in its place) and the
        base-change lines of the rivals adopted.
    """
    added = list(added)
    swaps: list[tuple[str, str]] = []
    lines: list[str] = []
    for name in [n for n in names if n in added and passed_over.get(n)]:
        swap = _revisit(
            name, passed_over[name], current, origin, added, config, data, ranges,
            workers, progress, say,
        )  # fmt: skip
        if swap is None:
            continue
        rival, fit, swapped = swap
        added.remove(name)
        swaps.append((name, rival))
        if swapped is None:
            added.append(rival)
        else:
            ranges, origin, line = _adopt(
                swapped, origin, data, current, fit, f", in place of {name}"
            )
            lines.append(line)
        current = fit
    return current, origin, ranges, added, swaps, lines


def _tied(items: Sequence[T], score: Callable[[T], float]) -> list[T]:
    """``items`` whose ``score`` is within ``SAME_CHOICE`` of the best."""
    if not items:
        return []
    top = min(score(item) for item in items)
    return [item for item in items if score(item) <= top * (1.0 + SAME_CHOICE)]


def _first(changes: Iterable[BaseChange]) -> list[str]:
    """Labels of ``changes`` that ``_choose`` takes before an effect in a tie (and that a
    re-made choice may take without a better score, ``_revisit``): a widened bound or a
    second ESC stage."""
    return [ch.label for ch in changes if ch.widened or ch.second_stage]


def _choose(
    finals: Sequence[tuple[Candidate, Fit, float]], first: Collection[str] = ()
) -> tuple[Candidate | None, Fit | None]:
    """Of ``finals`` (candidate, full calibration, cross-validated score), the one with the
    best score; of those within ``SAME_CHOICE`` of it, a widened bound or a second ESC stage
    (labels ``first``) before an effect, then the lowest BIC (an exact-base Coulomb torque
    hidden with a voltage sag, 60 s: the drive-loss base change reached held-out 1.78, BIC
    -3474, the torque 1.85, BIC -3601; with the base change taken, the torque gained nothing
    after). A parameter on its bound is evidence of its own that the base is off, and an
    effect that is there is still found after the widening; the reverse is not true (t200
    mismatch seed 525, inertia x 2.63 and a hidden current limit: a deadband 0.99 held-out,
    BIC -27883, the inertia widened 1.00, BIC -26153; with the deadband taken the widening
    was not tried again). Likewise a short second ESC stage and a dead time of less than a
    sample look alike at 10 Hz; a dead time taken first leaves the stage nothing to gain
    (t100 mismatch null trace 782, stage 0.058 s: a 0.045 s dead time and the stage both at
    held-out 1.00, BICs -29470 and -29427), while a delay that is there still shows behind
    the stage (a cascade cannot imitate it, and a 0.3-1 s dead time does not tie with one)."""
    if not finals:
        return None, None
    tied = _tied(finals, lambda cf: cf[2])
    tied = [cf for cf in tied if cf[0].name in first] or tied
    chosen, best, _ = min(tied, key=lambda cf: cf[1].bic)
    return chosen, best


def _run_jobs(
    jobs: list[tuple],
    workers: int,
    progress: bool,
    desc: str,
    run: Callable[[tuple], T] = _run_candidate,
    unit: str = "candidate",
) -> list[T]:
    """Run jobs (``run``: a candidate's ``_run_candidate`` by default) in ``workers``
    processes, in order."""
    bar = tqdm(total=len(jobs), desc=desc, disable=not progress, unit=unit)
    results: list[T] = []
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("fork")) as pool:
            for out in pool.map(run, jobs):
                results.append(out)
                bar.update()
    else:
        for job in jobs:
            results.append(run(job))
            bar.update()
    bar.close()
    return results


def search(
    config: SimConfig,
    data: Measured,
    *,
    workers: int = 2,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    warnings: tuple[str, ...] = (),
) -> Result:
    """Calibrate ``config``, adjust its base, add missing effects while an addition helps,
    and drop effects of the start the thruster lacks.

    Returns
    -------
    Result
        With the verdict: ``effects_found`` if an effect was named missing or superfluous,
        else ``unexplained`` if the held-out score is above ``STRUCTURED``, else
        ``nothing_missing``.
    """
    say = log or (lambda _msg: None)
    start = calibrate(config, data)
    say(f"calibrated start: held-out score {start.gap.score:.2f} ({start.n_sims} simulations)")
    current, origin, ranges = start, config, {}
    added: list[str] = []
    changed: list[str] = []
    retracted: set[str] = set()
    passed_over: dict[str, list[str]] = {}  # a named effect: the rivals it was chosen over
    waiting: list[str] = []  # effects accepted in rounds a base change won, not named since
    replaced: list[tuple[str, str]] = []
    rounds: list[Round] = []
    while len(added) < MAX_ROUNDS and _above_noise(current):
        names = [n for n in EFFECTS if current.config.effect(n) is None and n not in retracted]
        changes = base_changes(current, config, ranges)
        if not names and not changes:
            break
        named = _start_with(origin, current, added)
        # Control: the same model re-fitted once more, from the same two origins a candidate
        # starts from (the current model and the uncalibrated start plus the named effects),
        # so that a candidate is credited only with what its effect adds, not with what
        # further fitting of the base would give (after a base change, 6 more iterations
        # from the start took a model from held-out score 1.28 to 1.02 with any candidate).
        for origin_config in (current.config, named):
            control = calibrate(
                origin_config, data, max_iter=CANDIDATE_ITER, anchor=config, ranges=ranges
            )
            if control.bic < current.bic:
                current = replace(control, n_sims=control.n_sims + current.n_sims)
        if not _above_noise(current):
            # The control reached the noise level: there is no excess left for a candidate to
            # remove (t200 mismatch 601: a deadband named at held-out 0.92 after a control at
            # 0.97, when a gain was counted against the excess itself).
            say(f"control re-fit: held-out score {current.gap.score:.2f}, at the noise level")
            break
        jobs = [(w, current, data, named, config, ranges) for w in [*names, *changes]]
        braking = next((ch for ch in changes if ch.regen is not None), None)
        if braking is not None:
            jobs += [
                ((n, braking), current, data, named, config, braking.ranges)
                for n in BRAKING_PARTNERS
                if n in names
            ]
        widen = next((ch for ch in changes if ch.widened), None)
        results = _run_jobs(jobs, workers, progress, f"candidates (round {len(rounds) + 1})")
        results = _best_widening(_with_braking(results, braking), widen)
        accepted = sorted((c for c in results if c.accepted), key=lambda c: c.fit.gap.score)
        if not accepted and widen is not None and names:
            # Nothing passes on its own, and a base parameter sits on its bound: an effect may
            # show only together with the wider bound, and the bound be worth widening only with
            # the effect (a hidden slew limit in a thruster with k_q outside the range: either
            # alone gains under 15 %). Each effect is re-fitted with the bound widened; it is
            # accepted by the rules of an effect, and the widening must remove BASE_GAIN of
            # what the effect alone left (on the T200 bench trace it removes a quarter).
            jobs = [((n, widen), current, data, named, config, widen.ranges) for n in names]
            alone = {c.name: c for c in results if c.joint is None}
            for c in _run_jobs(jobs, workers, progress, "candidates with a wider bound"):
                marginal = _excess_gain(alone[c.name].fit.gap.score, c.fit.gap.score)
                results.append(replace(c, accepted=c.accepted and marginal >= BASE_GAIN))
            accepted = sorted((c for c in results if c.accepted), key=lambda c: c.fit.gap.score)
        pairs: tuple[Pair, ...] = ()
        if not accepted and current.gap.score > STRUCTURED:
            results, pairs = _paired(
                results, current, data, origin, added, config, ranges, workers, progress, say
            )
            accepted = [c for c in results if c.accepted]
        for c in sorted(results, key=lambda c: c.fit.gap.score):
            say(
                f"  {c.label:17s} dBIC {c.delta_bic:12.1f} gain {c.gain:6.2f} "
                f"own {c.own_gain:6.2f} held-out score {c.fit.gap.score:9.2f}"
                f"{'  accepted' if c.accepted else ''}"
            )
        # The effects' re-fits are short (CANDIDATE_ITER); the best N_FINALS accepted candidates
        # get a full calibration each (a base change had one already) and the better of those
        # is chosen. (A hidden viscous friction, for instance, is at first fitted better by a
        # Coulomb torque.)
        by_label = {ch.label: ch for ch in changes}
        finals = []  # (candidate, full calibration, its bounds)
        for c in accepted[:N_FINALS]:
            change = by_label.get(c.name) or c.joint
            wide = change.ranges if change else ranges
            base = change.apply(origin, data) if c.joint else origin
            full = c.fit if c.name in by_label else _recalibrate(config, base, added, c, data, wide)
            finals.append((c, full, wide))
        # Between two or more, the held-out blocks alone are too few to choose (an exact-base
        # Coulomb torque, 60 s: the drive losses 1.20 there, the torque 1.27, the truth
        # itself 1.19; the folds' medians 1.25 against 1.21): each is re-fitted on every fold
        # of a cross-validation, from its full calibration.
        scored, n_folds = _score_finals(finals, data, config, workers, progress)
        for c, full, cv in scored:
            folded = f", cross-validated {cv:.2f}" if len(scored) > 1 else ""
            say(
                f"  full calibration with {c.name}: held-out score {full.gap.score:.2f}"
                f"{folded}, BIC {full.bic:.1f}"
            )
        chosen, best = _choose(scored, _first(changes))
        rounds.append(
            Round(
                before=current,
                candidates=tuple(results),
                chosen=chosen.name if chosen else None,
                finals=tuple((c.name, full.gap.score, cv, full.bic) for c, full, cv in scored),
                chosen_with=chosen.joint.label if chosen and chosen.joint else None,
                pairs=pairs,
            )
        )
        if chosen is None or best is None:
            break
        best = replace(best, n_sims=best.n_sims + n_folds)
        change = by_label.get(chosen.name) or chosen.joint
        if change is not None:
            with_effect = f", with {chosen.name}" if chosen.joint else ""
            ranges, origin, line = _adopt(change, origin, data, current, best, with_effect)
            changed.append(line)
        before = list(added)
        if chosen.name not in by_label:
            added.append(chosen.name)
        current = best
        say(
            f"{'changed' if chosen.name in by_label else 'added'} {chosen.name}: held-out score "
            f"{current.gap.score:.2f} ({sum(c.fit.n_sims for c in results) + current.n_sims} "
            "simulations)"
        )
        if chosen.name in by_label:
            waiting.extend(c.name for c in accepted if c.name in EFFECTS)
        else:
            # Every accepted rival, not only the finals: the shortlist is cut by the short
            # re-fits on the base of the time (t200 mismatch 655, a hidden Coulomb torque: it came
            # fourth, 2.36, behind a viscous torque, 1.83, and two base changes taken later).
            # Effects a base change won over in the rounds before count too: they were
            # accepted for the excess this effect now takes (t100 mismatch 821, a hidden
            # Coulomb torque: accepted, 1.49, when the drive losses were taken, 1.31; then
            # short of the gain, 1.29, against a deadband's 1.21; once k_q was widened, the
            # torque in the deadband's place cross-validated 1.27 against 1.31).
            rivals = [*(c.name for c in accepted), *waiting]
            passed_over[chosen.name] = [n for n in dict.fromkeys(rivals) if n != chosen.name]
            waiting = []
        if before:
            # After a base change the effects named before it face the effect rules again;
            # after an effect, the BIC alone (``_retest``).
            current, gone = _retest(
                current, before, config, data, ranges, say, held_out=change is not None
            )
            added = [n for n in added if n not in gone]
            retracted.update(gone)
        if change is not None and before:
            current, origin, ranges, added, swaps, lines = _choices_again(
                before, passed_over, current, origin, ranges, added, config, data,
                workers, progress, say,
            )  # fmt: skip
            retracted.update(name for name, _rival in swaps)
            replaced.extend(swaps)
            changed.extend(lines)
    named = _start_with(origin, current, added)
    tests = tuple(
        test_superfluous(e.name, current, config, data, ranges, named, stuck=False)
        for e in config.effects
        if e.name not in added
    )
    if current.gap.score > STRUCTURED and not any(t.superfluous for t in tests):
        # The model still holds structure and no start effect is superfluous: a calibration
        # may be stuck with an effect the thruster lacks, its spread no contradiction (t200
        # mismatch 664, a 0.55 s dead time: 0.52 +- 0.42 s beside the 0.1 s lag shrunk to
        # 0.005 s, held-out 1023). Each one not contradicted is tested by removal, and only
        # the one whose removal leaves the lowest held-out score is taken: tested in a model
        # that far off, another may pass with it (t200 631: the lag, which that thruster has,
        # beside a superfluous dead time).
        stuck = [
            test_superfluous(t.name, current, config, data, ranges, named, stuck=True)
            for t in tests
            if not t.contradicted
        ]
        found = [t for t in stuck if t.superfluous]
        if found:
            first = min(found, key=lambda t: t.without.gap.score)
            tests = tuple(first if t.name == first.name else t for t in tests)
    tests = _one_at_a_time(tests, config, data, ranges, named)
    dropped = [t for t in tests if t.superfluous]
    for t in tests:
        values = ", ".join(
            f"{p} {t.fitted[p]:.4g} +- {t.fitted_std[p]:.2g} (start {v:.4g})"
            for p, v in t.start_params.items()
        )
        without = (
            f"; without: dBIC {t.delta_bic:.1f}, held-out score {t.without.gap.score:.2f}, "
            f"at the start's value {t.score_claim:.2f}"
            if t.without is not None
            else ""
        )
        staged = f" (with a {t.change.label.removeprefix('base: ')})" if t.change else ""
        mark = "  superfluous" if t.superfluous else ""
        say(f"  start's {t.name}: {values}{without}{staged}{mark}")
    for t in dropped:
        if t.change is not None and t.without is not None:
            ranges, origin, line = _adopt(
                t.change, origin, data, current, t.without, f", in place of {t.name}"
            )
            changed.append(line)
            current = t.without
    if dropped:
        current, gone = drop_superfluous(
            current, [t.name for t in dropped], added, origin, config, data, ranges, say
        )
        added = [n for n in added if n not in gone]
        # Without the start's effect the base is another, as after a base change: a choice
        # made beside it is made again (a viscous torque can be named over the idle-current
        # law the thruster has while a superfluous dead time stands in for its second ESC
        # stage).
        current, origin, ranges, added, swaps, lines = _choices_again(
            added, passed_over, current, origin, ranges, added, config, data,
            workers, progress, say,
        )  # fmt: skip
        replaced.extend(swaps)
        changed.extend(lines)
    if added or dropped:
        verdict = "effects_found"
    elif current.gap.score > STRUCTURED:
        verdict = "unexplained"
    else:
        verdict = "nothing_missing"
    return Result(
        verdict, start, current, tuple(added), tuple(rounds), warnings, tuple(changed), tests,
        config, dict(ranges), tuple(replaced),
    )  # fmt: skip


def run_workflow(
    trace: Trace,
    source: SimConfig,
    drop: Sequence[str] = (),
    *,
    workers: int = 2,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> tuple[Result, Measured]:
    """The whole workflow on one measured trace.

    Parameters
    ----------
    trace : Trace
        Measured trace (any trace CSV/MCAP with the documented columns).
    source : SimConfig
        Starting configuration (``--start``).
    drop : sequence of str
        Effects removed from it first (``--drop``); absent ones give a warning.
    workers : int
        Processes for the candidate re-fits (1: in this process).
    progress : bool
        Show tqdm progress bars.
    log : callable or None
        Receives one-line progress messages.

    Returns
    -------
    (Result, Measured)
        The result and the prepared measurement.
    """
    config, warnings = start_config(source, drop)
    data = prepare_measured(trace, config)
    result = search(config, data, workers=workers, progress=progress, log=log, warnings=warnings)
    return result, data
