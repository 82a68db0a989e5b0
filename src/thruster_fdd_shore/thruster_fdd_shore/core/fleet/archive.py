"""The recordings of an archive: where they are, whose they are, what they hold.

An archive is a folder; every rosbag2 bag folder (``metadata.yaml`` beside its MCAP files) and
every loose ``.mcap`` file under it is one recording. The vehicle of a recording is the name of
the first folder under the archive on its path (``ARCHIVE/<vehicle>/...``); a recording directly
in the archive has vehicle ``UNKNOWN_VEHICLE``. Its calendar time is its telemetry stamps
(``header.stamp``, ns since the Unix epoch, as the recorder writes them; a file written with a
``time_origin_ns`` metadata record has that origin added). Its identity is a digest of its bytes.
"""

from __future__ import annotations

import hashlib
import warnings
from dataclasses import dataclass
from pathlib import Path

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.traces.data import Trace
from thruster_fdd.core.traces.mcap_io import METADATA_NAME, ORIGIN_KEY, read_trace_mcap
from thruster_fdd.core.traces.recording import BAG_METADATA
from thruster_fdd_shore.core.traces.files import bag_files, is_bag, read_bag

UNKNOWN_VEHICLE = "unknown"
"""Vehicle of a recording that lies directly in the archive folder."""

EPOCH_FLOOR_S = 1.0e8
"""A first stamp below this (s, 1973) is taken as relative to the file's ``time_origin_ns``."""


@dataclass(frozen=True)
class Recording:
    """One recording of an archive.

    Attributes
    ----------
    path : Path
        Absolute path of the bag folder or MCAP file.
    relative : str
        Path relative to the archive (POSIX), the recording's name in the dataset.
    vehicle : str
        Vehicle id (the first folder under the archive).
    size_bytes : int
        Total size of its files, bytes.
    mtime_ns : int
        Latest modification time of its files, ns.
    """

    path: Path
    relative: str
    vehicle: str
    size_bytes: int
    mtime_ns: int


def recording_files(path: Path) -> list[Path]:
    """The files of a recording: a bag's MCAP files in recording order (and its metadata), or
    the MCAP file itself."""
    if is_bag(path):
        try:
            return [*bag_files(path), path / BAG_METADATA]
        except BadInputError:
            return [path / BAG_METADATA]
    return [path]


def find_recordings(archive: str | Path) -> list[Recording]:
    """Every recording under ``archive``, sorted by relative path.

    Raises
    ------
    BadInputError
        If ``archive`` is not a folder or holds no bag folder or ``.mcap`` file.
    """
    root = Path(archive).absolute()
    if not root.is_dir():
        raise BadInputError(f"{archive}: not a folder")
    bags = sorted(p.parent for p in root.rglob(BAG_METADATA))
    loose = sorted(
        p for p in root.rglob("*.mcap") if p.is_file() and not any(b in p.parents for b in bags)
    )
    found = []
    for path in sorted(bags + loose):
        rel = path.relative_to(root)
        vehicle = rel.parts[0] if len(rel.parts) > 1 else UNKNOWN_VEHICLE
        stats = [f.stat() for f in recording_files(path) if f.is_file()]
        found.append(
            Recording(
                path=path,
                relative=rel.as_posix(),
                vehicle=vehicle,
                size_bytes=sum(s.st_size for s in stats),
                mtime_ns=max((s.st_mtime_ns for s in stats), default=0),
            )
        )
    if not found:
        raise BadInputError(f"{archive}: holds no rosbag2 bag folder or .mcap recording")
    return found


def recording_digest(path: Path) -> str:
    """SHA-256 (hex) over the bytes of a recording's files in order (1 MiB at a time)."""
    h = hashlib.sha256()
    for file in recording_files(path):
        if not file.is_file():
            continue
        h.update(file.name.encode() + b"\0")
        with file.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def _origin_s(path: Path) -> float:
    """The ``time_origin_ns`` metadata of an MCAP file, s (0 when it has none)."""
    from mcap.reader import make_reader

    try:
        with path.open("rb") as f:
            for record in make_reader(f).iter_metadata():
                if record.name == METADATA_NAME and ORIGIN_KEY in record.metadata:
                    return int(record.metadata[ORIGIN_KEY]) * 1e-9
    except Exception:  # a damaged file: its stamps are all there is
        return 0.0
    return 0.0


@dataclass(frozen=True)
class Contents:
    """What a recording holds.

    Attributes
    ----------
    traces : list of Trace
        One per thruster, times ``t`` in s on the recording's clock.
    origin_s : float
        Add to ``t`` for s since the Unix epoch.
    problems : tuple of str
        Warnings of the readers: what of a damaged recording was lost.
    """

    traces: list[Trace]
    origin_s: float
    problems: tuple[str, ...]


def read_recording(path: Path) -> Contents:
    """Read every thruster's telemetry of a bag folder or MCAP file (the shore's readers).

    Raises
    ------
    BadInputError
        If nothing can be read (``core.traces.files.read_bag``, ``mcap_io.read_trace_mcap``).
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        traces = read_bag(path) if is_bag(path) else read_trace_mcap(path)
    problems = tuple(dict.fromkeys(str(w.message) for w in caught))
    first = min((float(t.t[0]) for t in traces if len(t)), default=0.0)
    return Contents(traces, origin_s(path, first), problems)


def origin_s(path: Path, first_s: float) -> float:
    """What to add to a recording's times (s, the first ``first_s``) for s since the epoch: 0
    for stamps in calendar time, else the first file's ``time_origin_ns`` (s)."""
    if first_s >= EPOCH_FLOOR_S:
        return 0.0
    return _origin_s(bag_files(path)[0] if is_bag(path) else path)
