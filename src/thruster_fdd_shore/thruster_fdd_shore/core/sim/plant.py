"""The numbers of one simulated unit in one condition, shared by the reference simulator
(``sim.physics``) and its compiled free run (``sim.freerun``).

``CONDITION_SPECS`` says how each condition changes a healthy unit, ``severity_spec`` a fault of
continuous severity between and beyond them (half a blade, heavy fouling); ``make_plant``
flattens a configuration, a condition and a supply voltage into a ``Plant``, which both
integrators read by field name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from thruster_fdd.core.diagnosis.reference import FAULT_FAMILIES, MAX_SEVERITY
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES
from thruster_fdd_shore.core.sim.config import SimConfig

RAD_S_TO_RPM = 60.0 / (2.0 * math.pi)
"""rad/s -> rpm."""

_OMEGA_REF = 400.0  # rad/s; scale of the extra fouling friction, near full speed


@dataclass(frozen=True)
class ConditionSpec:
    """How a condition changes the healthy unit.

    Attributes
    ----------
    supply_v : float
        Default supply voltage, V.
    k_q_factor : float
        Multiplier of the propeller torque coefficient (load).
    k_thrust_factor : float
        Multiplier of the thrust coefficient.
    friction_frac : float
        Extra friction: Coulomb ``friction_frac * k_q * 400**2`` N m and viscous
        ``friction_frac * k_q * 400`` N m s/rad (fouled shaft and nozzle).
    ripple : float
        Once-per-revolution load torque ripple, as a fraction of the propeller torque.
    """

    supply_v: float
    k_q_factor: float = 1.0
    k_thrust_factor: float = 1.0
    friction_frac: float = 0.0
    ripple: float = 0.0


CONDITION_SPECS: dict[str, ConditionSpec] = {
    "nominal_15v": ConditionSpec(15.0),
    "nominal_13v": ConditionSpec(13.0),
    "nominal_11v8": ConditionSpec(11.8),
    # Losing blades removes load (faster, less current) and unbalances the rotor (ripple).
    "broken_blade_1": ConditionSpec(15.0, k_q_factor=0.72, k_thrust_factor=0.65, ripple=0.12),
    "broken_blade_2": ConditionSpec(15.0, k_q_factor=0.45, k_thrust_factor=0.35, ripple=0.3),
    # Growth adds drag and friction (slower, more current) and spoils the blade profile.
    "biofouling": ConditionSpec(15.0, k_q_factor=1.35, k_thrust_factor=0.8, friction_frac=0.03),
}
"""Condition name (``labels.CLASS_NAMES``) -> its effect on the unit."""

if set(CONDITION_SPECS) != set(CLASS_NAMES):
    raise RuntimeError("CONDITION_SPECS must cover exactly labels.CLASS_NAMES")


SEVERITY_SWEEP: dict[str, tuple[str, float]] = {
    "half_blade": ("blades", 0.5),
    "one_blade": ("blades", 1.0),
    "one_and_half_blades": ("blades", 1.5),
    "two_blades": ("blades", 2.0),
    "light_fouling": ("fouling", 0.5),
    "fouling": ("fouling", 1.0),
    "heavy_fouling": ("fouling", 1.5),
    "very_heavy_fouling": ("fouling", 2.0),
}
"""Named faults between and beyond the classes: name -> (family, severity)."""


def severity_spec(family: str, severity: float, supply_v: float = 15.0) -> ConditionSpec:
    """A fault of continuous severity, interpolated through the classes' specs.

    Parameters
    ----------
    family : str
        ``"blades"``: severity is the number of blades lost, 0..2 (0.5: half a blade), piecewise
        linear through ``nominal_15v``, ``broken_blade_1`` and ``broken_blade_2``.
        ``"fouling"``: severity 0..2 in units of the ``biofouling`` class (0.5 light, 1.5
        heavy), every factor linear in it.
    severity : float
        0 is the healthy unit; at most ``MAX_SEVERITY``.
    supply_v : float
        Supply voltage of the spec, V.

    Raises
    ------
    BadInputError
        For another family or a severity outside [0, ``MAX_SEVERITY``].
    """
    if family not in FAULT_FAMILIES:
        raise BadInputError(f"unknown fault family {family!r}; expected one of {FAULT_FAMILIES}")
    if not (math.isfinite(severity) and 0.0 <= severity <= MAX_SEVERITY):
        raise BadInputError(f"severity must be in [0, {MAX_SEVERITY:g}], got {severity}")
    if family == "blades":
        ladder = [CONDITION_SPECS[c] for c in ("nominal_15v", "broken_blade_1", "broken_blade_2")]
        i = min(int(severity), 1)
        lo, hi, f = ladder[i], ladder[i + 1], severity - i
    else:
        lo, hi, f = CONDITION_SPECS["nominal_15v"], CONDITION_SPECS["biofouling"], severity
    return ConditionSpec(
        supply_v,
        k_q_factor=lo.k_q_factor + f * (hi.k_q_factor - lo.k_q_factor),
        k_thrust_factor=lo.k_thrust_factor + f * (hi.k_thrust_factor - lo.k_thrust_factor),
        friction_frac=lo.friction_frac + f * (hi.friction_frac - lo.friction_frac),
        ripple=lo.ripple + f * (hi.ripple - lo.ripple),
    )


def condition_spec(condition: str) -> ConditionSpec:
    """The ``ConditionSpec`` of a class name; BadInputError naming the classes for another name."""
    if condition not in CONDITION_SPECS:
        raise BadInputError(
            f"unknown condition {condition!r}; expected one of {', '.join(CONDITION_SPECS)}"
        )
    return CONDITION_SPECS[condition]


def check_voltage(voltage: float | None) -> None:
    """BadInputError unless ``voltage`` is None or a supply voltage in (0, 60] V."""
    if voltage is not None and not (math.isfinite(voltage) and 0.0 < voltage <= 60.0):
        raise BadInputError(f"supply voltage must be in (0, 60] V, got {voltage}")


class Plant(NamedTuple):
    """Flattened numbers of one unit in one condition, in SI units.

    A named tuple of floats, so the compiled free run (``sim.freerun``) takes it as it is and
    reads the same field names as the Python integrator. The last three come from
    ``SimConfig.structure``: ``tau2`` (s, second ESC stage; 0 none), ``i_idle_speed`` (idle
    current growth, A s/rad) and ``regen`` (1.0 regenerative braking, 0.0 coasting).
    """

    k_e: float
    r_ohm: float
    r_speed: float
    v_sat: float
    inertia: float
    k_q: float
    k_q_rev: float
    k_thrust: float
    k_thrust_rev: float
    i_idle: float
    coulomb: float
    viscous: float
    ripple: float
    delay: float
    width: float
    tau: float
    slew: float
    r_int: float
    i_max: float
    v_supply: float
    tau2: float
    i_idle_speed: float
    regen: float


def make_plant(unit: SimConfig, spec: ConditionSpec, voltage: float | None) -> Plant:
    """The ``Plant`` of ``unit`` in the condition ``spec`` at ``voltage`` V (None: the spec's)."""
    p = unit.params
    eff = {e.name: e for e in unit.effects}
    k_q = p.k_q * spec.k_q_factor
    k_t = p.k_thrust * spec.k_thrust_factor

    def get(name: str, attr: str, default: float) -> float:
        return float(getattr(eff[name], attr)) if name in eff else default

    return Plant(
        k_e=p.k_e,
        r_ohm=p.r_ohm,
        r_speed=p.r_speed_ohm_s,
        v_sat=p.esc_v_sat_v,
        inertia=p.inertia,
        k_q=k_q,
        k_q_rev=k_q * p.k_q_reverse_ratio,
        k_thrust=k_t,
        k_thrust_rev=k_t * p.reverse_thrust_ratio,
        i_idle=p.i_idle_a,
        coulomb=get("coulomb_friction", "torque_nm", 0.0)
        + spec.friction_frac * k_q * _OMEGA_REF**2,
        viscous=get("viscous_friction", "coeff", 0.0) + spec.friction_frac * k_q * _OMEGA_REF,
        ripple=spec.ripple,
        delay=get("dead_time", "delay_s", 0.0),
        width=get("deadband", "width", 0.0),
        tau=get("esc_lag", "tau_s", 0.0),
        slew=get("slew_rate_limit", "rate_per_s", math.inf),
        r_int=get("voltage_sag", "r_internal_ohm", 0.0),
        i_max=get("current_limit", "i_max_a", math.inf),
        v_supply=spec.supply_v if voltage is None else float(voltage),
        tau2=unit.structure.esc_tau2_s,
        i_idle_speed=unit.structure.i_idle_per_krpm_a * RAD_S_TO_RPM / 1000.0,
        regen=1.0 if unit.structure.regen else 0.0,
    )


def limited_duty(pl: Plant, d: float, ve: float, w: float, reff: float) -> float:
    """Duty of the same sign as ``d`` at which the bus current equals ``pl.i_max``.

    Plain arithmetic on floats: the reference integrator calls it, and ``sim.freerun`` compiles
    the same function for its kernel.
    """
    idle = pl.i_idle + pl.i_idle_speed * abs(w)
    disc = (pl.k_e * w) ** 2 + 4.0 * ve * reff * (pl.i_max - idle)
    root = math.sqrt(max(disc, 0.0))
    return (pl.k_e * w + math.copysign(root, d)) / (2.0 * ve)
