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
   ``MIN_GAIN`` of the held-out error. Repeated while an addition helps, so two missing effects
   are both named.

Measurement noise is handled explicitly: the model is simulated noise-free (noise, outliers and
quantisation off), the measured trace is despiked, residuals are weighted by the estimated noise
level of each channel, and the reporting floor (``rpm_floor``) is treated as censoring: a measured
zero only says the model's speed should be under the floor.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from multiprocessing import get_context

import numpy as np
from tqdm import tqdm

from thruster_fdd.core.discrepancy.fit import Fit, calibrate
from thruster_fdd.core.discrepancy.measure import (
    CHANNELS,
    Measured,
    gap,
    prepare_measured,
    simulate_model,
    weighted_residuals,
)
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.sim.config import SimConfig, set_effect
from thruster_fdd.core.sim.effects import EFFECTS, make_effect
from thruster_fdd.core.sim.plant import RAD_S_TO_RPM
from thruster_fdd.core.traces.data import Trace

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
        Score on the fit samples of the re-fit with the effect removed again, minus that with
        it, as a fraction of the base's excess error there: what the effect itself accounts
        for.
    """

    name: str
    fit: Fit
    delta_bic: float
    gain: float
    accepted: bool
    own_gain: float = math.nan


@dataclass(frozen=True)
class Round:
    """One search round: the calibrated model it starts from and every candidate's result."""

    before: Fit
    candidates: tuple[Candidate, ...]
    chosen: str | None


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
    """

    verdict: str
    start: Fit
    final: Fit
    added: tuple[str, ...]
    rounds: tuple[Round, ...]
    warnings: tuple[str, ...]

    def report(self) -> dict:
        """The report.json mapping, exactly the keys of docs/contracts.md."""
        missing = []
        for name in self.added:
            effect = self.final.config.effect(name)
            params = effect.params() if effect is not None else {}
            missing.append(
                {
                    "name": name,
                    "params": params,
                    "uncertainty": {p: self.final.uncertainty(f"{name}.{p}") for p in params},
                }
            )
        return {
            "verdict": self.verdict,
            "missing_effects": missing,
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
    """Initial values tried for effect ``name`` (plausible range, scaled to this thruster)."""
    p = config.params
    w_max = max(float(np.max(np.abs(data.rpm))) / RAD_S_TO_RPM, 1.0)
    torque = p.k_q * w_max * w_max
    i_max = float(np.max(data.current))
    grids: dict[str, tuple[str, list[float]]] = {
        "dead_time": ("delay_s", [0.05, 0.15, 0.3, 0.6, 1.0, 1.5]),
        "deadband": ("width", [0.01, 0.025, 0.045, 0.07, 0.1, 0.15]),
        "esc_lag": ("tau_s", [0.05, 0.15, 0.3, 0.6, 1.0, 2.0]),
        "slew_rate_limit": ("rate_per_s", [0.3, 0.6, 1.2, 2.5, 5.0, 10.0]),
        "coulomb_friction": (
            "torque_nm",
            [torque * f for f in (0.003, 0.01, 0.02, 0.04, 0.08, 0.15)],
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
    res = weighted_residuals(simulate_model(config, data), data)
    return float(sum(np.mean(res[c][data.fit] ** 2) / data.sigma[c] ** 2 for c in CHANNELS))


def try_candidate(
    name: str,
    base: Fit,
    data: Measured,
    origin: SimConfig | None = None,
    max_iter: int = CANDIDATE_ITER,
) -> Candidate:
    """Add effect ``name`` to ``base``, grid-initialise it, re-fit, and test it.

    The effect is added to ``base``'s calibrated configuration and, if given, to ``origin``
    (the uncalibrated starting configuration plus the effects named so far), each at the best
    of its ``candidate_grid`` values; both are re-fitted (every parameter free, ``max_iter``
    iterations) and the re-fit with the lower BIC is kept. The second origin matters: the
    calibrated base has distorted its parameters to make up for the missing effect, and from
    there the effect at its true value may fit worse than not binding at all (a slew limit
    above every duty step has no gradient to follow).

    Acceptance needs a lower BIC on the fit samples (penalising the added parameters) and a
    held-out gain of at least ``MIN_GAIN`` of the excess error (above noise), and the effect
    itself must account for at least ``MIN_GAIN`` of the excess on the fit samples: removing it
    from the re-fit must cost that much (so a candidate is not credited with a better fit of
    the other parameters).
    """
    starts = []
    n_trials = 0
    for config in (base.config,) if origin is None else (base.config, origin):
        grid = candidate_grid(name, config, data)
        trials = [set_effect(config, make_effect(name, g)) for g in grid]
        scores = [_score_config(c, data) for c in trials]
        starts.append(trials[int(np.argmin(scores))])
        n_trials += len(trials)
    # ``origin`` holds the user's base values, the anchor of the base parameters' bounds.
    fits = [calibrate(start, data, max_iter=max_iter, anchor=origin) for start in starts]
    fit = min(fits, key=lambda f: f.bic)
    fit = replace(fit, n_sims=sum(f.n_sims for f in fits) + n_trials)
    delta_bic = fit.bic - base.bic  # both penalise all their parameters
    excess = max(base.gap.score - 1.0, 1e-12)
    gain = (base.gap.score - fit.gap.score) / excess
    # Ablation: the re-fitted model with the effect taken out again. The effect itself must
    # account for the gain, not the further re-fit of the other parameters that came with it.
    # Measured on the fit samples: an effect active in few places (a current limit binding for
    # 2 s of a 60 s trace) may be active in none of the held-out blocks, where its removal
    # changes nothing; the held-out gain above already checks that the re-fit generalises.
    ablated = replace(fit.config, effects=tuple(e for e in fit.config.effects if e.name != name))
    base_fit = gap(simulate_model(base.config, data), data, data.fit).score
    fit_score = gap(simulate_model(fit.config, data), data, data.fit).score
    ablated_score = gap(simulate_model(ablated, data), data, data.fit).score
    own_gain = (ablated_score - fit_score) / max(base_fit - 1.0, 1e-12)
    fit = replace(fit, n_sims=fit.n_sims + 3)
    accepted = delta_bic < 0.0 and gain >= MIN_GAIN and own_gain >= MIN_GAIN
    return Candidate(
        name=name,
        fit=fit,
        delta_bic=delta_bic,
        gain=gain,
        accepted=accepted,
        own_gain=own_gain,
    )


def _run_candidate(args: tuple[str, Fit, Measured, SimConfig | None]) -> Candidate:
    return try_candidate(*args)


def _recalibrate(config: SimConfig, added: Sequence[str], chosen: Candidate, data: Measured) -> Fit:
    """Full calibration with ``added`` and ``chosen`` effects, from the better of two origins.

    The origins: the start's values plus the effects (the start's fit may have drifted to
    compensate for what was missing) and the candidate's re-fit; whichever fits better to begin
    with is calibrated, and the candidate's re-fit is kept if that does not improve its BIC.
    """
    reset = config
    for name in (*added, chosen.name):
        reset = set_effect(reset, chosen.fit.config.effect(name))
    origins = (reset, chosen.fit.config)
    fit = calibrate(min(origins, key=lambda c: _score_config(c, data)), data, anchor=config)
    if fit.bic > chosen.fit.bic:
        fit = calibrate(chosen.fit.config, data, anchor=config)
    return fit


def search(
    config: SimConfig,
    data: Measured,
    *,
    workers: int = 2,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> tuple[Fit, Fit, tuple[str, ...], tuple[Round, ...]]:
    """Calibrate ``config`` and add missing effects while an addition helps.

    Returns
    -------
    (start, final, added, rounds)
        Calibrated start, calibrated final configuration, named effects, search rounds.
    """
    say = log or (lambda _msg: None)
    start = calibrate(config, data)
    say(f"calibrated start: held-out score {start.gap.score:.2f} ({start.n_sims} simulations)")
    current = start
    added: list[str] = []
    rounds: list[Round] = []
    ctx = get_context("fork")
    for _ in range(MAX_ROUNDS):
        names = [n for n in EFFECTS if current.config.effect(n) is None]
        if not names or current.gap.score <= 1.0 + 1e-9:
            break
        # Control: the same model re-fitted once more, so that a candidate is credited only
        # with what its effect adds, not with what further fitting of the base would give.
        control = calibrate(current.config, data, max_iter=CANDIDATE_ITER, anchor=config)
        if control.bic < current.bic:
            current = replace(control, n_sims=control.n_sims + current.n_sims)
        origin = config
        for name in added:
            origin = set_effect(origin, current.config.effect(name))
        jobs = [(n, current, data, origin) for n in names]
        bar = tqdm(
            total=len(jobs),
            desc=f"candidates (round {len(rounds) + 1})",
            disable=not progress,
            unit="effect",
        )
        results: list[Candidate] = []
        if workers > 1:
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                for cand in pool.map(_run_candidate, jobs):
                    results.append(cand)
                    bar.update()
        else:
            for job in jobs:
                results.append(_run_candidate(job))
                bar.update()
        bar.close()
        accepted = sorted((c for c in results if c.accepted), key=lambda c: c.fit.gap.score)
        for c in sorted(results, key=lambda c: c.fit.gap.score):
            say(
                f"  {c.name:17s} dBIC {c.delta_bic:12.1f} gain {c.gain:6.2f} own {c.own_gain:6.2f} "
                f"held-out score {c.fit.gap.score:9.2f}{'  accepted' if c.accepted else ''}"
            )
        # The candidate re-fits are short (CANDIDATE_ITER); the best two accepted ones get a
        # full calibration each and the better of those (held-out score) is named. (A hidden
        # viscous friction, for instance, is at first fitted better by a Coulomb torque.)
        finals = [(c, _recalibrate(config, added, c, data)) for c in accepted[:2]]
        chosen, best = min(finals, key=lambda cf: cf[1].gap.score) if finals else (None, None)
        rounds.append(
            Round(before=current, candidates=tuple(results), chosen=chosen.name if chosen else None)
        )
        if chosen is None or best is None:
            break
        added.append(chosen.name)
        current = best
        say(
            f"added {chosen.name}: held-out score {current.gap.score:.2f} "
            f"({sum(c.fit.n_sims for c in results) + current.n_sims} simulations)"
        )
    return start, current, tuple(added), tuple(rounds)


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
    start, final, added, rounds = search(config, data, workers=workers, progress=progress, log=log)
    if added:
        verdict = "effects_found"
    elif final.gap.score > STRUCTURED:
        verdict = "unexplained"
    else:
        verdict = "nothing_missing"
    return Result(verdict, start, final, added, rounds, warnings), data
