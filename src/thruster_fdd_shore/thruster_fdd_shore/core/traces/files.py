"""Reading and writing traces by file type: trace CSV, MCAP, rosbag2 bag folders, or folders of
them."""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Callable, Iterable
from dataclasses import replace
from pathlib import Path
from typing import TypeVar

import numpy as np

from thruster_fdd.core.errors import BadInputError, PartialInputWarning
from thruster_fdd.core.safe_yaml import load_yaml
from thruster_fdd.core.traces.data import Trace
from thruster_fdd.core.traces.mcap_io import read_trace_mcap, write_trace_mcap
from thruster_fdd.core.traces.recording import BAG_METADATA
from thruster_fdd_shore.core.traces.csv_io import read_trace_csv, write_trace_csv

SUFFIXES = (".csv", ".mcap")

T = TypeVar("T")


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` is a rosbag2 bag folder (it holds ``metadata.yaml``)."""
    return (Path(path) / BAG_METADATA).is_file()


def bag_files(folder: str | Path) -> list[Path]:
    """The MCAP files of a bag folder, in recording order: those ``metadata.yaml`` lists, then
    any other ``.mcap`` in the folder (a file begun after the last metadata update).

    Raises
    ------
    BadInputError
        If ``folder`` is not a bag, its metadata is unreadable, or it holds no MCAP file.
    """
    folder = Path(folder)
    if not is_bag(folder):
        raise BadInputError(f"{folder}: not a bag folder (no {BAG_METADATA})")
    source = folder / BAG_METADATA
    text = source.read_text(encoding="utf-8", errors="replace")
    try:
        info = load_yaml(text, str(source))["rosbag2_bagfile_information"]
        listed = [folder / Path(str(name)).name for name in info.get("relative_file_paths") or []]
    except (KeyError, TypeError, AttributeError) as exc:
        raise BadInputError(f"{source}: not rosbag2 metadata ({exc!r})") from None
    files = [p for p in listed if p.suffix == ".mcap" and p.is_file()]
    files += sorted(p for p in folder.glob("*.mcap") if p not in files)
    if not files:
        raise BadInputError(f"{folder}: bag holds no .mcap file")
    return files


def _concat(parts: list[Trace]) -> Trace:
    """One thruster's traces from consecutive files of a bag, as one trace (a sample that a
    later file repeats is kept once)."""
    if len(parts) == 1:
        return parts[0]
    keeps, last = [], -np.inf
    for part in parts:
        keeps.append(part.t > last)
        last = max(last, float(part.t[-1])) if len(part) else last

    def joined(arrays: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([a[k] for a, k in zip(arrays, keeps, strict=True)])

    labels = [p.sample_labels() for p in parts]
    names = None
    if all(lab is not None for lab in labels):
        names = joined([np.asarray(lab, dtype=object) for lab in labels])
    keys = set.intersection(*(set(p.extra) for p in parts))
    trace = Trace(
        t=joined([p.t for p in parts]),
        command=joined([p.command for p in parts]),
        voltage=joined([p.voltage for p in parts]),
        rpm=joined([p.rpm for p in parts]),
        current=joined([p.current for p in parts]),
        thruster_id=parts[0].thruster_id,
        extra={k: joined([p.extra[k] for p in parts]) for k in sorted(keys)},
    )
    if names is not None and len(set(names)) == 1:
        return replace(trace, condition=str(names[0]))
    return replace(trace, labels=names)


def read_splits(folder: str | Path, read: Callable[[Path], T]) -> list[T]:
    """``read(file)`` of every MCAP file of a bag folder (``bag_files``), skipping a split that
    cannot be read (empty, as a full disk leaves them, or damaged) with a one-line
    ``PartialInputWarning`` naming it.

    Raises
    ------
    BadInputError
        If ``folder`` is not a bag, or no split of it can be read (the first split's reason).
    """
    results: list[T] = []
    refused: list[tuple[Path, BadInputError]] = []
    for file in bag_files(folder):
        try:
            results.append(read(file))
        except BadInputError as exc:
            refused.append((file, exc))
    if not results:
        raise refused[0][1]
    for file, exc in refused:
        size = file.stat().st_size if file.exists() else 0
        why = "empty" if size == 0 else str(exc).removeprefix(f"{file}: ")
        warnings.warn(
            PartialInputWarning(f"{file}: split skipped ({why}); the rest of the bag is read"),
            stacklevel=2,
        )
    return results


def read_bag(folder: str | Path) -> list[Trace]:
    """Every thruster's telemetry in a bag folder, one trace per thruster across its files (a
    split that cannot be read is skipped with a warning, ``read_splits``)."""
    by_id: dict[str | None, list[Trace]] = {}
    for traces in read_splits(folder, read_trace_mcap):
        for trace in traces:
            by_id.setdefault(trace.thruster_id, []).append(trace)
    return [_concat(parts) for _, parts in sorted(by_id.items(), key=lambda kv: str(kv[0]))]


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


def _sources(sources: Iterable[str | Path]) -> list[Path]:
    """Trace files and bag folders named by ``sources`` (folders searched recursively; a bag
    folder is one source)."""
    out: list[Path] = []
    for source in sources:
        path = Path(source)
        if is_bag(path) or path.is_file():
            out.append(path)
        elif path.is_dir():
            bags = sorted(p.parent for p in path.rglob(BAG_METADATA))
            loose = [
                p
                for p in path.rglob("*")
                if p.suffix in SUFFIXES and p.is_file() and not any(b in p.parents for b in bags)
            ]
            found = sorted(bags + loose)
            if not found:
                raise BadInputError(f"{path}: folder holds no .csv or .mcap trace or bag")
            out.extend(found)
        else:
            raise BadInputError(f"{path}: no such file or folder")
    return out


def trace_files(sources: Iterable[str | Path]) -> list[Path]:
    """The trace files that ``sources`` name: files as given, a bag folder's MCAP files, other
    folders' CSV/MCAP files and bags recursively.

    Raises
    ------
    ValueError
        If a source does not exist or a folder holds no trace.
    """
    files: list[Path] = []
    for path in _sources(sources):
        files.extend(bag_files(path) if path.is_dir() else [path])
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
        Files (``.csv``, ``.mcap``), bag folders, and folders holding them.

    Returns
    -------
    list of Trace
        One per CSV file, one per thruster in each MCAP file and in each bag (across its
        split files), in sorted path order.

    Raises
    ------
    ValueError
        If a source does not exist, has another suffix, or a folder holds no trace.
    """
    traces: list[Trace] = []
    for path in _sources(sources):
        if path.is_dir():
            traces.extend(read_bag(path))
        elif path.suffix == ".csv":
            traces.append(read_trace_csv(path))
        elif path.suffix == ".mcap":
            traces.extend(read_trace_mcap(path))
        else:
            raise BadInputError(f"{path}: a trace must be a .csv or .mcap file or a bag folder")
    return traces
