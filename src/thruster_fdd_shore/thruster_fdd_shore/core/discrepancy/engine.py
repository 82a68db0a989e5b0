"""The selection engine of the discrepancy workflow (docs/discrepancy.md, "Method").

One score, one acceptance rule, one loop:

- **Score**: blocked cross-validation. Each model is calibrated on every fold of
  ``Policy.folds`` (two of ten blocks held out); its held-out residuals, in noise standard
  deviations, give a Gaussian log-likelihood per sample, each channel weighted by its
  effective sample share ``(1 - rho) / (1 + rho)`` (``rho``: lag-1 autocorrelation of the
  step's model's residual). A move's gain is the sum of the differences.
- **Acceptance**: the gain must exceed ``Policy.min_gain`` and its own uncertainty (the noise's:
  a sample whose residuals differ by ``delta`` adds ``w * delta**2`` to the variance) times the
  normal quantile of ``Policy.alpha`` shared by the step's moves (Bonferroni). The same test
  applies where an effect acts (its signature must be in the data) and against the generic
  correction (``correction``): a move must gain beyond it, or the correction must not be
  clearly better than the move, and it must not lose beyond it. Gains are counted against a
  control, the model re-fitted as the moves are, so no move is credited with further fitting.
- **Loop**: forward, of the accepted moves within the score's uncertainty of the largest gain,
  the one adding the fewest parameters (the one-standard-error rule); after every addition,
  and when no move is accepted, a backward step removes what no longer earns its place (and
  the forward steps go on if it removed anything); a start effect only when the data
  contradict its claimed values: its removal passes the acceptance rule against the claim,
  where the claim acts (a limit that never binds stays) and beyond the generic correction,
  and the model without it leaves no structured rest where the claim acts.
  When that removes nothing either, an exchange offers each adopted base change's place to
  the other moves. At the end a removed start effect the final model does not contradict is
  restored.

A block bootstrap of the recorded gains gives each choice its selection frequency and the
weights of the moves within the score's uncertainty of it; the fold fits give every named
parameter a jackknife spread.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from multiprocessing import get_context

import numpy as np
from tqdm import tqdm

from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.discrepancy.fit import Fit, _get, calibrate
from thruster_fdd_shore.core.discrepancy.measure import N_BLOCKS, Measured, prepare_measured
from thruster_fdd_shore.core.discrepancy.moves import Move, available, start_config
from thruster_fdd_shore.core.discrepancy.score import (
    DEFAULT_POLICY,
    Policy,
    Scored,
    effective_samples,
    evaluate,
    excess,
    gain_of,
    rest_of,
    weights,
)
from thruster_fdd_shore.core.sim.config import SimConfig

VERDICTS = ("effects_found", "nothing_missing", "unexplained")
"""Values of ``report.json``'s ``verdict`` (docs/contracts.md)."""


@dataclass(frozen=True)
class Judged:
    """One move of one step, judged against the step's model.

    ``gain``/``se``: the held-out gain and its standard error (ESS-weighted nats);
    ``where``: gain where the move acts (``None`` for a removal); ``beyond``: gain over
    the model plus the generic correction, both corrected; ``deficit``: the corrected model's
    lead over the move; ``accepted``: every test passed. ``d``: the per-block gains
    (plain, where, beyond, deficit, then plain, beyond, deficit over each part of a joint
    move), shape (4 + 3 parts, 2, N_BLOCKS) (``gain_of``), for the bootstrap.
    """

    move: str
    gain: float
    se: float
    significant: bool
    where: float | None
    beyond: float
    deficit: float
    accepted: bool
    d: np.ndarray = field(repr=False)


def judge(
    move: Move, cand: Scored, parent: Scored, data: Measured, w, policy, moves, parts=()
) -> Judged:
    """Apply the acceptance rule to ``cand`` (``parent`` with ``move``; ``moves`` share the
    step's ``alpha``; ``parts``: a joint move's parts made alone, each of which it must beat)."""
    plain = gain_of(cand.r, parent.r, data, w)
    acts = cand.active is not None
    stack = np.stack(
        [
            plain,
            gain_of(cand.r, parent.r, data, w, cand.active) if acts else plain,
            gain_of(cand.r_g, parent.r_g, data, w),
            gain_of(parent.r_g, cand.r, data, w),
            *(
                g
                for part in parts
                for g in (
                    gain_of(cand.r, part.r, data, w),
                    gain_of(cand.r_g, part.r_g, data, w),
                    gain_of(part.r_g, cand.r, data, w),
                )
            ),
        ]
    )
    gain, se, sig, gain_where, beyond, deficit, accepted = _verdict(stack, policy, moves)
    return Judged(
        move.label, gain, se, sig, gain_where if acts else None, beyond, deficit, accepted, stack
    )


def _with_parts(moves: list[Move]) -> list[Move]:
    """``moves`` and the parts of its joint moves, each once."""
    labels = {m.label for m in moves}
    extra = {p.label: p for m in moves for p in m.parts if p.label not in labels}
    return [*moves, *extra.values()]


def _judge_all(
    moves: list[Move], outs: list[Scored], parent: Scored, data: Measured, policy: Policy
) -> tuple[Judged, ...]:
    """``judge`` each of ``moves`` (its calibration in ``outs``) against ``parent``, a joint
    move against its parts (``moves`` holds them, ``_with_parts``)."""
    w = weights(parent.r, data)
    by_label = {m.label: o for m, o in zip(moves, outs, strict=True)}
    return tuple(
        judge(m, o, parent, data, w, policy, len(moves), [by_label[p.label] for p in m.parts])
        for m, o in zip(moves, outs, strict=True)
    )


_LOSS = np.array([[-1.0], [1.0]])
"""Turns a per-block gain (``gain_of``) into the loss: the sum negated, the variance kept."""


def _verdict(d: np.ndarray, policy: Policy, moves: int) -> tuple:
    """(gain, se, significant, where, beyond, deficit, accepted) of the gains ``d`` (``judge``):
    significant, significant where the move acts (the rest of its gain is the re-fit of the
    base it allows: a missing effect distorts the fit of the others), not clearly worse once
    both models have the generic correction (a gain that the correction turns into a loss
    depends on a difference the move does not model: it stands in for it), and either
    significant beyond the correction or not clearly behind it; a joint move also has evidence
    of a gain over each of its parts made alone, beyond the correction or not clearly behind it
    there (each part earns its place beside the other, as a move made on it would)."""
    gain, se, sig = policy.test(d[0], moves)
    where, _, sig_where = policy.test(d[1], moves)
    beyond, _, sig_beyond = policy.test(d[2], moves)
    deficit, _, sig_deficit = policy.test(d[3], moves)
    loses = policy.test(d[2] * _LOSS, moves)[2]
    accepted = sig and sig_where and not loses and (sig_beyond or not sig_deficit)
    for k in range(4, len(d), 3):  # each part of a joint move as the parent
        sig_p, beyond_p, deficit_p = (policy.test(d[k + i], moves)[2] for i in range(3))
        accepted = accepted and sig_p and (beyond_p or not deficit_p)
    return gain, se, sig, where, beyond, deficit, accepted


@dataclass(frozen=True)
class Step:
    """One forward or backward step: the moves judged, the one taken (None: none), and the
    alternatives within the score's uncertainty of it with their bootstrap weights."""

    kind: str
    judged: tuple[Judged, ...]
    taken: str | None
    frequency: float = 1.0
    alternatives: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Result:
    """Outcome of the search: the verdict, the calibrated start and final model (on the
    default held-out blocks), the final model's fold fits, its spec, the steps, the policy,
    the warnings and the rest (``rest_of`` the final model)."""

    verdict: str
    start: Fit
    final: Fit
    scored: Scored
    steps: tuple[Step, ...]
    anchor: SimConfig
    policy: Policy
    warnings: tuple[str, ...] = ()
    rest: dict = field(default_factory=dict)

    @property
    def added(self) -> tuple[str, ...]:
        """Effects named missing."""
        return self.scored.spec.added

    @property
    def removed(self) -> tuple[str, ...]:
        """Effects of the start named superfluous."""
        return self.scored.spec.removed

    def spread(self, key: str) -> float:
        """Jackknife standard deviation of parameter ``owner.name`` over the fold fits."""
        vals = np.array([_get(f.config, key) for f in self.scored.folds])
        k = len(vals)
        return float(math.sqrt((k - 1) / k * np.sum((vals - vals.mean()) ** 2)))

    def frequency(self, label: str) -> float:
        """Bootstrap frequency with which the step that took ``label`` (alone or in a joint
        move) took it."""
        taken = (s for s in self.steps if s.taken and label in s.taken.split(" + "))
        return next((s.frequency for s in taken), 0.0)


def _run(jobs: list[tuple], workers: int, progress: bool, desc: str) -> list[Scored]:
    bar = tqdm(total=len(jobs), desc=desc, disable=not progress, unit="model", leave=False)
    out: list[Scored] = []
    if workers > 1 and len(jobs) > 1:
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("fork")) as pool:
            for s in pool.map(evaluate, jobs):
                out.append(s)
                bar.update()
    else:
        for job in jobs:
            out.append(evaluate(job))
            bar.update()
    bar.close()
    return out


def _bootstrap(judged: tuple[Judged, ...], policy: Policy, rng) -> dict[str, float]:
    """How often each move is the accepted one of largest gain over block resamples."""
    counts = dict.fromkeys([j.move for j in judged], 0)
    for _ in range(policy.bootstrap):
        idx = rng.integers(0, N_BLOCKS, N_BLOCKS)
        verdicts = [(_verdict(j.d[:, :, idx], policy, len(judged)), j.move) for j in judged]
        accepted = [(v[0], move) for v, move in verdicts if v[6]]
        if accepted:
            counts[max(accepted)[1]] += 1
    return {k: v / policy.bootstrap for k, v in counts.items()}


def _refit(current: Scored, data, anchor, policy) -> Scored:
    """The control: ``current`` re-fitted on every fold to convergence (``FULL_ITER``), with no
    move; the better of the two is the step's model, so that no move is credited with further
    fitting."""
    control = evaluate((None, current, data, anchor, policy, None))
    w = weights(current.r, data)
    return control if gain_of(control.r, current.r, data, w)[0].sum() > 0.0 else current


def search(
    anchor: SimConfig,
    data: Measured,
    *,
    policy: Policy = DEFAULT_POLICY,
    workers: int = 2,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    warnings: tuple[str, ...] = (),
) -> Result:
    """Forward selection of moves with a backward step after every addition (module doc)."""
    say = log or (lambda _msg: None)
    rng = np.random.default_rng(policy.seed)
    current = evaluate((None, None, data, anchor, policy, None))
    say(f"start calibrated on {len(policy.folds)} folds")
    steps: list[Step] = []

    def run(moves: list[Move], desc: str, parent: Scored | None = None) -> list[Scored]:
        jobs = [(m, parent or current, data, anchor, policy, None) for m in moves]
        return _run(jobs, workers, progress, desc)

    def exchange() -> bool:
        """Offer each adopted base change's place to the moves it may stand in for, those with
        evidence of a gain in the step that took it: the change undone and the accepted move of
        largest gain made there instead, taken when that model scores higher than the current
        one, or within the score's uncertainty of it with fewer parameters (as a forward step
        prefers). A flexible change taken early, while an effect or another change was still
        missing, may stand in for them. Whether it exchanged."""
        nonlocal current
        rivals = {
            s.taken: {j.move for j in s.judged if j.significant and j.move != s.taken}
            for s in steps
            if s.kind == "forward" and s.taken in current.spec.changes
        }
        changes = [c for c in current.spec.changes if rivals.get(c)]
        undos = run([Move("undo", c) for c in changes], "undo base changes")
        for change, undone in zip(changes, undos, strict=True):
            others = _with_parts(
                [m for m in available(undone.spec, undone.folds[0].config, anchor)
                 if m.label in rivals[change]]
            )  # fmt: skip
            if not others:
                continue
            outs = run(others, f"in place of {change}", undone)
            judged = _judge_all(others, outs, undone, data, policy)
            ok = [(m, j, o) for m, j, o in zip(others, judged, outs, strict=True) if j.accepted]
            if not ok:
                continue
            move, j, swapped = max(ok, key=lambda mjo: mjo[1].gain)
            w = weights(current.r, data)
            sv = gain_of(swapped.r, current.r, data, w)
            ahead = policy.test(sv, len(others))
            behind = policy.test(sv * _LOSS, len(others))
            size = (move.size(anchor), Move("base", change).size(anchor))
            within = not behind[2] and (size[0] < size[1] or (size[0] == size[1] and ahead[0] > 0))
            if not (ahead[2] or within):
                continue
            steps.append(Step("exchange", judged, f"{change} -> {j.move}"))
            say(f"exchanged {change} for {j.move}")
            current = swapped
            return True
        return False

    def backward(just: Move | None) -> bool:
        """Remove, one at a time, what no longer earns its place (not the effect ``just``
        added); an effect of the start only where the data also contradict its claim. Whether
        anything was removed."""
        nonlocal current
        removed = False
        for _ in range(len(anchor.effects) + policy.max_steps):
            current = _refit(current, data, anchor, policy)
            w = weights(current.r, data)
            removals = [Move("remove", e.name) for e in current.folds[0].config.effects]
            added = {p.label for p in (just.parts or (just,))} if just else set()
            removals = [m for m in removals if f"add {m.name}" not in added]
            if not removals:
                return removed
            outs = run(removals, "backward step")
            keep = {
                m.name: (policy.test(gain_of(current.r, o.r, data, w), len(removals)), o)
                for m, o in zip(removals, outs, strict=True)
            }
            taken = None
            for name in sorted(
                (n for n, (t, _o) in keep.items() if not t[2]), key=lambda n: keep[n][0][0]
            ):
                if name in current.spec.added:
                    taken = name
                    break
                n = len(removals)
                if _contradicted(keep[name][1], current, name, data, anchor, policy, n)[0]:
                    taken = name
                    break
            judged = tuple(
                Judged(f"remove {n}", -t[0], t[1], t[2], None, 0.0, 0.0, n == taken,
                       np.zeros((4, 2, 1)))
                for n, (t, _o) in keep.items()
            )  # fmt: skip
            steps.append(Step("backward", judged, f"remove {taken}" if taken else None))
            if taken is None:
                return removed
            say(f"removed {taken}")
            current, removed = keep[taken][1], True
        return removed

    for _ in range(policy.max_steps):
        moves = available(current.spec, current.folds[0].config, anchor)
        # When no move earns its place, what the model holds is judged: a removal judged
        # while an effect is still missing would be credited with the missing effect's work.
        if not moves:
            if backward(None) or exchange():
                continue
            break
        outs = run(moves, f"step {len(steps) + 1}: {len(moves)} moves")
        w = weights(current.r, data)
        judged = _judge_all(moves, outs, current, data, policy)
        for j in sorted(judged, key=lambda j: -j.gain):
            say(
                f"  {j.move:24s} gain {j.gain:10.1f} +- {j.se:8.1f} beyond {j.beyond:10.1f}"
                f" deficit {j.deficit:10.1f}{'  accepted' if j.accepted else ''}"
            )
        ok = [(j, o) for j, o in zip(judged, outs, strict=True) if j.accepted]
        if not ok:
            steps.append(Step("forward", judged, None))
            if backward(None) or exchange():
                continue
            break
        top, top_scored = max(ok, key=lambda jo: jo[0].gain)
        freq = _bootstrap(judged, policy, rng)
        # Within the score's uncertainty of the largest gain, the simplest move (the
        # one-standard-error rule of cross-validation): fewest parameters added.
        within = [
            (j, o)
            for j, o in ok
            if j is top or not policy.test(gain_of(top_scored.r, o.r, data, w), len(moves))[2]
        ]
        by_label = {m.label: m for m in moves}
        best, scored = min(within, key=lambda jo: (by_label[jo[0].move].size(anchor), -jo[0].gain))
        tied = {j.move: freq[j.move] for j, _o in within if j is not best}
        steps.append(Step("forward", judged, best.move, freq[best.move], tied))
        say(f"took {best.move}")
        current = scored
        backward(by_label[best.move])
    else:
        backward(None)
    current = _confirm_removals(current, data, anchor, policy, say)
    rest = rest_of(current, data, policy)
    return _finish(current, anchor, data, policy, tuple(steps), warnings, rest)


def _contradicted(without: Scored, current: Scored, name, data, anchor, policy, moves) -> tuple:
    """Whether the data contradict the claim of start effect ``name``, and the claim (``current``
    with ``name`` held at the claimed values): ``without`` (``current`` without it) passes the
    acceptance rule against the claim, the generic correction included, so that a difference
    of another kind (a throttle curve) does not make a start effect look superfluous; and
    ``without`` explains the data where the claim acts (its held-out residual variance there,
    ``excess``, is no structure by ``Policy.structured``): where the model cannot, the claim
    may be wrong or the thruster may have a difference the model lacks there (a play in the
    command), and absence is not shown."""
    claim = evaluate((None, current, data, anchor, policy, name))
    w = weights(current.r, data)
    without = replace(without, active=claim.active)
    j = judge(Move("remove", name), without, claim, data, w, policy, moves)
    return j.accepted and excess(without, data, policy, claim.active) <= policy.structured, claim


def _confirm_removals(current: Scored, data, anchor, policy, say) -> Scored:
    """Restore each start effect a backward step removed whose claim the final model does not
    contradict: a removal judged while another effect was still missing may have been the
    stand-in's doing."""
    for name in current.spec.removed:
        moves = len(current.spec.removed)
        contradicted, claim = _contradicted(current, current, name, data, anchor, policy, moves)
        if contradicted:
            continue
        removed = tuple(n for n in current.spec.removed if n != name)
        claim = replace(claim, spec=replace(claim.spec, removed=removed))
        current = evaluate((None, claim, data, anchor, policy, None))
        say(f"restored {name}: the final model does not contradict its claim")
    return current


def structured(current: Scored, data: Measured, policy: Policy, rest: dict) -> bool:
    """Whether ``current`` leaves structure: a group of the generic correction explains at least
    ``Policy.rest_least`` noise variances of its residual with evidence, or the residual's
    variance exceeds ``Policy.structured`` noise variances."""
    least = policy.rest_least * effective_samples(current.r, data) / 2.0
    return (
        any(v[2] and v[0] > least for v in rest.values())
        or excess(current, data, policy) > policy.structured
    )


def _finish(current, anchor, data, policy, steps, warnings, rest) -> Result:
    """Calibrate start and final on the default held-out blocks; the verdict."""
    start = calibrate(anchor, data)
    spec = current.spec
    final = calibrate(current.folds[0].config, data, anchor=anchor, ranges=spec.ranges)
    if spec.added or spec.removed:
        verdict = "effects_found"
    else:
        verdict = "unexplained" if structured(current, data, policy, rest) else "nothing_missing"
    return Result(verdict, start, final, current, steps, anchor, policy, warnings, rest)


def policy_dict(policy: Policy) -> dict:
    """The policy as report.json carries it."""
    return asdict(policy)


def run_workflow(
    trace: Trace,
    source: SimConfig,
    drop: tuple[str, ...] | list[str] = (),
    *,
    workers: int = 2,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    policy: Policy = DEFAULT_POLICY,
) -> tuple[Result, Measured]:
    """The whole workflow on one measured trace: ``--drop`` applied to ``source``, the trace
    prepared (``measure.prepare_measured``), the search run.

    Returns
    -------
    (Result, Measured)
    """
    config, warnings = start_config(source, drop)
    data = prepare_measured(trace, config)
    result = search(
        config, data, policy=policy, workers=workers, progress=progress, log=log,
        warnings=warnings,
    )  # fmt: skip
    return result, data
