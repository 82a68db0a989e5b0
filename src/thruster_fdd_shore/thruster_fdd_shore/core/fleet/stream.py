"""A recording's telemetry as one stream of samples, thruster by thruster in time order, with
memory bounded by a window rather than by the recording.

``stream_recording`` gives what ``archive.read_recording`` reads (the shore's ``read_bag`` /
``read_trace_mcap``: the same samples, values and times, the same warnings) one sample at a
time. The whole-recording readers sort each thruster's samples of a file by stamp and keep a
stamp recorded twice once; here a per-thruster reorder buffer does that over a bounded window
(``REORDER_S`` of stamps and at most ``REORDER_MAX`` samples), which is exact while no sample
arrives later than that (a recorder writes in receive order). A sample that arrives later is
left out and counted in a warning. The unit check of ``data.check_units`` needs medians and
percentiles of the whole trace; here it counts the samples beyond each limit instead (a median
above a limit is more than half of the samples above it, a 99th percentile above it more than
1 %), so its decisions agree except at the boundary sample and its messages name the share.
"""

from __future__ import annotations

import heapq
import math
import warnings
from collections.abc import Iterator
from pathlib import Path

from thruster_fdd.core.errors import BadInputError, PartialInputWarning
from thruster_fdd.core.traces.data import (
    MAX_CURRENT_A,
    MAX_MEDIAN_VOLTAGE_V,
    MAX_RPM,
    MAX_STEP_S,
    TraceWarning,
)
from thruster_fdd.core.traces.mcap_io import TelemetryRow, iter_trace_mcap
from thruster_fdd_shore.core.traces.files import bag_files, is_bag

Sample = tuple[str, float, float, float, float, float]
"""One sample of a thruster: id, t (s), command (-1..1), voltage (V), rpm, current (A)."""

REORDER_S = 2.0
"""A sample whose stamp is this much (s) behind the newest of its thruster is put in order."""

REORDER_MAX = 4096
"""Most samples a thruster's reorder buffer holds (about 80 s at 50 Hz)."""

_COLUMNS = ("t", "command", "voltage", "rpm", "current", "temperature")


class _Thruster:
    """One thruster's samples of one file on their way out: finite filter, reorder buffer,
    unit counts (the state ``read_trace_mcap``'s ``_trace`` keeps as whole arrays)."""

    def __init__(self) -> None:
        self.offered = 0  # samples read, finite or not
        self.non_finite = 0
        self.first_bad = -1  # index of the first non-finite sample
        self.bad_columns: set[str] = set()
        self.heap: list[tuple[float, int, TelemetryRow]] = []
        self.newest = -math.inf
        self.last = -math.inf  # stamp of the last sample handed out
        self.late = 0
        self.out = 0
        self.max_command = 0.0
        self.pwm_like = 0  # commands within 800..2200 (a pulse width in µs)
        self.long_steps = 0
        self.high = {"voltage": 0, "current": 0, "rpm": 0}

    def push(self, row: TelemetryRow) -> Iterator[TelemetryRow]:
        """Take one decoded row; the rows that leave the buffer, in stamp order."""
        index = self.offered
        self.offered += 1
        if not all(math.isfinite(x) for x in row[1:]):
            self.non_finite += 1
            if self.first_bad < 0:
                self.first_bad = index
            self.bad_columns.update(
                c for c, x in zip(_COLUMNS, row[1:], strict=True) if not math.isfinite(x)
            )
            return
        t = row[1]
        heapq.heappush(self.heap, (t, index, row))
        self.newest = max(self.newest, t)
        while self.heap and (
            self.heap[0][0] <= self.newest - REORDER_S or len(self.heap) > REORDER_MAX
        ):
            yield from self._release(heapq.heappop(self.heap)[2])

    def drain(self) -> Iterator[TelemetryRow]:
        """The rows still buffered, in stamp order (the end of a file)."""
        while self.heap:
            yield from self._release(heapq.heappop(self.heap)[2])

    def _release(self, row: TelemetryRow) -> Iterator[TelemetryRow]:
        t = row[1]
        if t <= self.last:
            self.late += t < self.last  # an equal stamp is a re-sent sample, kept once
            return
        if self.out:
            self.long_steps += t - self.last > MAX_STEP_S
        self.last = t
        self.out += 1
        command = abs(row[2])
        self.max_command = max(self.max_command, command)
        self.pwm_like += 800.0 <= row[2] <= 2200.0
        self.high["voltage"] += abs(row[3]) > MAX_MEDIAN_VOLTAGE_V
        self.high["rpm"] += abs(row[4]) > MAX_RPM
        self.high["current"] += abs(row[5]) > MAX_CURRENT_A
        yield row

    def finish(self, source: str) -> None:
        """Warn or refuse as ``_trace`` does: non-finite samples, late samples, units.

        Raises
        ------
        BadInputError
            If every sample had a non-finite value, or a column is plausibly in the wrong unit.
        """
        bad = ", ".join(c for c in _COLUMNS if c in self.bad_columns)
        if self.non_finite == self.offered:
            raise BadInputError(f"{source}: every sample has a non-finite value (in {bad})")
        if self.non_finite:
            warnings.warn(
                TraceWarning(
                    f"{source}: left out {self.non_finite} of {self.offered} samples with a "
                    f"non-finite value in {bad} (the first is sample {self.first_bad})"
                ),
                stacklevel=2,
            )
        if self.late:
            warnings.warn(
                TraceWarning(
                    f"{source}: left out {self.late} sample(s) stamped more than {REORDER_S:g} s "
                    f"(or {REORDER_MAX} samples) before a sample read earlier"
                ),
                stacklevel=2,
            )
        self._check_units(source)

    def _check_units(self, source: str) -> None:
        n = self.out
        if self.max_command > 1.001:
            if self.pwm_like > n / 2:
                hint = "it looks like a pulse width in µs: command = (pwm_us - 1500) / 400"
            elif self.max_command <= 100.0:
                hint = "if it is in percent, divide by 100"
            else:
                hint = "the command is normalised to -1..1"
            raise BadInputError(
                f"{source}: column 'command' reaches {self.max_command:g}, outside -1..1; {hint}"
            )
        if n > 1 and self.long_steps > (n - 1) / 2:
            raise BadInputError(
                f"{source}: column 't' steps by more than {MAX_STEP_S:g} in {self.long_steps} of "
                f"{n - 1} steps; times are in seconds and this looks like ms or µs"
            )
        checks = (
            ("voltage", 0.5, MAX_MEDIAN_VOLTAGE_V, "V", "mV"),
            ("current", 0.01, MAX_CURRENT_A, "A", "mA"),
            ("rpm", 0.01, MAX_RPM, "rpm", "eRPM (rpm x pole pairs)"),
        )
        for name, share, limit, unit, guess in checks:
            if self.high[name] > share * n:
                raise BadInputError(
                    f"{source}: column {name!r} is above {limit:g} {unit} in {self.high[name]} "
                    f"of {n} samples; is it in {guess}?"
                )


def _stream_file(path: Path, last: dict[str, float]) -> Iterator[Sample]:
    """One MCAP file's samples per thruster in stamp order, those not after ``last`` (the
    thruster's last stamp of an earlier split, updated) left out as ``read_bag`` does."""
    thrusters: dict[str, _Thruster] = {}

    def take(rows: Iterator[TelemetryRow]) -> Iterator[Sample]:
        for tid, t, command, voltage, rpm, current, _ in rows:
            if t > last.get(tid, -math.inf):
                last[tid] = t
                yield tid, t, command, voltage, rpm, current

    for row in iter_trace_mcap(path):
        state = thrusters.get(row[0])
        if state is None:
            state = thrusters[row[0]] = _Thruster()
        yield from take(state.push(row))
    for tid in sorted(thrusters):
        yield from take(thrusters[tid].drain())
        thrusters[tid].finish(f"{path} ({tid})")


def stream_recording(path: Path) -> Iterator[Sample]:
    """Every thruster's telemetry of a bag folder or MCAP file, sample by sample: per thruster
    in stamp order across the bag's splits; thrusters interleaved as recorded.

    Warnings are those of ``archive.read_recording`` (damage, non-finite samples, a split that
    cannot be read), plus one for samples left out as too late (``REORDER_S``).

    Raises
    ------
    BadInputError
        If nothing can be read, as ``read_recording``; also when a bag split fails the unit
        check after its samples were handed out (``read_bag`` would skip that split).
    """
    last: dict[str, float] = {}
    if not is_bag(path):
        yield from _stream_file(path, last)
        return
    files = bag_files(path)
    refused: list[tuple[Path, BadInputError]] = []
    for file in files:
        given = False
        try:
            for sample in _stream_file(file, last):
                given = True
                yield sample
        except BadInputError as exc:
            if given:
                raise
            refused.append((file, exc))
    if len(refused) == len(files):
        raise refused[0][1]
    for file, exc in refused:
        size = file.stat().st_size if file.exists() else 0
        why = "empty" if size == 0 else str(exc).removeprefix(f"{file}: ")
        warnings.warn(
            PartialInputWarning(f"{file}: split skipped ({why}); the rest of the bag is read"),
            stacklevel=2,
        )
