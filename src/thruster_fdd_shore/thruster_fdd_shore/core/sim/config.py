"""Simulator configuration: base thruster parameters, effects, measurement, unit spread; YAML I/O.

YAML layout (see docs/simulator.md)::

    name: t100
    spread: 0.03
    params: {k_e: ..., r_ohm: ..., ...}
    effects: {dead_time: {delay_s: 0.55}, deadband: {width: 0.0625}, ...}
    measurement: {rpm_noise: ..., ...}
    structure: {esc_tau2_s: 0.1, i_idle_per_krpm_a: 0.05, regen: false}   # optional
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import asdict, dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.safe_yaml import load_yaml
from thruster_fdd_shore.core.sim.effects import EFFECTS, Effect, canonical_order, make_effect

_PRESETS = ("t100", "t200")


def _check_number(owner: str, name: str, value: Any, *, positive: bool = False) -> None:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or math.isnan(value):
        raise BadInputError(f"{owner}.{name} must be a number, got {value!r}")
    if positive and value <= 0:
        raise BadInputError(f"{owner}.{name} must be > 0, got {value}")
    if value < 0:
        raise BadInputError(f"{owner}.{name} must be >= 0, got {value}")


@dataclass(frozen=True)
class ThrusterParams:
    """Base physical parameters of one thruster (motor, ESC drive, propeller, thermal).

    Attributes
    ----------
    k_e : float
        Back-EMF constant, V s/rad; equals the torque constant k_t in N m/A.
    r_ohm : float
        Effective motor plus ESC resistance at standstill, ohm.
    r_speed_ohm_s : float
        Speed-proportional resistance (commutation voltage drop), ohm s/rad; R = r_ohm + this |w|.
    esc_v_sat_v : float
        ESC drive-loss voltage scale, V: the drive sees V_bus / (1 + V_bus / esc_v_sat_v);
        ``inf`` means a lossless drive.
    inertia : float
        Rotor, propeller and entrained water inertia J, kg m^2.
    k_q : float
        Propeller torque coefficient in forward, N m s^2/rad^2 (torque k_q w|w|).
    k_q_reverse_ratio : float
        Multiplier of k_q in reverse.
    k_thrust : float
        Thrust coefficient in forward, N s^2/rad^2 (thrust k_thrust w|w|).
    reverse_thrust_ratio : float
        Multiplier of k_thrust in reverse (< 1: reverse is less efficient).
    i_idle_a : float
        ESC idle bus current, A.
    water_temp_c : float
        Water temperature, C (initial and ambient winding temperature).
    thermal_resistance_c_per_w : float
        Winding temperature rise per W of resistive loss at steady state, C/W.
    thermal_tau_s : float
        Winding thermal time constant, s.
    """

    k_e: float
    r_ohm: float
    r_speed_ohm_s: float
    esc_v_sat_v: float
    inertia: float
    k_q: float
    k_q_reverse_ratio: float
    k_thrust: float
    reverse_thrust_ratio: float
    i_idle_a: float
    water_temp_c: float = 15.0
    thermal_resistance_c_per_w: float = 0.5
    thermal_tau_s: float = 60.0

    def __post_init__(self) -> None:
        positive = {"k_e", "r_ohm", "esc_v_sat_v", "inertia", "k_q", "k_q_reverse_ratio"}
        positive |= {"thermal_tau_s"}
        for f in fields(self):
            if f.name != "water_temp_c":
                _check_number("params", f.name, getattr(self, f.name), positive=f.name in positive)
        if not math.isfinite(self.water_temp_c):
            raise BadInputError(f"params.water_temp_c must be finite, got {self.water_temp_c}")


@dataclass(frozen=True)
class Measurement:
    """Telemetry measurement model: noise, quantisation, outliers and reporting floor.

    Attributes
    ----------
    rpm_noise, current_noise_a, voltage_noise_v : float
        Gaussian noise standard deviation (rpm, A, V).
    rpm_step, current_step_a, voltage_step_v : float
        Quantisation step (rpm, A, V); 0 disables.
    outlier_prob : float
        Probability per sample and channel of a spike.
    outlier_rpm, outlier_current_a, outlier_voltage_v : float
        Spike size (random sign) per channel (rpm, A, V).
    rpm_floor : float
        Speeds with ``|rpm| < rpm_floor`` are reported as 0 (sensor cannot see slow rotation).
    floor_zeroes_current : bool
        Also report current 0 when the speed is under the floor (as in the T200 workbook).
    """

    rpm_noise: float = 0.0
    current_noise_a: float = 0.0
    voltage_noise_v: float = 0.0
    rpm_step: float = 0.0
    current_step_a: float = 0.0
    voltage_step_v: float = 0.0
    outlier_prob: float = 0.0
    outlier_rpm: float = 0.0
    outlier_current_a: float = 0.0
    outlier_voltage_v: float = 0.0
    rpm_floor: float = 0.0
    floor_zeroes_current: bool = False

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name != "floor_zeroes_current":
                _check_number("measurement", f.name, getattr(self, f.name))
        if not isinstance(self.floor_zeroes_current, bool):
            raise BadInputError("measurement.floor_zeroes_current must be true or false")
        if self.outlier_prob > 1:
            raise BadInputError(f"measurement.outlier_prob must be <= 1, got {self.outlier_prob}")


@dataclass(frozen=True)
class Structure:
    """Structural switches of the physics beyond the reference; the defaults are the reference.

    Laws rather than values of one unit: ``perturb_unit`` leaves them as they are.

    Attributes
    ----------
    esc_tau2_s : float
        Time constant of a second ESC stage in cascade behind ``esc_lag``, s: 0 keeps the
        first-order response, > 0 makes it second order (two real poles).
    i_idle_per_krpm_a : float
        Growth of the ESC's idle bus current with speed, A per 1000 rpm (switching and
        commutation losses drawn from the bus): ``I = d i_m + i_idle_a + this |rpm| / 1000``.
    regen : bool
        True (reference): while the motor generates (``d i_m < 0``, braking under drive) its
        current flows back to the bus. False: the ESC lets it coast instead (no motor torque,
        no current back, bus current at the idle level), as ESCs without active braking do.
    """

    esc_tau2_s: float = 0.0
    i_idle_per_krpm_a: float = 0.0
    regen: bool = True

    def __post_init__(self) -> None:
        for name in ("esc_tau2_s", "i_idle_per_krpm_a"):
            _check_number("structure", name, getattr(self, name))
            if not math.isfinite(getattr(self, name)):
                raise BadInputError(f"structure.{name} must be finite, got {getattr(self, name)}")
        if not isinstance(self.regen, bool):
            raise BadInputError("structure.regen must be true or false")


@dataclass(frozen=True)
class SimConfig:
    """A complete simulator configuration.

    Attributes
    ----------
    name : str
        Human-readable name (the preset name for presets).
    params : ThrusterParams
        Base physical parameters of the nominal unit.
    effects : tuple of Effect
        Present effects, kept in signal-path order; absent effects are simply not in the tuple.
    measurement : Measurement
        Telemetry measurement model.
    spread : float
        Unit-to-unit spread: relative standard deviation applied by seed to every physical
        parameter (0 gives the nominal unit).
    structure : Structure
        Structural switches of the physics (defaults: the reference physics).
    """

    name: str
    params: ThrusterParams
    effects: tuple[Effect, ...] = ()
    measurement: Measurement = field(default_factory=Measurement)
    spread: float = 0.0
    structure: Structure = field(default_factory=Structure)

    def __post_init__(self) -> None:
        object.__setattr__(self, "effects", canonical_order(tuple(self.effects)))
        _check_number("config", "spread", self.spread)
        if self.spread > 0.2:
            raise BadInputError(f"config.spread must be <= 0.2 (a fraction), got {self.spread}")

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the present effects, in signal-path order."""
        return tuple(e.name for e in self.effects)

    def effect(self, name: str) -> Effect | None:
        """Return the effect called ``name``, or None if absent (ValueError if not a name)."""
        if name not in EFFECTS:
            raise BadInputError(f"unknown effect {name!r}; expected one of {', '.join(EFFECTS)}")
        return next((e for e in self.effects if e.name == name), None)


def add_effect(config: SimConfig, effect: Effect) -> SimConfig:
    """Return a copy of ``config`` with ``effect`` added (ValueError if already present)."""
    if config.effect(effect.name) is not None:
        raise BadInputError(f"effect {effect.name!r} is already present; use replace_effect")
    return replace(config, effects=(*config.effects, effect))


def remove_effect(config: SimConfig, name: str) -> SimConfig:
    """Return a copy of ``config`` without effect ``name`` (ValueError if absent)."""
    if config.effect(name) is None:
        raise BadInputError(f"effect {name!r} is not present in config {config.name!r}")
    return replace(config, effects=tuple(e for e in config.effects if e.name != name))


def replace_effect(config: SimConfig, effect: Effect) -> SimConfig:
    """Return a copy of ``config`` with the same-named effect replaced (ValueError if absent)."""
    return add_effect(remove_effect(config, effect.name), effect)


def set_effect(config: SimConfig, effect: Effect) -> SimConfig:
    """Return a copy of ``config`` with ``effect`` added, or replacing the same-named one."""
    if config.effect(effect.name) is None:
        return add_effect(config, effect)
    return replace_effect(config, effect)


def without_effects(config: SimConfig, names: Collection[str]) -> SimConfig:
    """``config`` without the effects ``names``; without ``esc_lag`` also without a second ESC
    stage (a fraction of it, it would become the lag)."""
    config = replace(config, effects=tuple(e for e in config.effects if e.name not in names))
    if "esc_lag" in names and config.structure.esc_tau2_s > 0.0:
        config = replace(config, structure=replace(config.structure, esc_tau2_s=0.0))
    return config


def perturb_unit(config: SimConfig, seed: int) -> SimConfig:
    """Draw one unit: every physical parameter times ``1 + spread * z``, z ~ N(0, 1) clipped.

    Parameters
    ----------
    config : SimConfig
        The nominal configuration; its ``spread`` sets the relative standard deviation.
    seed : int
        Unit seed; the same seed gives the same unit.

    Returns
    -------
    SimConfig
        The unit's configuration, with ``spread`` 0. Temperatures and the measurement model are
        not perturbed.
    """
    if config.spread == 0.0:
        return config
    rng = np.random.default_rng([int(seed), 0x5EED])
    unperturbed = {"water_temp_c"}

    def factor() -> float:
        return 1.0 + config.spread * float(np.clip(rng.standard_normal(), -2.5, 2.5))

    p = config.params
    new_params = replace(
        p, **{f.name: getattr(p, f.name) * factor() for f in fields(p) if f.name not in unperturbed}
    )
    new_effects = []
    for effect in config.effects:
        values = {k: v * factor() for k, v in effect.params().items()}
        if effect.name == "deadband":
            values["width"] = min(values["width"], 0.99)
        new_effects.append(make_effect(effect.name, values))
    return replace(config, params=new_params, effects=tuple(new_effects), spread=0.0)


def preset_names() -> tuple[str, ...]:
    """Names of the packaged presets."""
    return _PRESETS


def config_from_dict(data: Any, *, origin: str = "config") -> SimConfig:
    """Build a configuration from the YAML mapping layout (ValueError with the reason if bad)."""
    if not isinstance(data, dict):
        raise BadInputError(f"{origin}: expected a mapping with name, params, effects, measurement")
    unknown = sorted(
        set(data) - {"name", "params", "effects", "measurement", "spread", "structure"}
    )
    if unknown:
        raise BadInputError(f"{origin}: unknown top-level key(s) {unknown}")
    if "params" not in data or not isinstance(data["params"], dict):
        raise BadInputError(f"{origin}: 'params' mapping is required")
    effects_data = data.get("effects") or {}
    if not isinstance(effects_data, dict):
        raise BadInputError(f"{origin}: 'effects' must map effect names to parameter mappings")
    for key in ("measurement", "structure"):
        if not isinstance(data.get(key) or {}, dict):
            raise BadInputError(f"{origin}: {key!r} must be a mapping")
    try:
        params = ThrusterParams(**data["params"])
        measurement = Measurement(**(data.get("measurement") or {}))
        structure = Structure(**(data.get("structure") or {}))
    except TypeError as exc:
        raise BadInputError(f"{origin}: {exc}") from exc
    effects = tuple(
        make_effect(str(name), values if isinstance(values, dict) else {})
        for name, values in effects_data.items()
    )
    return SimConfig(
        name=str(data.get("name", origin)),
        params=params,
        effects=effects,
        measurement=measurement,
        spread=float(data.get("spread", 0.0)),
        structure=structure,
    )


def config_to_dict(config: SimConfig) -> dict[str, Any]:
    """Return the YAML mapping layout of ``config`` (inverse of ``config_from_dict``).

    ``structure`` is written only when it differs from the reference physics.
    """
    out = {
        "name": config.name,
        "spread": float(config.spread),
        "params": {k: float(v) for k, v in asdict(config.params).items()},
        "effects": {e.name: e.params() for e in config.effects},
        "measurement": asdict(config.measurement),
    }
    if config.structure != Structure():
        out["structure"] = asdict(config.structure)
    return out


def load_config(source: str | Path) -> SimConfig:
    """Load a preset by name (``"t100"``, ``"t200"``) or a configuration YAML file.

    Raises
    ------
    ValueError
        If ``source`` is neither a preset name nor a readable, valid configuration file.
    """
    if isinstance(source, str) and source in _PRESETS:
        text = (
            resources.files("thruster_fdd_shore.core.sim") / "presets" / f"{source}.yaml"
        ).read_text()
        origin = f"preset {source}"
    else:
        path = Path(source)
        if not path.is_file():
            raise BadInputError(
                f"{source!r} is neither a preset ({', '.join(_PRESETS)}) nor an existing file"
            )
        # A binary file becomes replacement characters, which the YAML parser refuses by line.
        text = path.read_text(encoding="utf-8", errors="replace")
        origin = str(path)
    try:
        data = load_yaml(text, origin)
    except yaml.YAMLError as exc:
        raise BadInputError(f"{origin}: not valid YAML ({exc})") from exc
    return config_from_dict(data, origin=origin)


def dump_config(config: SimConfig, path: str | Path) -> None:
    """Write ``config`` as YAML that ``load_config`` reads back to an equal configuration.

    Atomic (``core.atomic``): the file appears whole or not at all.
    """
    write_text(path, yaml.safe_dump(config_to_dict(config), sort_keys=False))
