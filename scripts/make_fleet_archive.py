#!/usr/bin/env python3
"""Write a synthetic fleet archive from the simulator (docs/fleet.md): vehicles x thrusters x
days, a few thrusters fouling slowly over the weeks, one losing a blade on a given day, one
recording damaged.

Layout: ``OUT/<vehicle>/<vehicle>_<YYYYMMDD>T<HHMMSS>.mcap``, one MCAP recording per vehicle and
day with every thruster's ``EscTelemetry`` (``core.traces.mcap_io.write_trace_mcap``), stamped
in calendar time (ns since the epoch; the vehicle id is the folder name). Each thruster is one
simulated t100 unit (its own seed, the same unit every day) on a ``mission`` command signal drawn
afresh each day. ``OUT/manifest.json`` says what was simulated: per recording and thruster the
condition, the fouling severity, the blade loss, and which recording was damaged.

    python scripts/make_fleet_archive.py /tmp/fleet --vehicles 2 --thrusters 3 --days 10
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from thruster_fdd.core.traces.data import Trace
from thruster_fdd.core.traces.mcap_io import write_trace_mcap
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator, simulate
from thruster_fdd_shore.core.sim.plant import severity_spec
from thruster_fdd_shore.core.sim.signals import make_signal


def _unit(spec: str) -> tuple[int, int]:
    vehicle, _, thruster = spec.partition("/")
    return int(vehicle), int(thruster)


def blade_trace(
    config: object, t: np.ndarray, command: np.ndarray, seed: int, fault_at_s: float
) -> Trace:
    """A healthy unit that loses one blade at ``fault_at_s`` (s after the trace's start)."""
    sim = ThrusterSimulator(config, "nominal_15v", seed=seed)  # type: ignore[arg-type]
    rows, previous = [], t[0]
    for ti, ci in zip(t.tolist(), command.tolist(), strict=True):
        if ti - t[0] >= fault_at_s and sim.condition != "broken_blade_1":
            sim.set_condition("broken_blade_1")
        s = sim.step(ci, ti - previous)
        previous = ti
        rows.append((s.command, s.voltage, s.rpm, s.current, s.temperature))
    out = np.array(rows)
    labels = np.where(t - t[0] >= fault_at_s, "broken_blade_1", "nominal_15v").astype(object)
    return Trace(
        t=t.copy(),
        command=out[:, 0],
        voltage=out[:, 1],
        rpm=out[:, 2],
        current=out[:, 3],
        extra={"temperature": out[:, 4]},
        labels=labels,
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="archive folder to write (created)")
    p.add_argument("--vehicles", type=int, default=2, help="vehicles (auv01, auv02, ...)")
    p.add_argument("--thrusters", type=int, default=3, help="thrusters per vehicle (t0, t1, ...)")
    p.add_argument("--days", type=int, default=10, help="recordings per vehicle, one a day")
    p.add_argument("--every", type=int, default=2, help="calendar days between recordings")
    p.add_argument("--duration", type=float, default=120.0, help="length of a recording, s")
    p.add_argument("--rate", type=float, default=10.0, help="telemetry rate, Hz")
    p.add_argument("--start", default="2026-03-02", help="date of the first recording (UTC)")
    p.add_argument("--preset", default="t100", help="simulator preset of every thruster")
    p.add_argument(
        "--fouling",
        nargs="*",
        default=["0/1", "1/0"],
        metavar="V/T",
        help="units (vehicle index/thruster index) fouling linearly from 0 to --max-fouling",
    )
    p.add_argument("--max-fouling", type=float, default=1.2, help="fouling on the last day")
    p.add_argument("--blade", default="1/2", metavar="V/T", help="unit that loses a blade")
    p.add_argument("--blade-day", type=int, default=5, help="recording index of the blade loss")
    p.add_argument("--damaged", default="0@3", metavar="V@DAY", help="recording to damage")
    p.add_argument("--seed", type=int, default=0, help="base seed of units and signals")
    args = p.parse_args(argv)
    config = load_config(args.preset)
    fouling = {_unit(u) for u in args.fouling}
    blade = _unit(args.blade) if args.blade else None
    dv, _, dd = args.damaged.partition("@") if args.damaged else ("", "", "")
    damaged = (int(dv), int(dd)) if args.damaged else None
    start = datetime.fromisoformat(args.start).replace(tzinfo=UTC)
    manifest: dict = {"preset": args.preset, "rate_hz": args.rate, "recordings": []}
    for v in range(args.vehicles):
        vehicle = f"auv{v + 1:02d}"
        for day in range(args.days):
            when = start + timedelta(days=day * args.every, hours=8, minutes=17 * v)
            epoch_s = when.timestamp()
            traces, truth = [], {}
            for k in range(args.thrusters):
                tid = f"t{k}"
                unit_seed = args.seed + 100 * v + k
                t, command = make_signal(
                    "mission", args.duration, args.rate, seed=args.seed + 7919 * v + 97 * k + day
                )
                severity = 0.0
                if (v, k) in fouling and args.days > 1:
                    severity = args.max_fouling * day / (args.days - 1)
                if blade == (v, k) and day == args.blade_day:
                    trace = blade_trace(config, t, command, unit_seed, 0.5 * args.duration)
                    truth[tid] = {
                        "condition": "broken_blade_1",
                        "blade_lost_at_s": 0.5 * args.duration,
                    }
                elif blade == (v, k) and day > args.blade_day:
                    trace = simulate(config, t, command, "broken_blade_1", seed=unit_seed)
                    truth[tid] = {"condition": "broken_blade_1"}
                else:
                    label = "biofouling" if severity >= 0.5 else "nominal_15v"
                    spec = severity_spec("fouling", severity) if severity > 0 else None
                    trace = simulate(config, t, command, label, seed=unit_seed, spec=spec)
                    truth[tid] = {"condition": label, "fouling": severity}
                traces.append(replace(trace, t=trace.t + epoch_s, thruster_id=tid))
            path = args.out / vehicle / f"{vehicle}_{when:%Y%m%dT%H%M%S}.mcap"
            path.parent.mkdir(parents=True, exist_ok=True)
            write_trace_mcap(traces, path, origin_ns=0)
            is_damaged = damaged == (v, day)
            if is_damaged:  # not MCAP any more: the scan must make it an error row
                with path.open("r+b") as f:
                    f.write(b"\x00DAMAGED")
            manifest["recordings"].append(
                {
                    "recording": path.relative_to(args.out).as_posix(),
                    "vehicle": vehicle,
                    "day": day,
                    "date": f"{when:%Y-%m-%d}",
                    "damaged": is_damaged,
                    "thrusters": truth,
                }
            )
    (args.out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    n = len(manifest["recordings"])
    print(f"{args.out}: {n} recordings, {args.vehicles} vehicles x {args.thrusters} thrusters")
    return 0


if __name__ == "__main__":
    sys.exit(main())
