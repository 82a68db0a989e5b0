"""One robust reader of MCAP recordings: whatever is recoverable, with the damage said.

Every tool that reads a recording (``read_trace_mcap``, ``replay_check.load_bag``,
``recording.read_recovered``) goes through :func:`read_mcap`, or :class:`McapStream`, the same
walk handing out one message at a time (memory bounded by a chunk, not by the recording). It
walks the records itself rather than trusting the summary, so a file cut by ``kill -9`` (no
footer, no summary) reads up to its last complete record; it checks every chunk's CRC and
size, the data section's CRC when one was written and the summary's (a summary that fails is
not used), skips a chunk that fails (its messages are counted from the message indexes behind
it) and a record that does not parse, and stops where the records no longer fit the file
(mapped, not read into memory).
What was lost is listed in ``McapContents.problems`` and said in one
:class:`DamagedRecordingWarning`. A file that does not start with the MCAP magic, or from which
not one message can be read, is refused with ``BadInputError`` (exit 2, one line). No rclpy.
"""

from __future__ import annotations

import contextlib
import io
import mmap
import os
import struct
import warnings
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Message,
    MessageIndex,
    Metadata,
    Schema,
    Statistics,
)
from mcap_ros2.decoder import DecoderFactory

from thruster_fdd.core.errors import BadInputError, PartialInputWarning

MAGIC = b"\x89MCAP0\r\n"
"""The 8 bytes that start (and end) every MCAP file."""


_RECORD_HEADER = struct.Struct("<BQ")


_PARSERS: dict[int, Callable[[ReadDataStream, int], Any]] = {
    Opcode.SCHEMA: lambda s, _: Schema.read(s),
    Opcode.CHANNEL: lambda s, _: Channel.read(s),
    Opcode.MESSAGE: Message.read,
    Opcode.CHUNK: lambda s, _: Chunk.read(s),
    Opcode.MESSAGE_INDEX: lambda s, _: MessageIndex.read(s),
    Opcode.METADATA: lambda s, _: Metadata.read(s),
    Opcode.STATISTICS: lambda s, _: Statistics.read(s),
    Opcode.DATA_END: lambda s, _: DataEnd.read(s),
    Opcode.FOOTER: lambda s, _: Footer.read(s),
}
"""The records a reader needs; every other record (and any future one) is skipped whole."""


_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)


_PRIVATE_OPCODES = 0x80
"""Record types from here up are for private use (skipped); below, only the known ones occur."""


# What a damaged record can raise while parsing (besides McapError): a length field far beyond
# the record gives OverflowError or MemoryError.
_PARSE_ERRORS = (
    McapError,
    struct.error,
    UnicodeDecodeError,
    ValueError,
    KeyError,
    IndexError,
    OverflowError,
    MemoryError,
)


class DamagedRecordingWarning(PartialInputWarning):
    """A recording was read only in part; the text says what was lost and how much."""


@dataclass(frozen=True)
class McapChannel:
    """A channel of a recording: topic, message encoding and its schema (None if unknown)."""

    topic: str
    message_encoding: str
    schema: Schema | None


@dataclass(frozen=True)
class McapContents:
    """What could be read from an MCAP file.

    Attributes
    ----------
    path : Path
        The file.
    channels : dict of int to McapChannel
        Every channel seen, by id.
    messages : list of (int, int, bytes)
        (channel id, log time ns, data) of every message read, in file order.
    metadata : dict of str to dict of str to str
        Metadata records by name (a later record of the same name adds to the earlier).
    complete : bool
        Whether the file ended properly: footer and closing magic present.
    problems : tuple of str
        What was lost or could not be checked, each with its extent; empty for a sound file.
    expected_messages : int or None
        The message count of the file's statistics record, when it has one.
    messages_read : int
        Messages read (``len(messages)``; also when ``messages`` was streamed, not kept).
    """

    path: Path
    channels: dict[int, McapChannel]
    messages: list[tuple[int, int, bytes]]
    metadata: dict[str, dict[str, str]]
    complete: bool
    problems: tuple[str, ...]
    expected_messages: int | None = None
    messages_read: int = 0


@dataclass
class _Walk:
    """Mutable state of one pass over a file."""

    path: Path
    channels: dict[int, McapChannel] = field(default_factory=dict)
    schemas: dict[int, Schema] = field(default_factory=dict)
    messages: list[tuple[int, int, bytes]] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    raw_channels: dict[int, Channel] = field(default_factory=dict)
    bad_chunks: int = 0
    lost_in_chunks: int = 0
    lost_span_ns: int = 0
    last_chunk_bad: bool = False
    not_chunk: tuple[int, int] | None = None  # (offset, type) of the last record if no chunk
    expected: int | None = None
    read: int = 0
    footer_end: int | None = None
    stopped: list[str] = field(default_factory=list)

    def add_schema(self, schema: Schema) -> None:
        # The first definition wins: the summary repeats them outside any checked chunk.
        self.schemas.setdefault(schema.id, schema)

    def add_channel(self, channel: Channel) -> None:
        self.raw_channels.setdefault(channel.id, channel)

    def resolve_channels(self, orphans: int | None = None) -> None:
        """Channels with their schemas (a schema may come after its channel in a summary);
        ``orphans``: messages met without their channel (None: count them in ``messages``)."""
        self.channels = {
            cid: McapChannel(ch.topic, ch.message_encoding, self.schemas.get(ch.schema_id))
            for cid, ch in self.raw_channels.items()
        }
        if orphans is None:
            orphans = sum(1 for cid, _, _ in self.messages if cid not in self.channels)
        if orphans:
            self.problems.append(f"{orphans} message(s) on channels whose definition was lost")

    def add_message(self, message: Message) -> None:
        self.messages.append((message.channel_id, message.log_time, message.data))


def _describe_start(head: bytes) -> str:
    """A few words on what a file that is not MCAP starts with."""
    if not head:
        return "it is empty"
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError:
        return f"it starts with bytes {head[:8].hex(' ')}"
    line = text.splitlines()[0] if text.splitlines() else text
    return f"it starts with the text {line[:40]!r}"


def _records(
    data: bytes | mmap.mmap, start: int, end: int, stopped: list[str]
) -> Iterator[tuple[int, int, bytes]]:
    """(offset, opcode, body) of the records in ``data[start:end]`` that fit, one at a time
    (a recording is not copied whole); why the walk stopped early is appended to ``stopped``."""
    pos = start
    while pos < end:
        if end - pos < _RECORD_HEADER.size:
            stopped.append(f"{end - pos} stray bytes at byte {pos}")
            return
        opcode, length = _RECORD_HEADER.unpack(data[pos : pos + _RECORD_HEADER.size])
        body_start = pos + _RECORD_HEADER.size
        if length > end - body_start:
            stopped.append(f"a record at byte {pos} runs past the end ({length} bytes declared)")
            return
        yield pos, opcode, bytes(data[body_start : body_start + length])
        pos = body_start + length


_FOOTER = struct.Struct("<BQQQI")


_SUMMARY_COPIES = frozenset({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.STATISTICS})
"""Records the summary repeats from the (chunk-checked) data section."""


def _damaged_summary(data: bytes | mmap.mmap) -> bool:
    """Whether the footer's summary CRC fails (False when there is no footer or no CRC). The
    summary lies outside every chunk, so only its CRC vouches for the schemas, channels and
    counts it repeats."""
    end = len(data) - len(MAGIC) - _FOOTER.size
    if end < len(MAGIC) or data[len(data) - len(MAGIC) :] != MAGIC:
        return False
    opcode, length, start, _, crc = _FOOTER.unpack(data[end : end + _FOOTER.size])
    if opcode != Opcode.FOOTER or length != _FOOTER.size - 9:
        return True  # a closing magic without a footer before it: nothing vouches for the end
    if start == 0 or crc == 0:
        return False  # no summary, or one written without a CRC
    covered = end + _FOOTER.size - 4  # through summary_offset_start
    return not len(MAGIC) <= start <= end or _crc32(data, covered, start) != crc


def _crc32(data: bytes | mmap.mmap, end: int, start: int = 0) -> int:
    """CRC-32 of ``data[start:end]``, a MiB at a time (no copy of a whole recording)."""
    crc = 0
    for a in range(start, end, 1 << 20):
        crc = zlib.crc32(data[a : min(end, a + (1 << 20))], crc)
    return crc


def _parse(opcode: int, body: bytes) -> Any:
    parser = _PARSERS.get(opcode)
    if parser is None:
        return None
    return parser(ReadDataStream(io.BytesIO(body)), len(body))


MAX_CHUNK_BYTES = 256 * 1024 * 1024
"""Largest uncompressed chunk read (the recorder writes 512 KiB by default): a bound on what a
damaged or hostile size field can make the reader allocate."""


def _decompress(chunk: Chunk) -> bytes:
    size = chunk.uncompressed_size
    if size > MAX_CHUNK_BYTES:
        raise ValueError(f"declares {size} bytes uncompressed, above {MAX_CHUNK_BYTES}")
    if chunk.compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=size)
    if chunk.compression == "lz4":
        return lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=size)
    if chunk.compression == "":
        return bytes(chunk.data)
    raise ValueError(f"unknown compression {chunk.compression!r}")


def _read_chunk(walk: _Walk, chunk: Chunk, offset: int) -> list[Message]:
    """The messages of a sound chunk (its schemas and channels go into ``walk``); none of a
    damaged one."""
    walk.last_chunk_bad = True
    span_ns = max(0, chunk.message_end_time - chunk.message_start_time)
    try:
        data = _decompress(chunk)
    except (zstandard.ZstdError, RuntimeError, ValueError, MemoryError) as exc:
        # MemoryError: zstandard's answer to some damaged frame headers (found by fuzzing).
        walk.problems.append(f"chunk at byte {offset} does not decompress ({exc})")
        walk.bad_chunks += 1
        walk.lost_span_ns += span_ns
        return []
    if len(data) != chunk.uncompressed_size or (
        chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc
    ):
        walk.problems.append(f"chunk at byte {offset} fails its CRC")
        walk.bad_chunks += 1
        walk.lost_span_ns += span_ns
        return []
    stopped: list[str] = []
    parsed = []
    try:
        parsed = [
            (opcode, _parse(opcode, body))
            for _, opcode, body in _records(data, 0, len(data), stopped)
        ]
    except _PARSE_ERRORS as exc:
        stopped.append(f"a record does not parse ({type(exc).__name__})")
    if stopped:
        # The CRC matched, so the writer itself wrote this: keep nothing of it.
        walk.problems.append(f"chunk at byte {offset} is malformed: {stopped[0]}")
        walk.bad_chunks += 1
        walk.lost_span_ns += span_ns
        return []
    walk.last_chunk_bad = False
    messages = []
    for opcode, record in parsed:
        if opcode == Opcode.MESSAGE:
            messages.append(record)
        else:
            _take(walk, opcode, record)
    return messages


def _take(walk: _Walk, opcode: int, record: Any) -> None:
    if opcode == Opcode.SCHEMA:
        walk.add_schema(record)
    elif opcode == Opcode.CHANNEL:
        walk.add_channel(record)


def read_mcap(path: str | Path, *, require_messages: bool = True) -> McapContents:
    """Read every message that can be recovered from an MCAP file.

    Parameters
    ----------
    path : str or Path
        The file.
    require_messages : bool
        Refuse a file from which no message can be read. False for a recorder's own files,
        where a file cut before its first message (even inside the magic) is an empty result.

    Returns
    -------
    McapContents
        Channels, messages, metadata and the problems met (see the module docstring).

    Raises
    ------
    BadInputError
        If the file does not start with the MCAP magic (e.g. a CSV renamed ``.mcap``), or
        holds no message that can be read (``require_messages``).
    OSError
        If the file cannot be read.
    """
    path = Path(path)
    with _mapped(path) as data:
        early = _check_start(path, data, require_messages)
        if early is not None:
            return early
        walk = _Walk(path)
        for message in _walk_messages(walk, data):
            walk.add_message(message)
        walk.resolve_channels()
        return _finish(walk, data, require_messages)


@contextlib.contextmanager
def _mapped(path: Path) -> Iterator[bytes | mmap.mmap]:
    """The file's bytes, mapped: a recording (256 MB by default) costs address space, not a
    copy."""
    with path.open("rb") as f:
        size = os.fstat(f.fileno()).st_size
        data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    try:
        yield data
    finally:
        if isinstance(data, mmap.mmap):
            data.close()


def _check_start(
    path: Path, data: bytes | mmap.mmap, require_messages: bool
) -> McapContents | None:
    """Refuse a file that is not MCAP; the empty result of one cut inside the magic; else
    None."""
    if data[: len(MAGIC)] == MAGIC:
        return None
    if require_messages or not MAGIC.startswith(data[: len(MAGIC)]):
        raise BadInputError(f"{path}: not an MCAP recording ({_describe_start(data[:40])})")
    problem = f"the file ends early ({len(data)} bytes, inside the magic): the rest is lost"
    return McapContents(path, {}, [], {}, False, (problem,))


def _walk_messages(walk: _Walk, data: bytes | mmap.mmap) -> Iterator[Message]:
    """The messages of a file that starts with the magic, one at a time in file order;
    everything else (channels, metadata, damage) goes into ``walk``."""
    summary_damaged = _damaged_summary(data)
    if summary_damaged:
        walk.problems.append("the summary fails its CRC: its schemas, channels and counts unused")
    in_summary = False
    for offset, opcode, body in _records(data, len(MAGIC), len(data), walk.stopped):
        if summary_damaged and in_summary and opcode in _SUMMARY_COPIES:
            continue
        try:
            if not (opcode in _KNOWN_OPCODES or opcode >= _PRIVATE_OPCODES):
                raise ValueError(f"unknown record type {opcode:#04x}")
            record = _parse(opcode, body)
        except _PARSE_ERRORS as exc:
            # Perhaps a chunk: the message indexes behind it count what it held.
            walk.problems.append(f"record at byte {offset} is damaged ({exc})")
            walk.last_chunk_bad = True
            walk.not_chunk = None  # said already
            continue
        if opcode != Opcode.MESSAGE_INDEX:
            walk.not_chunk = None if opcode == Opcode.CHUNK else (offset, opcode)
        if opcode == Opcode.CHUNK:
            for message in _read_chunk(walk, record, offset):
                walk.read += 1
                yield message
        elif opcode == Opcode.MESSAGE_INDEX:
            if walk.not_chunk is not None:
                # Message indexes follow only chunks: this record held one, its type byte hit
                # (0x06 ^ 0x80 reads as a private record and is skipped whole).
                at, kind = walk.not_chunk
                walk.problems.append(
                    f"record at byte {at} (type {kind:#04x}) has message indexes behind it "
                    "(a chunk with its type damaged)"
                )
                walk.bad_chunks += 1
                walk.last_chunk_bad = True
                walk.not_chunk = None
            if walk.last_chunk_bad:
                walk.lost_in_chunks += len(record.records)
        elif opcode == Opcode.METADATA:
            walk.metadata.setdefault(record.name, {}).update(record.metadata)
        elif opcode == Opcode.STATISTICS:
            walk.expected = record.message_count
        elif opcode == Opcode.DATA_END:
            in_summary = True
            if record.data_section_crc not in (0, _crc32(data, offset)):
                walk.problems.append("the data section fails its CRC")
        elif opcode == Opcode.FOOTER:
            walk.footer_end = offset + _RECORD_HEADER.size + len(body)
            break
        elif opcode == Opcode.MESSAGE:
            walk.read += 1
            yield record
        else:
            _take(walk, opcode, record)


def _finish(walk: _Walk, data: bytes | mmap.mmap, require_messages: bool) -> McapContents:
    """What a finished walk (channels resolved) read, with the rest of its problems."""
    complete = walk.footer_end is not None and data[walk.footer_end :] == MAGIC
    if walk.footer_end is None:
        end = walk.stopped[0] if walk.stopped else "no footer"
        walk.problems.append(f"the file ends early ({end}; {len(data)} bytes): the rest is lost")
    elif not complete:
        walk.problems.append("the closing magic after the footer is missing or damaged")
    if walk.bad_chunks or walk.lost_in_chunks:
        span = f" spanning {walk.lost_span_ns * 1e-9:.1f} s" if walk.lost_span_ns else ""
        walk.problems.append(
            f"{walk.bad_chunks} damaged chunk(s) skipped: {walk.lost_in_chunks} message(s) "
            f"lost{span}"
        )
    unaccounted = (walk.expected or 0) - walk.read - walk.lost_in_chunks
    if unaccounted > 0:
        # The last check: the statistics record (under the summary CRC when there is one)
        # counts messages that no damaged record explains.
        walk.problems.append(f"{unaccounted} message(s) the statistics count are missing")
    if not walk.read and require_messages:
        summary = "; ".join(walk.problems) or "it holds no messages"
        raise BadInputError(f"{walk.path}: no message could be read ({summary})")
    return McapContents(
        walk.path,
        walk.channels,
        walk.messages,
        walk.metadata,
        complete,
        tuple(walk.problems),
        walk.expected,
        walk.read,
    )


class McapStream:
    """The messages of an MCAP file one at a time, as :func:`read_mcap` would read them.

    Iterate once: each item is ``(channel id, channel, log time ns, data)`` in file order
    (the order the recorder and ``write_trace_mcap`` write, i.e. log-time order), ``channel``
    as defined before the message in the file, else by the summary when its CRC holds, else
    None (counted as lost). What is held is one chunk's records at a time. After the iteration
    ``contents`` holds channels, metadata and problems as ``read_mcap`` gives them, with
    ``messages`` empty.

    Parameters
    ----------
    path : str or Path
        The file.
    require_messages : bool
        As for ``read_mcap``.

    Raises
    ------
    BadInputError
        While iterating: as ``read_mcap`` (not MCAP at the first item, no message at the end).
    """

    def __init__(self, path: str | Path, *, require_messages: bool = True) -> None:
        self.path = Path(path)
        self.require_messages = require_messages
        self.contents: McapContents | None = None

    def __iter__(self) -> Iterator[tuple[int, McapChannel | None, int, bytes]]:
        with _mapped(self.path) as data:
            early = _check_start(self.path, data, self.require_messages)
            if early is not None:
                self.contents = early
                return
            walk = _Walk(self.path)
            fallback = _summary_channels(data)
            known: dict[int, McapChannel | None] = {}
            defined = (0, 0)
            orphans = 0
            for message in _walk_messages(walk, data):
                cid = message.channel_id
                if defined != (len(walk.raw_channels), len(walk.schemas)):
                    known.clear()  # a definition came in: look channels up again
                    defined = (len(walk.raw_channels), len(walk.schemas))
                if cid not in known:
                    known[cid] = _channel_of(walk, fallback, cid)
                channel = known[cid]
                orphans += channel is None
                yield cid, channel, message.log_time, message.data
            walk.resolve_channels(orphans)
            self.contents = _finish(walk, data, self.require_messages)


def _channel_of(
    walk: _Walk, fallback: tuple[dict[int, Schema], dict[int, Channel]], cid: int
) -> McapChannel | None:
    """Channel ``cid`` as defined so far in the file, else as the summary defines it."""
    schemas, channels = fallback
    raw = walk.raw_channels.get(cid) or channels.get(cid)
    if raw is None:
        return None
    schema = walk.schemas.get(raw.schema_id) or schemas.get(raw.schema_id)
    return McapChannel(raw.topic, raw.message_encoding, schema)


def _summary_channels(data: bytes | mmap.mmap) -> tuple[dict[int, Schema], dict[int, Channel]]:
    """Schemas and channels of the file's summary when it has one that its CRC vouches for (or
    that was written without a CRC); empty otherwise."""
    end = len(data) - len(MAGIC) - _FOOTER.size
    if end < len(MAGIC) or data[end + _FOOTER.size :] != MAGIC or _damaged_summary(data):
        return {}, {}
    opcode, length, start, _, _ = _FOOTER.unpack(data[end : end + _FOOTER.size])
    if opcode != Opcode.FOOTER or length != _FOOTER.size - 9 or not len(MAGIC) <= start < end:
        return {}, {}
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for _, op, body in _records(data, start, end, []):
        if op not in (Opcode.SCHEMA, Opcode.CHANNEL):
            continue
        try:
            record = _parse(op, body)
        except _PARSE_ERRORS:
            continue
        if op == Opcode.SCHEMA:
            schemas.setdefault(record.id, record)
        else:
            channels.setdefault(record.id, record)
    return schemas, channels


def read_mcap_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """The metadata records of an MCAP file as ``read_mcap`` gives them (``metadata``), read
    without decompressing a chunk: a pass over the top-level record headers.

    Raises
    ------
    BadInputError
        If the file does not start with the MCAP magic.
    OSError
        If the file cannot be read.
    """
    path = Path(path)
    metadata: dict[str, dict[str, str]] = {}
    with _mapped(path) as data:
        _check_start(path, data, True)
        pos, end = len(MAGIC), len(data)
        while end - pos >= _RECORD_HEADER.size:
            opcode, length = _RECORD_HEADER.unpack(data[pos : pos + _RECORD_HEADER.size])
            body = pos + _RECORD_HEADER.size
            if length > end - body or opcode == Opcode.FOOTER:
                break
            if opcode == Opcode.METADATA:
                with contextlib.suppress(*_PARSE_ERRORS):
                    record = _parse(opcode, bytes(data[body : body + length]))
                    metadata.setdefault(record.name, {}).update(record.metadata)
            pos = body + length
    return metadata


def warn_if_damaged(contents: McapContents, extra: tuple[str, ...] = ()) -> None:
    """Issue one :class:`DamagedRecordingWarning` saying what of ``contents`` was lost."""
    problems = contents.problems + extra
    if not problems:
        return
    read = contents.messages_read
    of = f" of {contents.expected_messages}" if contents.expected_messages else ""
    warnings.warn(
        DamagedRecordingWarning(
            f"{contents.path}: recording read in part ({read}{of} messages read): "
            f"{'; '.join(problems)}"
        ),
        stacklevel=3,
    )


def ros2_decoder(channel: McapChannel) -> Callable[[bytes], Any] | None:
    """A CDR decoder for the channel's ``ros2msg`` schema; None if it has another encoding,
    no schema, or a schema that does not parse."""
    if channel.schema is None:
        return None
    try:
        # The vendored rosidl parser prints a line to stderr before raising: keep it off the
        # user's terminal (the warning says the schema does not parse).
        with contextlib.redirect_stderr(io.StringIO()):
            return DecoderFactory().decoder_for(channel.message_encoding, channel.schema)
    except Exception:
        # The schema text is input and its parser raises many kinds: any error means unusable.
        return None
