"""Reading and writing traces by file type: trace CSV, MCAP, or folders of them."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.traces.csv_io import read_trace_csv, write_trace_csv
from thruster_fdd.core.traces.data import Trace
from thruster_fdd.core.traces.mcap_io import read_trace_mcap, write_trace_mcap

SUFFIXES = (".csv", ".mcap")


def write_trace(trace: Trace, path: str | Path) -> None:
    """Write ``trace`` as CSV or MCAP, chosen by the file's suffix.

    Raises
    ------
    ValueError
        If the suffix is neither ``.csv`` nor ``.mcap``.
    """
    path = Path(path)
    if path.suffix == ".csv":
        write_trace_csv(trace, path)
    elif path.suffix == ".mcap":
        write_trace_mcap([trace], path)
    else:
        raise BadInputError(f"{path}: output must end in .csv or .mcap")


def trace_files(sources: Iterable[str | Path]) -> list[Path]:
    """The trace files that ``sources`` name: files as given, folders' CSV/MCAP recursively.

    Raises
    ------
    ValueError
        If a source does not exist or a folder holds no trace.
    """
    files: list[Path] = []
    for source in sources:
        path = Path(source)
        if path.is_dir():
            found = sorted(p for p in path.rglob("*") if p.suffix in SUFFIXES)
            if not found:
                raise BadInputError(f"{path}: folder holds no .csv or .mcap trace")
            files.extend(found)
        elif path.is_file():
            files.append(path)
        else:
            raise BadInputError(f"{path}: no such file or folder")
    return files


def file_digests(sources: Iterable[str | Path]) -> list[dict[str, str]]:
    """Name and SHA-256 of every trace file of ``sources`` (what a model card records)."""
    return [
        {"file": str(path), "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
        for path in trace_files(sources)
    ]


def read_traces(sources: Iterable[str | Path]) -> list[Trace]:
    """Read every trace in the given files and folders (CSV and MCAP, folders recursively).

    Parameters
    ----------
    sources : iterable of str or Path
        Files (``.csv``, ``.mcap``) and folders holding them.

    Returns
    -------
    list of Trace
        One per CSV file, one per thruster in each MCAP file, in sorted path order.

    Raises
    ------
    ValueError
        If a source does not exist, has another suffix, or a folder holds no trace.
    """
    traces: list[Trace] = []
    for file in trace_files(sources):
        if file.suffix == ".csv":
            traces.append(read_trace_csv(file))
        elif file.suffix == ".mcap":
            traces.extend(read_trace_mcap(file))
        else:
            raise BadInputError(f"{file}: a trace must be a .csv or .mcap file")
    return traces
