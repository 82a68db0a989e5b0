"""Recordings as rosbag2 bags of raw CDR messages in MCAP files, without ROS.

The recorder node hands every message it receives (topic, type, CDR bytes, time) to a
:class:`McapRecorder`, which writes one bag folder per run, as ``ros2 bag record -s mcap`` does:
``metadata.yaml`` (rosbag2 format version 9: files, topics with their type, type hash, offered
QoS profiles and message counts, custom data) and the size/duration-split files
``<bag>_<index>.mcap`` in rosbag2's MCAP layout (profile ``ros2``, schema encoding ``ros2msg``
with the definitions of ``core.traces.mcap_io.describe``, message encoding ``cdr``, each
channel's ``offered_qos_profiles`` in its metadata as the MCAP ros2 profile requires). A type
nobody can describe is recorded with an empty definition rather than stopping the recorder.
The chunk in progress is closed and written through to the OS, and ``metadata.yaml``
rewritten, every ``flush_period_s``, so a killed recorder leaves all but the last period
readable (:func:`read_recovered` reads a cut file).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from mcap.writer import CompressionType, Writer

from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.safe_yaml import dump_yaml
from thruster_fdd.core.traces.mcap_io import describe
from thruster_fdd.core.traces.mcap_read import read_mcap

BAG_METADATA = "metadata.yaml"
"""File name of a rosbag2 bag's metadata in its folder."""

BAG_VERSION = 9
"""rosbag2 metadata format version written (ROS 2 Jazzy's)."""

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


@dataclass
class _FileStats:
    """What ``metadata.yaml`` says of one file: name, span and message count."""

    name: str
    first_ns: int = 0
    last_ns: int = 0
    messages: int = 0


@dataclass
class _Topic:
    """What ``metadata.yaml`` says of one topic."""

    type_name: str
    offered_qos: list[dict[str, Any]]
    type_hash: str = ""
    messages: int = 0


class McapRecorder:
    """Writes raw CDR messages into a rosbag2 bag folder of size/duration-split MCAP files.

    Parameters
    ----------
    bag_dir : str or Path
        The bag folder, created here and only here (its parent if missing): a folder that
        exists already, even an empty one, is not written into, so two recorders never share
        one. Its files are ``<folder name>_<index>.mcap``.
    policy : RecordingPolicy
        Splitting, chunking, flushing, compression.
    metadata : dict of str to str
        Written as the ``thruster_fdd`` metadata record at the start of every file and as the
        bag's ``custom_data``; the dict is read then, so the caller may add to it while
        recording.
    definition_for : callable
        Message type name -> rosbag2-style definition text, or None when it cannot be described
        (the messages are then recorded with an empty definition).

    Raises
    ------
    FileExistsError
        If ``bag_dir`` exists (a bag, or a folder another recorder has just made).
    OSError
        If the folder cannot be created or a file cannot be written (the caller reports it).
    """

    def __init__(
        self,
        bag_dir: str | Path,
        policy: RecordingPolicy | None = None,
        metadata: dict[str, str] | None = None,
        *,
        definition_for: Callable[[str], str | None] = describe,
    ) -> None:
        self.bag_dir = Path(bag_dir)
        self.policy = policy or RecordingPolicy()
        self.metadata = metadata if metadata is not None else {}
        self._definition_for = definition_for
        self._definitions: dict[str, str | None] = {}
        self._file: _OpenFile | None = None
        self._last_flush = time.monotonic()
        self._topics: dict[str, _Topic] = {}
        self._stats: list[_FileStats] = []
        # topic -> ((type, hash), its QoS list object, rendered YAML): ``_topic_yaml``.
        self._topic_yaml_cache: dict[str, tuple[tuple[str, str], object, str]] = {}
        self.files: list[Path] = []
        self.messages_written = 0
        self.bag_dir.parent.mkdir(parents=True, exist_ok=True)
        # Exclusive: of two recorders given one folder, one gets it and the other an error.
        self.bag_dir.mkdir()

    def add_topic(
        self,
        topic: str,
        type_name: str,
        offered_qos: list[dict[str, Any]],
        type_hash: str = "",
    ) -> None:
        """Declare a topic before its messages: its publishers' QoS profiles (rosbag2 v9 form,
        ``qos_profile_dict``) and type hash (``RIHS01_...``) for the bag's metadata."""
        known = self._topics.get(topic)
        if known is not None and known.type_name == type_name:
            known.offered_qos, known.type_hash = offered_qos, type_hash
            return
        self._topics[topic] = _Topic(type_name, offered_qos, type_hash)

    def update_topic(
        self, topic: str, offered_qos: list[dict[str, Any]], type_hash: str = ""
    ) -> None:
        """Take a topic's publishers' QoS profiles and type hash seen after it was declared
        (its publishers appeared after the recorder subscribed), keeping its message count.

        ``metadata.yaml`` says them from its next rewrite on; a file whose channel for the topic
        is already written keeps the channel it has (an MCAP channel cannot change), the next
        file's channel has them.
        """
        info = self._topics.get(topic)
        if info is None:
            raise KeyError(f"{topic}: not declared (add_topic)")
        info.offered_qos, info.type_hash = offered_qos, type_hash

    def _open(self, log_time_ns: int) -> _OpenFile:
        path = self.bag_dir / f"{self.bag_dir.name}_{len(self.files)}.mcap"
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
        self._stats.append(_FileStats(path.name, log_time_ns, log_time_ns))
        self.write_metadata()
        return _OpenFile(path, stream, writer, log_time_ns)

    def _channel(self, f: _OpenFile, topic: str, type_name: str) -> int:
        info = self._topics.setdefault(topic, _Topic(type_name, []))
        if type_name not in f.schemas:
            if type_name not in self._definitions:
                self._definitions[type_name] = self._definition_for(type_name)
            # An empty definition keeps the type's name (readers map channels by it) and the
            # data; only decoding that one type needs its definition from elsewhere.
            text = self._definitions[type_name] or ""
            f.schemas[type_name] = f.writer.register_schema(type_name, "ros2msg", text.encode())
        channel_meta = {"offered_qos_profiles": dump_yaml(info.offered_qos)}
        if info.type_hash:
            channel_meta["topic_type_hash"] = info.type_hash
        return f.writer.register_channel(topic, "cdr", f.schemas[type_name], channel_meta)

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
        if topic not in f.channels:
            f.channels[topic] = self._channel(f, topic, type_name)
        channel = f.channels[topic]
        seq = f.sequence.get(channel, 0)
        f.sequence[channel] = seq + 1
        f.writer.add_message(channel, log_time_ns, data, log_time_ns, seq)
        self.messages_written += 1
        self._topics[topic].messages += 1
        stats = self._stats[-1]
        stats.messages += 1
        stats.first_ns = min(stats.first_ns, log_time_ns)
        stats.last_ns = max(stats.last_ns, log_time_ns)
        self.flush_if_due()

    def flush_if_due(self) -> None:
        """Write out the chunk in progress and ``metadata.yaml`` when ``flush_period_s`` has
        passed."""
        now = time.monotonic()
        if self._file is not None and now - self._last_flush >= self.policy.flush_period_s:
            self._file.writer.flush()
            self.write_metadata()
            self._last_flush = now

    def bag_metadata(self) -> dict[str, Any]:
        """The bag's ``metadata.yaml`` content now (rosbag2 format ``BAG_VERSION``)."""
        used = [s for s in self._stats if s.messages]
        start = min((s.first_ns for s in used), default=0)
        end = max((s.last_ns for s in used), default=0)
        return {
            "rosbag2_bagfile_information": {
                "version": BAG_VERSION,
                "storage_identifier": "mcap",
                "relative_file_paths": [s.name for s in self._stats],
                "duration": {"nanoseconds": end - start},
                "starting_time": {"nanoseconds_since_epoch": start},
                "message_count": self.messages_written,
                "topics_with_message_count": [
                    {
                        "topic_metadata": {
                            "name": name,
                            "type": t.type_name,
                            "serialization_format": "cdr",
                            "offered_qos_profiles": t.offered_qos,
                            "type_description_hash": t.type_hash,
                        },
                        "message_count": t.messages,
                    }
                    for name, t in self._topics.items()
                ],
                "compression_format": "",
                "compression_mode": "",
                "files": [
                    {
                        "path": s.name,
                        "starting_time": {"nanoseconds_since_epoch": s.first_ns},
                        "duration": {"nanoseconds": s.last_ns - s.first_ns},
                        "message_count": s.messages,
                    }
                    for s in self._stats
                ],
                "custom_data": {str(k): str(v) for k, v in self.metadata.items()},
                "ros_distro": "jazzy",
            }
        }

    def write_metadata(self) -> None:
        """Rewrite ``metadata.yaml`` (atomically: a reader sees the old or the new one)."""
        write_text(self.bag_dir / BAG_METADATA, self.metadata_text())

    def metadata_text(self) -> str:
        """``bag_metadata()`` as YAML, each topic's metadata rendered once: rewritten every
        flush, the full dump took most of a recorder's CPU at 8 thrusters."""
        info = dict(self.bag_metadata()["rosbag2_bagfile_information"])
        topics = info.pop("topics_with_message_count")
        lines = [dump_yaml({"rosbag2_bagfile_information": info}).rstrip("\n")]
        lines.append("  topics_with_message_count:" + ("" if topics else " []"))
        for entry in topics:
            lines.append(self._topic_yaml(entry["topic_metadata"]))
            lines.append(f"    message_count: {entry['message_count']}")
        return "\n".join(lines) + "\n"

    def _topic_yaml(self, metadata: dict[str, Any]) -> str:
        """One ``topic_metadata`` list entry, indented for ``topics_with_message_count``; kept
        until the topic's QoS profiles or type hash change."""
        name = metadata["name"]
        key = (metadata["type"], metadata["type_description_hash"])
        cached = self._topic_yaml_cache.get(name)
        if cached is None or cached[0] != key or cached[1] is not metadata["offered_qos_profiles"]:
            text = dump_yaml([{"topic_metadata": metadata}]).rstrip("\n")
            block = "\n".join(f"  {line}" for line in text.splitlines())
            cached = self._topic_yaml_cache[name] = (key, metadata["offered_qos_profiles"], block)
        return cached[2]

    def bytes_written(self) -> int:
        """Bytes in all files of this recording so far."""
        return sum(p.stat().st_size for p in self.files if p.exists())

    def _close_file(self) -> None:
        f, self._file = self._file, None
        if f is not None:
            f.writer.finish()
            f.stream.close()
            self.write_metadata()

    def abandon(self) -> None:
        """Drop the current file after a write error; the next message opens the next file.

        What the file already holds stays readable with :func:`read_recovered`.
        """
        f, self._file = self._file, None
        if f is not None:
            with contextlib.suppress(OSError):
                f.stream.close()
        with contextlib.suppress(OSError):
            self.write_metadata()

    def close(self, final_metadata: dict[str, str] | None = None) -> None:
        """Finish the current file (with an optional last metadata record) and the bag's
        ``metadata.yaml``."""
        if self._file is not None and final_metadata:
            self._file.writer.add_metadata("thruster_fdd_final", final_metadata)
        self._close_file()
        self.write_metadata()


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
