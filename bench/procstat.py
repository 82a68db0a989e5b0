"""CPU time of a process from /proc, shared by the benchmark scripts (imported as a sibling:
they run as ``python bench/<name>.py``, which puts ``bench/`` on ``sys.path``)."""

from __future__ import annotations

import os
from pathlib import Path

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time of process ``pid`` so far, s.

    Raises
    ------
    OSError
        If the process is gone.
    """
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS
