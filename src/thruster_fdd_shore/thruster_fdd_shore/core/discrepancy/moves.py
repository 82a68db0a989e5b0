"""The moves of the discrepancy search: one flat set of changes to a model.

A model (``Spec``) is the user's start (the *anchor*) with some moves made: effects of the
vocabulary added, effects of the start removed, and changes of its base structure. Every move
offers starting configurations for a calibration (``Move.starts``): the effect at each value
of a grid scaled to the thruster, the structure switched, bounds widened or terms freed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace

import numpy as np

from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.core.discrepancy.fit import BASE_FIT, BASE_RANGE, lacking_drive_losses
from thruster_fdd_shore.core.discrepancy.measure import Measured
from thruster_fdd_shore.core.sim.config import SimConfig, set_effect, without_effects
from thruster_fdd_shore.core.sim.effects import EFFECTS, make_effect
from thruster_fdd_shore.core.sim.plant import RAD_S_TO_RPM

WIDE_RANGE = 4.0
"""Factor around the anchor to which a base parameter on its ``BASE_RANGE`` bound may be
widened."""

SECOND_STAGE = (0.03, 0.06, 0.12, 0.2, 0.3, 0.45)
"""Starting time constants of a second ESC stage, as fractions of the ``esc_lag``'s, which is
shortened by as much (the cascade keeps the lag's mean delay)."""


def start_config(source: SimConfig, drop: Sequence[str]) -> tuple[SimConfig, tuple[str, ...]]:
    """``source`` without the effects ``drop``, and a warning per name it does not hold.

    Raises
    ------
    BadInputError
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
        config = without_effects(config, (name,))
    return config, tuple(warnings)


def candidate_grid(name: str, config: SimConfig, data: Measured) -> list[dict[str, float]]:
    """Starting values of effect ``name``: its plausible range, scaled to this thruster (the
    load torque at the trace's top speed, the measured current maximum). The slew limit's grid
    is dense because its fit has a narrow valley below the duty's peak rate and a plateau
    above it, where a calibration has no slope to follow."""
    w_max = max(float(np.max(np.abs(data.rpm))) / RAD_S_TO_RPM, 1.0)
    torque = config.params.k_q * w_max * w_max
    i_max = float(np.max(data.current))
    grids: dict[str, tuple[str, list[float]]] = {
        "dead_time": ("delay_s", [0.05, 0.15, 0.3, 0.6, 1.0, 1.5]),
        "deadband": ("width", [0.01, 0.025, 0.045, 0.07, 0.1, 0.15]),
        "esc_lag": ("tau_s", [0.05, 0.15, 0.3, 0.6, 1.0, 2.0]),
        "slew_rate_limit": ("rate_per_s", [float(r) for r in np.geomspace(0.3, 10.0, 20)]),
        "coulomb_friction": ("torque_nm", [torque * f for f in (0.003, 0.01, 0.03, 0.1, 0.3, 0.6)]),
        "viscous_friction": ("coeff", [torque / w_max * f for f in (0.01, 0.03, 0.1, 0.25, 0.5)]),
        "voltage_sag": ("r_internal_ohm", [0.01, 0.03, 0.06, 0.1, 0.2, 0.4]),
        "current_limit": ("i_max_a", [i_max * f for f in (0.5, 0.65, 0.8, 0.9, 0.97)]),
    }
    attr, values = grids[name]
    return [{attr: v} for v in values]


@dataclass(frozen=True)
class Spec:
    """A model: the anchor with moves made.

    Attributes
    ----------
    added : tuple of str
        Effects of the vocabulary added (named missing if they stay).
    removed : tuple of str
        Effects of the anchor removed (superfluous).
    changes : tuple of str
        Labels of the base changes made (``BASE_CHANGES``).
    ranges : dict of str to float
        Bound factors of base parameters other than ``BASE_RANGE``; a ``fit.DRIVE_LOSSES`` key
        frees that term (``fit.calibrate``).
    """

    added: tuple[str, ...] = ()
    removed: tuple[str, ...] = ()
    changes: tuple[str, ...] = ()
    ranges: dict[str, float] = field(default_factory=dict)


BASE_CHANGES = (
    "widen bounds",
    "second ESC stage",
    "other braking law",
    "no drive saturation",
    "drive losses",
    "refit winding loss",
)
"""Changes of the base structure: base parameters on their ``BASE_RANGE`` bound fitted within
``WIDE_RANGE``; a second ESC stage behind ``esc_lag``; coasting instead of regeneration (or
back); the start's ESC drive saturation removed; the drive losses the start lacks freed (drive
saturation, speed-dependent winding loss, idle current growing with speed); the start's
winding loss fitted within ``WIDE_RANGE``."""

JOINT = {"coulomb_friction": "other braking law", "viscous_friction": "other braking law"}
"""Effects also offered together with a base change (the ``joint`` move, effect -> change):
near standstill the propeller's drag vanishes as the square of the speed, so the end of a
spin-down is its braking law and its friction torques. Neither the braking law nor a friction
torque fits a spin-down alone where the other is missing (a coasting rotor without the friction
decelerates too slowly near standstill, and regenerative braking does part of the friction's
work), so a thruster differing in both would otherwise gain from neither single move."""


@dataclass(frozen=True)
class Move:
    """One change of a model: ``kind`` is ``add`` (an effect of the vocabulary), ``remove``
    (an effect the model holds), ``base`` (one of ``BASE_CHANGES``), ``joint`` (an effect of
    ``JOINT`` and its base change together) or ``undo`` (a base change the model made);
    ``name`` says which (the effect, for a joint move)."""

    kind: str
    name: str

    def size(self, anchor: SimConfig) -> int:
        """Parameters the move adds: an effect's, the drive-loss terms it frees, every base
        parameter for a widening, one for another base change."""
        if self.kind == "add":
            return len(fields(EFFECTS[self.name]))
        if self.kind == "joint":
            return sum(part.size(anchor) for part in self.parts)
        if self.kind in ("remove", "undo"):
            return 0
        if self.name == "drive losses":
            return len(lacking_drive_losses(anchor))
        if self.name == "widen bounds":
            return len(BASE_FIT)
        return 1

    @property
    def parts(self) -> tuple[Move, ...]:
        """The single moves a joint move makes together (none for the others)."""
        if self.kind != "joint":
            return ()
        return (Move("base", JOINT[self.name]), Move("add", self.name))

    @property
    def label(self) -> str:
        """``add NAME``, ``remove NAME``, the base change's name, or a joint move's parts'
        labels joined by `` + ``."""
        if self.kind == "joint":
            return " + ".join(part.label for part in self.parts)
        return self.name if self.kind == "base" else f"{self.kind} {self.name}"

    def spec(self, spec: Spec, fitted: SimConfig, anchor: SimConfig) -> Spec:
        """``spec`` with this move made (``fitted``: the model's calibrated configuration)."""
        if self.kind == "joint":
            for part in self.parts:
                spec = part.spec(spec, fitted, anchor)
            return spec
        if self.kind == "add":
            if self.name in spec.removed:  # the start's effect restored
                return replace(spec, removed=tuple(n for n in spec.removed if n != self.name))
            return replace(spec, added=(*spec.added, self.name))
        if self.kind == "remove":
            if self.name in spec.added:
                return replace(spec, added=tuple(n for n in spec.added if n != self.name))
            return replace(spec, removed=(*spec.removed, self.name))
        if self.kind == "undo":
            changes = tuple(c for c in spec.changes if c != self.name)
            ranges = {k: v for k, v in spec.ranges.items() if k not in made(self.name, anchor)}
            return replace(spec, changes=changes, ranges=ranges)
        ranges = dict(spec.ranges)
        if self.name == "widen bounds":
            ranges.update(dict.fromkeys(at_bound(fitted, anchor, spec.ranges), WIDE_RANGE))
        elif self.name == "drive losses":
            ranges.update(dict.fromkeys(lacking_drive_losses(anchor), math.inf))
        elif self.name == "refit winding loss":
            ranges["params.r_speed_ohm_s"] = WIDE_RANGE
        return replace(spec, changes=(*spec.changes, self.name), ranges=ranges)

    def starts(self, config: SimConfig, data: Measured, anchor: SimConfig) -> list[SimConfig]:
        """``config`` (a calibrated model) with the move made, once per starting value (an
        undone base change's terms at the ``anchor``'s values)."""
        if self.kind == "joint":
            base, effect = self.parts
            return [
                c for b in base.starts(config, data, anchor) for c in effect.starts(b, data, anchor)
            ]
        if self.kind == "add":
            return [
                set_effect(config, make_effect(self.name, g))
                for g in candidate_grid(self.name, config, data)
            ]
        if self.kind == "remove":
            return [without_effects(config, (self.name,))]
        if self.kind == "undo" and self.name == "widen bounds":
            values = {
                n: min(max(getattr(config.params, n), a / BASE_RANGE), a * BASE_RANGE)
                for n in BASE_FIT
                if (a := getattr(anchor.params, n)) > 0.0
            }
            return [replace(config, params=replace(config.params, **values))]
        if self.kind == "undo":
            return [undo(Move("base", self.name), config, anchor, made(self.name, anchor))]
        structure, params = config.structure, config.params
        if self.name == "other braking law":
            return [replace(config, structure=replace(structure, regen=not structure.regen))]
        if self.name == "no drive saturation":
            return [replace(config, params=replace(params, esc_v_sat_v=math.inf))]
        lag = config.effect("esc_lag")
        if self.name == "second ESC stage" and lag is not None:
            return [
                set_effect(
                    replace(config, structure=replace(structure, esc_tau2_s=f * lag.tau_s)),
                    make_effect("esc_lag", {"tau_s": (1.0 - f) * lag.tau_s}),
                )
                for f in SECOND_STAGE
            ]
        return [config]


UNDONE = {
    "second ESC stage": ("structure.esc_tau2_s",),
    "other braking law": ("structure.regen",),
    "no drive saturation": ("params.esc_v_sat_v",),
    "drive losses": ("params.esc_v_sat_v", "params.r_speed_ohm_s", "structure.i_idle_per_krpm_a"),
    "refit winding loss": ("params.r_speed_ohm_s",),
    "widen bounds": tuple(f"params.{n}" for n in BASE_FIT),
}
"""What a base change changes: the terms ``undo`` takes back."""


def made(change: str, anchor: SimConfig) -> tuple[str, ...]:
    """The terms base change ``change`` sets or frees on ``anchor``: ``UNDONE``'s, of the drive
    losses those the anchor lacks."""
    return lacking_drive_losses(anchor) if change == "drive losses" else UNDONE[change]


def undo(
    move: Move, config: SimConfig, before: SimConfig, keys: tuple[str, ...] | None = None
) -> SimConfig:
    """``config`` (fitted with ``move``, an addition or a base change) with what the move
    changed (``keys``, default ``UNDONE``'s) taken back to ``before`` (the model it was made
    on): where the two differ is where the move acts."""
    if move.kind == "add":
        return without_effects(config, (move.name,))
    if move.kind == "joint":
        base, effect = move.parts
        return undo(base, undo(effect, config, before), before)
    keys = UNDONE[move.name] if keys is None else keys
    params = {
        k.split(".")[1]: getattr(before.params, k.split(".")[1])
        for k in keys
        if k.startswith("params.")
    }
    structure = {
        k.split(".")[1]: getattr(before.structure, k.split(".")[1])
        for k in keys
        if k.startswith("structure.")
    }
    out = replace(config, params=replace(config.params, **params))
    out = replace(out, structure=replace(out.structure, **structure))
    lag = config.effect("esc_lag")
    if move.name == "second ESC stage" and lag is not None:  # the cascade's mean delay kept
        tau = lag.tau_s + config.structure.esc_tau2_s
        out = set_effect(out, make_effect("esc_lag", {"tau_s": tau}))
    return out


def at_bound(config: SimConfig, anchor: SimConfig, ranges: dict[str, float]) -> list[str]:
    """Base parameters (``params.NAME``) of ``config`` within 5 % of their bound around
    ``anchor``: ``BASE_RANGE``, or their factor in ``ranges`` (``i_idle_a`` has physical
    bounds)."""
    out = []
    for name in (n for n in BASE_FIT if n != "i_idle_a"):
        key = f"params.{name}"
        ratio = abs(math.log(getattr(config.params, name) / getattr(anchor.params, name)))
        if ratio >= math.log(ranges.get(key, BASE_RANGE) / 1.05):
            out.append(key)
    return out


def available(spec: Spec, fitted: SimConfig, anchor: SimConfig) -> list[Move]:
    """Every move that may be made to ``spec`` (calibrated as ``fitted``): each absent effect
    (a start effect removed before included: what a backward step took out while another
    effect was missing may be wanted back), and each base change not made and meaningful for
    this model."""
    moves = [Move("add", n) for n in EFFECTS if fitted.effect(n) is None]
    done = set(spec.changes)
    possible = {
        "widen bounds": bool(at_bound(fitted, anchor, spec.ranges)),
        "second ESC stage": fitted.effect("esc_lag") is not None
        and fitted.structure.esc_tau2_s == 0.0,
        "other braking law": True,
        "no drive saturation": math.isfinite(fitted.params.esc_v_sat_v),
        "drive losses": bool(lacking_drive_losses(anchor)),
        "refit winding loss": anchor.params.r_speed_ohm_s > 0.0,
    }
    moves += [Move("base", n) for n in BASE_CHANGES if possible[n] and n not in done]
    moves += [
        Move("joint", effect)
        for effect, change in JOINT.items()
        if possible[change] and change not in done and fitted.effect(effect) is None
    ]
    return moves


def cold(config: SimConfig, anchor: SimConfig) -> SimConfig:
    """``config`` with the anchor's base parameters: the second origin of every re-fit. A
    calibration without a missing effect distorts the base to make up for it, and from there
    the true effect can fit worse than none."""
    values = {n: getattr(anchor.params, n) for n in BASE_FIT}
    return replace(config, params=replace(config.params, **values))
