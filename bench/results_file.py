"""Machine-readable results of a benchmark run, shared by the benchmark scripts (imported as a
sibling: they run as ``python bench/<name>.py``, which puts ``bench/`` on ``sys.path``).

Each run writes one JSON file, ``bench/results/<UTC date>-<script>.json`` (a later run of the
same script on the same day replaces it):

``{"bench", "command", "date", "started", "finished", "machine": {...},
"load_average": {"start", "end"}, "results": [{"metric", "unit", "median", ...}], ...}``

docs/benchmarks.md shows the medians of these files; compare runs from the same machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def add_results_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--results DIR`` (default ``bench/results``; ``-`` writes no file)."""
    parser.add_argument(
        "--results",
        default=str(RESULTS_DIR),
        metavar="DIR",
        help="folder for this run's JSON file (default bench/results; '-' for none)",
    )


def machine() -> dict[str, Any]:
    """Cores, memory, CPU model, OS and Python of this machine."""
    memory_gb = None
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                memory_gb = round(int(line.split()[1]) / 2**20, 1)
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cores": len(os.sched_getaffinity(0)),
        "memory_gb": memory_gb,
        "cpu": cpu,
        "system": platform.platform(),
        "python": platform.python_version(),
    }


@dataclass
class Run:
    """One benchmark run: its start, and the rows it measured.

    Attributes
    ----------
    bench : str
        Script name without ``.py``.
    rows : list of dict
        ``{"metric": what, "unit": unit, "median": value, ...}`` (p99, min, max, count, ...).
    """

    bench: str
    rows: list[dict[str, Any]] = field(default_factory=list)
    started: str = field(default_factory=lambda: datetime.now(UTC).isoformat(timespec="seconds"))
    load_start: float = field(default_factory=lambda: os.getloadavg()[0])

    def add(self, metric: str, unit: str, median: float, **more: Any) -> None:
        """Add one measured row (values rounded to 4 significant digits)."""
        row: dict[str, Any] = {"metric": metric, "unit": unit, "median": _round(median)}
        row.update({k: _round(v) for k, v in more.items()})
        self.rows.append(row)

    def write(self, folder: str, **extra: Any) -> Path | None:
        """Write the run's JSON file into ``folder`` (``-``: none) atomically; its path."""
        if folder == "-":
            return None
        out_dir = Path(folder)
        out_dir.mkdir(parents=True, exist_ok=True)
        finished = datetime.now(UTC)
        doc = {
            "bench": self.bench,
            "command": " ".join(["python", f"bench/{self.bench}.py", *sys.argv[1:]]),
            "date": finished.date().isoformat(),
            "started": self.started,
            "finished": finished.isoformat(timespec="seconds"),
            "machine": machine(),
            "load_average": {
                "start": round(self.load_start, 2),
                "end": round(os.getloadavg()[0], 2),
            },
            "results": self.rows,
            **extra,
        }
        path = out_dir / f"{doc['date']}-{self.bench}.json"
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
        tmp.replace(path)
        print(f"wrote {path}")
        return path


def _round(value: Any) -> Any:
    if isinstance(value, float):
        return float(f"{value:.4g}")
    return value
