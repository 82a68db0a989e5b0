"""Turn the T200 steady-state workbook (../shared/data/t200) into a trace CSV of command steps.

Each workbook row is one step of the bench procedure (README of the data): from neutral, jump to
the PWM, 1.5 s unlogged, 2 s logged at 10 Hz and averaged, then rest. The trace replays that:
per step one row at the end of a ``--rest`` s rest at command 0 (rpm 0, the workbook's neutral
current), then 21 rows at 1.5-3.5 s after the jump holding the step's averaged values. The
workbook's rpm is unsigned, so it is signed by the command. Sheets (supply voltages) follow each
other in increasing voltage; within a sheet the steps are in a seeded random order, so every part
of the trace covers the whole command range. Rows: every 4 us within +-60 us of neutral (the
zero band), every 16 us elsewhere (``--all`` keeps every 4 us row).

Usage::

    python scripts/t200_to_trace.py --out /tmp/t200_steps.csv [--data ../shared/data/t200]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from calibrate_t200 import DEFAULT_DATA, load_sheets

from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.traces.csv_io import write_trace_csv

SETTLE_S = 1.5
LOGGED_S = 2.0
RATE_HZ = 10.0


def steps_trace(
    folder: Path,
    *,
    rest_s: float = 1.5,
    every: bool = False,
    seed: int = 0,
    spacing_us: float = 16.0,
    voltages: tuple[float, ...] = (),
) -> Trace:
    """Build the step trace from the workbook sheets in ``folder``.

    Returns
    -------
    Trace
        Columns t (s), command (-1..1), voltage (V, the sheet's set-point), rpm (signed), current
        (A); ``extra["pwm_us"]``. Away from neutral, rows every ``spacing_us`` (a multiple of
        4 us); ``voltages`` (non-empty) keeps only those sheets.
    """
    rng = np.random.default_rng(seed)
    rows: list[tuple[float, float, float, float, float, float]] = []
    t = 0.0
    logged = np.arange(round(LOGGED_S * RATE_HZ) + 1) / RATE_HZ
    for sheet in load_sheets(folder):
        if voltages and not any(abs(sheet.voltage - v) < 0.05 for v in voltages):
            continue
        off = np.abs(sheet.pwm_us - 1500.0)
        keep = every | (off <= 60.0) | (np.round(off) % spacing_us == 0.0)
        idx = rng.permutation(np.flatnonzero(keep))
        neutral = int(np.argmin(off))
        for i in idx:
            t += rest_s
            rows.append((t, 0.0, sheet.voltage, 0.0, float(sheet.current[neutral]), 1500.0))
            u = (sheet.pwm_us[i] - 1500.0) / 400.0
            rpm = float(np.sign(u) * sheet.rpm[i])
            for k, dt in enumerate(logged):
                tk = t + SETTLE_S + dt
                rows.append((tk, u, sheet.voltage, rpm, float(sheet.current[i]), sheet.pwm_us[i]))
                if k == len(logged) - 1:
                    t = tk
    a = np.array(rows)
    return Trace(
        t=a[:, 0],
        command=a[:, 1],
        voltage=a[:, 2],
        rpm=a[:, 3],
        current=a[:, 4],
        extra={"pwm_us": a[:, 5]},
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--rest", type=float, default=1.5, help="rest at neutral per step, s")
    parser.add_argument("--all", action="store_true", help="keep every 4 us row")
    parser.add_argument("--spacing", type=float, default=16.0,
                        help="us between kept rows away from neutral (multiple of 4)")  # fmt: skip
    parser.add_argument("--voltages", type=float, nargs="*", default=[],
                        help="keep only these sheets (supply V); default all")  # fmt: skip
    args = parser.parse_args(argv)
    trace = steps_trace(
        args.data,
        rest_s=args.rest,
        every=args.all,
        spacing_us=args.spacing,
        voltages=tuple(args.voltages),
    )
    write_trace_csv(trace, args.out)
    print(f"wrote {len(trace)} rows, {trace.t[-1]:.0f} s, to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
