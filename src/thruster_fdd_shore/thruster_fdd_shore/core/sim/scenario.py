"""A simulation run as ``thruster-fdd simulate`` describes it: signal, condition, fault onset."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator, simulate
from thruster_fdd_shore.core.sim.signals import make_signal
from thruster_fdd_shore.core.traces.csv_io import read_command_csv


def run_scenario(
    source: str | Path,
    condition: str,
    *,
    signal: str = "steps",
    command_csv: Path | None = None,
    duration_s: float = 60.0,
    rate_hz: float = 10.0,
    voltage: float | None = None,
    seed: int = 0,
    thruster_id: str = "t0",
    fault_at_s: float | None = None,
    fault_condition: str | None = None,
) -> Trace:
    """Simulate one thruster and return its labelled trace.

    Parameters
    ----------
    source : str or Path
        Preset name (``t100``, ``t200``) or simulator configuration YAML.
    condition : str
        Condition at start (``labels.CLASS_NAMES``).
    signal : str
        Command signal spec of ``core.sim.signals.make_signal``; ignored with ``command_csv``.
    command_csv : Path or None
        Command history (columns ``t``, ``command``) that replaces ``signal``, ``duration_s``
        and ``rate_hz``: the trace has one row per row of the file.
    duration_s, rate_hz : float
        Length (s) and sample rate (Hz) of the generated signal.
    voltage : float or None
        Supply voltage in V; None uses the condition's.
    seed : int
        Seed of the unit's spread, the noise and random signals.
    thruster_id : str
        Written into the trace.
    fault_at_s, fault_condition : float or None, str or None
        From this time on (s) the thruster is in ``fault_condition``; both or neither.

    Returns
    -------
    Trace
        With ``condition`` (no fault) or per-sample ``labels`` (fault mid-run).

    Raises
    ------
    ValueError
        For an unknown preset, condition or signal, or a fault given by half.
    """
    if (fault_at_s is None) != (fault_condition is None):
        raise BadInputError("a fault needs both --fault-at and --fault-condition")
    config = load_config(source)
    if command_csv is not None:
        t, command = read_command_csv(command_csv)
    else:
        t, command = make_signal(signal, duration_s, rate_hz, seed=seed)
    if fault_at_s is None or fault_condition is None:
        trace = simulate(config, t, command, condition, voltage=voltage, seed=seed)
        return replace(trace, thruster_id=thruster_id)
    sim = ThrusterSimulator(config, condition, voltage=voltage, seed=seed)
    faulty = t >= fault_at_s
    rows = []
    previous = t[0]
    for ti, ci, fi in zip(t.tolist(), command.tolist(), faulty.tolist(), strict=True):
        if fi and sim.condition != fault_condition:
            sim.set_condition(fault_condition)
        s = sim.step(ci, ti - previous)
        previous = ti
        rows.append((s.command, s.voltage, s.rpm, s.current, s.temperature, s.thrust))
    out = np.array(rows, dtype=float)
    labels = np.where(faulty, fault_condition, condition).astype(object)
    return Trace(
        t=np.asarray(t, dtype=float),
        command=out[:, 0],
        voltage=out[:, 1],
        rpm=out[:, 2],
        current=out[:, 3],
        thruster_id=thruster_id,
        extra={"temperature": out[:, 4], "thrust": out[:, 5]},
        labels=None if faulty.all() else labels,
        condition=fault_condition if faulty.all() else None,
    )
