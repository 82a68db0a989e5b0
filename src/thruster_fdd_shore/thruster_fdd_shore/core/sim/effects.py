"""Named, parameterised simulator effects (docs/contracts.md, "Canonical names").

Each effect is a frozen dataclass holding its parameters; a configuration holds a tuple of them.
The discrepancy workflow reports missing effects with exactly these names and parameters, so the
registry ``EFFECTS`` is the single source of both.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import ClassVar

from thruster_fdd.core.errors import BadInputError


@dataclass(frozen=True)
class Effect:
    """Base class of all effects; ``name`` is the canonical effect name."""

    name: ClassVar[str] = ""

    def params(self) -> dict[str, float]:
        """Return the effect's parameters as ``{parameter name: value}``."""
        return {k: float(v) for k, v in asdict(self).items()}

    def _check(
        self, field_name: str, *, positive: bool = False, upper: float | None = None
    ) -> None:
        value = getattr(self, field_name)
        if (
            not isinstance(value, (int, float))
            or isinstance(value, bool)
            or not math.isfinite(value)
        ):
            raise BadInputError(f"{self.name}.{field_name} must be a finite number, got {value!r}")
        if positive and value <= 0:
            raise BadInputError(f"{self.name}.{field_name} must be > 0, got {value}")
        if value < 0:
            raise BadInputError(f"{self.name}.{field_name} must be >= 0, got {value}")
        if upper is not None and value >= upper:
            raise BadInputError(f"{self.name}.{field_name} must be < {upper}, got {value}")


@dataclass(frozen=True)
class DeadTime(Effect):
    """Pure transport delay between command and ESC.

    Attributes
    ----------
    delay_s : float
        Delay in s, >= 0.
    """

    name: ClassVar[str] = "dead_time"
    delay_s: float

    def __post_init__(self) -> None:
        self._check("delay_s")


@dataclass(frozen=True)
class Deadband(Effect):
    """ESC deadband: ``|u| <= width`` gives zero duty; outside, rescaled to reach 1 at ``|u| = 1``.

    Attributes
    ----------
    width : float
        Half-width in normalised command units (25 us of PWM = 0.0625), in [0, 1).
    """

    name: ClassVar[str] = "deadband"
    width: float

    def __post_init__(self) -> None:
        self._check("width", upper=1.0)


@dataclass(frozen=True)
class EscLag(Effect):
    """First-order lag of the applied duty behind the command.

    Attributes
    ----------
    tau_s : float
        Time constant in s, > 0.
    """

    name: ClassVar[str] = "esc_lag"
    tau_s: float

    def __post_init__(self) -> None:
        self._check("tau_s", positive=True)


@dataclass(frozen=True)
class SlewRateLimit(Effect):
    """Maximum change of the applied duty per second.

    Attributes
    ----------
    rate_per_s : float
        Duty change per s (full scale is 1), > 0.
    """

    name: ClassVar[str] = "slew_rate_limit"
    rate_per_s: float

    def __post_init__(self) -> None:
        self._check("rate_per_s", positive=True)


@dataclass(frozen=True)
class CoulombFriction(Effect):
    """Constant friction torque opposing rotation (with stiction at rest).

    Attributes
    ----------
    torque_nm : float
        Friction torque in N m, >= 0.
    """

    name: ClassVar[str] = "coulomb_friction"
    torque_nm: float

    def __post_init__(self) -> None:
        self._check("torque_nm")


@dataclass(frozen=True)
class ViscousFriction(Effect):
    """Friction torque proportional to speed.

    Attributes
    ----------
    coeff : float
        N m s/rad, >= 0.
    """

    name: ClassVar[str] = "viscous_friction"
    coeff: float

    def __post_init__(self) -> None:
        self._check("coeff")


@dataclass(frozen=True)
class VoltageSag(Effect):
    """Bus voltage drop through the supply's internal resistance.

    Attributes
    ----------
    r_internal_ohm : float
        Supply plus wiring resistance in ohm, >= 0.
    """

    name: ClassVar[str] = "voltage_sag"
    r_internal_ohm: float

    def __post_init__(self) -> None:
        self._check("r_internal_ohm")


@dataclass(frozen=True)
class CurrentLimit(Effect):
    """ESC reduces duty so the bus current stays at or below a limit.

    Attributes
    ----------
    i_max_a : float
        Bus current limit in A, > 0.
    """

    name: ClassVar[str] = "current_limit"
    i_max_a: float

    def __post_init__(self) -> None:
        self._check("i_max_a", positive=True)


EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (
        DeadTime,
        Deadband,
        EscLag,
        SlewRateLimit,
        CoulombFriction,
        ViscousFriction,
        VoltageSag,
        CurrentLimit,
    )
}
"""Effect name -> class, in signal-path order (the order configurations keep them in)."""


def make_effect(name: str, params: Mapping[str, float]) -> Effect:
    """Build an effect from its canonical name and a parameter mapping.

    Raises
    ------
    ValueError
        If the name is unknown, a parameter is missing or unknown, or a value is invalid.
    """
    if name not in EFFECTS:
        raise BadInputError(f"unknown effect {name!r}; expected one of {', '.join(EFFECTS)}")
    cls = EFFECTS[name]
    expected = [f.name for f in fields(cls)]
    unknown = sorted(set(params) - set(expected))
    missing = [p for p in expected if p not in params]
    if unknown or missing:
        raise BadInputError(
            f"effect {name!r} takes parameter(s) {', '.join(expected)}; "
            f"missing {missing or 'none'}, unknown {unknown or 'none'}"
        )
    try:
        values = {p: float(params[p]) for p in expected}
    except (TypeError, ValueError) as exc:
        raise BadInputError(
            f"effect {name!r}: parameters must be numbers, got {dict(params)}"
        ) from exc
    return cls(**values)


def canonical_order(effects: tuple[Effect, ...]) -> tuple[Effect, ...]:
    """Return ``effects`` sorted in signal-path order.

    Raises
    ------
    ValueError
        If an element is not an effect or a name occurs twice.
    """
    order = list(EFFECTS)
    seen: set[str] = set()
    for effect in effects:
        if not isinstance(effect, Effect) or effect.name not in EFFECTS:
            raise BadInputError(f"not a registered effect: {effect!r}")
        if effect.name in seen:
            raise BadInputError(f"effect {effect.name!r} given twice")
        seen.add(effect.name)
    return tuple(sorted(effects, key=lambda e: order.index(e.name)))
