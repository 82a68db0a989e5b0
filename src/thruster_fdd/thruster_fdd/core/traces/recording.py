"""MCAP recording of raw CDR messages, split into files, without ROS.

The recorder node hands every message it receives (topic, type, CDR bytes, time) to a
:class:`McapRecorder`. Files use rosbag2's MCAP layout (profile ``ros2``, schema encoding
``ros2msg`` with the definitions of ``core.traces.mcap_io.message_definition``, message encoding
``cdr``). The chunk in progress is closed and written through to the OS every
``flush_period_s``, so a killed recorder leaves all but the last period readable
(:func:`read_recovered` reads such a file).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mcap.writer import CompressionType, Writer

from thruster_fdd.core.traces.mcap_io import message_definition
from thruster_fdd.core.traces.mcap_read import read_mcap

COMPRESSIONS = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


@dataclass(frozen=True)
class RecordingPolicy:
    """How recordings are split, compressed and flushed.

    Attributes
    ----------
    max_file_bytes : int
        Start a new file when the current one passes this size (bytes written so far).
    max_file_duration_s : float
        Start a new file when the current one spans more than this, s.
    chunk_bytes : int
        Uncompressed size at which a chunk is closed and written.
    flush_period_s : float
        Close and write the chunk in progress at least this often, s: the most a killed
        recorder can lose.
    compression : str
        ``zstd``, ``lz4`` or ``none``.
    """

    max_file_bytes: int = 256 * 1024 * 1024
    max_file_duration_s: float = 600.0
    chunk_bytes: int = 512 * 1024
    flush_period_s: float = 1.0
    compression: str = "zstd"

    def __post_init__(self) -> None:
        if self.compression not in COMPRESSIONS:
            raise ValueError(
                f"compression must be one of {sorted(COMPRESSIONS)}, got {self.compression!r}"
            )
        for name in ("max_file_bytes", "max_file_duration_s", "chunk_bytes", "flush_period_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")


@dataclass
class _OpenFile:
    """The file being written (mutable bookkeeping of the recorder)."""

    path: Path
    stream: BinaryIO
    writer: Writer
    started_ns: int
    schemas: dict[str, int] = field(default_factory=dict)
    channels: dict[str, int] = field(default_factory=dict)
    sequence: dict[int, int] = field(default_factory=dict)


class McapRecorder:
    """Writes raw CDR messages into size/duration-split MCAP files.

    Parameters
    ----------
    out_dir : str or Path
        Folder of the recording; created if missing. Files are ``<prefix>_<index>.mcap``.
    policy : RecordingPolicy
        Splitting, chunking, flushing, compression.
    metadata : dict of str to str
        Written as the ``thruster_fdd`` metadata record at the start of every file; the dict is
        read then, so the caller may add to it while recording.
    prefix : str
        File name prefix (e.g. a start time stamp).
    definition_for : callable
        Message type name -> rosbag2-style definition text.

    Raises
    ------
    OSError
        If the folder cannot be created or a file cannot be written (the caller reports it).
    """

    def __init__(
        self,
        out_dir: str | Path,
        policy: RecordingPolicy | None = None,
        metadata: dict[str, str] | None = None,
        *,
        prefix: str = "recording",
        definition_for: Callable[[str], str] = message_definition,
    ) -> None:
        self.out_dir = Path(out_dir)
        self.policy = policy or RecordingPolicy()
        self.metadata = metadata if metadata is not None else {}
        self.prefix = prefix
        self._definition_for = definition_for
        self._definitions: dict[str, str] = {}
        self._file: _OpenFile | None = None
        self._last_flush = time.monotonic()
        self.files: list[Path] = []
        self.messages_written = 0
        self.out_dir.mkdir(parents=True, exist_ok=True)

    def _open(self, log_time_ns: int) -> _OpenFile:
        path = self.out_dir / f"{self.prefix}_{len(self.files):03d}.mcap"
        # Writer.flush (every flush_period_s) closes the chunk and flushes this stream to the
        # OS, which bounds what a killed process can lose.
        stream = path.open("wb")
        writer = Writer(
            stream,
            chunk_size=self.policy.chunk_bytes,
            compression=COMPRESSIONS[self.policy.compression],
        )
        writer.start(profile="ros2", library="thruster_fdd")
        writer.add_metadata("thruster_fdd", self.metadata)
        self.files.append(path)
        return _OpenFile(path, stream, writer, log_time_ns)

    def write(self, topic: str, type_name: str, data: bytes, log_time_ns: int) -> None:
        """Append one message; opens, splits and flushes files as the policy says.

        Parameters
        ----------
        topic : str
            Topic name.
        type_name : str
            ``pkg/msg/Type``.
        data : bytes
            The CDR-serialised message, as received.
        log_time_ns : int
            Receive time, ns since the epoch.
        """
        f = self._file
        if f is not None and (
            f.stream.tell() > self.policy.max_file_bytes
            or (log_time_ns - f.started_ns) * 1e-9 > self.policy.max_file_duration_s
        ):
            self._close_file()
            f = None
        if f is None:
            f = self._file = self._open(log_time_ns)
        if type_name not in f.schemas:
            if type_name not in self._definitions:
                self._definitions[type_name] = self._definition_for(type_name)
            f.schemas[type_name] = f.writer.register_schema(
                type_name, "ros2msg", self._definitions[type_name].encode()
            )
        if topic not in f.channels:
            f.channels[topic] = f.writer.register_channel(topic, "cdr", f.schemas[type_name])
        channel = f.channels[topic]
        seq = f.sequence.get(channel, 0)
        f.sequence[channel] = seq + 1
        f.writer.add_message(channel, log_time_ns, data, log_time_ns, seq)
        self.messages_written += 1
        self.flush_if_due()

    def flush_if_due(self) -> None:
        """Write out the chunk in progress when ``flush_period_s`` has passed."""
        now = time.monotonic()
        if self._file is not None and now - self._last_flush >= self.policy.flush_period_s:
            self._file.writer.flush()
            self._last_flush = now

    def bytes_written(self) -> int:
        """Bytes in all files of this recording so far."""
        return sum(p.stat().st_size for p in self.files if p.exists())

    def _close_file(self) -> None:
        f, self._file = self._file, None
        if f is not None:
            f.writer.finish()
            f.stream.close()

    def abandon(self) -> None:
        """Drop the current file after a write error; the next message opens the next file.

        What the file already holds stays readable with :func:`read_recovered`.
        """
        f, self._file = self._file, None
        if f is not None:
            with contextlib.suppress(OSError):
                f.stream.close()

    def close(self, final_metadata: dict[str, str] | None = None) -> None:
        """Finish the current file (with an optional last metadata record)."""
        if self._file is not None and final_metadata:
            self._file.writer.add_metadata("thruster_fdd_final", final_metadata)
        self._close_file()


@dataclass(frozen=True)
class Recovered:
    """What could be read from a possibly truncated MCAP file.

    Attributes
    ----------
    messages : list of (topic, schema name, data, log_time_ns)
        Every message that could be read, in file order (bytes as written).
    complete : bool
        Whether the file ended properly (footer and magic present).
    error : str
        What was lost (a cut end, damaged chunks), empty for a sound file.
    """

    messages: list[tuple[str, str, bytes, int]]
    complete: bool
    error: str = ""


def read_recovered(path: str | Path) -> Recovered:
    """Read every message from an MCAP file, tolerating a missing end (a killed recorder) and
    damaged chunks (skipped; ``error`` says what was lost).

    Uses ``core.traces.mcap_read.read_mcap``, which needs no summary section.

    Raises
    ------
    BadInputError
        If the file is not an MCAP file (a prefix of the magic, even empty, is a cut one).
    """
    contents = read_mcap(path, require_messages=False)
    messages = []
    for channel_id, log_time, data in contents.messages:
        channel = contents.channels.get(channel_id)
        if channel is not None:
            schema = "" if channel.schema is None else channel.schema.name
            messages.append((channel.topic, schema, data, log_time))
    return Recovered(messages, contents.complete, "; ".join(contents.problems))
