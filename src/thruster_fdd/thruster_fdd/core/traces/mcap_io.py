"""Traces as MCAP recordings, and ROS message definitions as rosbag2 writes them. No rclpy.

MCAP files use schema encoding ``ros2msg`` and message encoding ``cdr``; a schema's data is the
message definition followed by the definitions it depends on, each after a line of 80 ``=``
and a ``MSG: pkg/Type`` line (rosbag2's layout), so the files open in rosbag2's MCAP plugin,
Foxglove and the ``mcap`` / ``mcap-ros2-support`` readers. Definitions are read from the
``share/<pkg>/msg/*.msg`` files of the installed packages (``AMENT_PREFIX_PATH``), or, for a
recorder whose environment lacks a package, from the ``rosbags`` type store of ROS 2 Jazzy's
standard messages (``describe``).

Simulated traces are written with wall-clock-like stamps (a time origin plus the trace's own
time, the origin kept in the metadata), so tools show a real date; reading subtracts the origin
again, so a trace comes back with the times it was written with.
"""

from __future__ import annotations

import os
import re
import struct
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
from mcap_ros2.writer import Writer

from thruster_fdd.core.atomic import replaced_file
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES
from thruster_fdd.core.traces.data import Trace, check_units, finite_rows
from thruster_fdd.core.traces.mcap_read import (
    McapChannel,
    McapContents,
    McapStream,
    read_mcap,
    read_mcap_metadata,
    ros2_decoder,
    warn_if_damaged,
)

TELEMETRY_TYPE = "thruster_fdd_msgs/msg/EscTelemetry"


METADATA_NAME = "thruster_fdd"


ORIGIN_KEY = "time_origin_ns"
"""Metadata key of a simulated recording's time origin: stamp = origin + trace time (ns)."""


_SEPARATOR = "=" * 80


_PRIMITIVES = frozenset(
    [
        "bool",
        "byte",
        "char",
        "float32",
        "float64",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "string",
        "wstring",
    ]
)


_TELEMETRY_TOPIC = re.compile(r"^/thruster/(?P<id>[^/]+)/esc/telemetry$")


def telemetry_topic(thruster_id: str) -> str:
    """Topic of a thruster's telemetry, ``/thruster/<id>/esc/telemetry``."""
    return f"/thruster/{thruster_id}/esc/telemetry"


def _share_dirs() -> list[Path]:
    prefixes = os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)
    return [Path(p) / "share" for p in prefixes if p]


def _msg_file(type_name: str) -> Path:
    pkg, _, name = type_name.replace("/msg/", "/").partition("/")
    for share in _share_dirs():
        candidate = share / pkg / "msg" / f"{name}.msg"
        if candidate.is_file():
            return candidate
    raise BadInputError(
        f"no definition of {type_name} under AMENT_PREFIX_PATH (is the workspace sourced?)"
    )


def _dependencies(pkg: str, text: str) -> list[str]:
    deps: list[str] = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        # The first token is the type (constants are always primitive); drop array/bounds.
        field_type = re.sub(r"(\[.*\]|<=\d+)", "", line.split()[0])
        if field_type in _PRIMITIVES:
            continue
        if field_type == "Header":
            field_type = "std_msgs/Header"
        deps.append(field_type if "/" in field_type else f"{pkg}/{field_type}")
    return deps


def message_definition(type_name: str) -> str:
    """The full definition of a message type as rosbag2 stores it in MCAP schemas.

    Parameters
    ----------
    type_name : str
        ``pkg/msg/Type`` or ``pkg/Type``.

    Raises
    ------
    ValueError
        If a definition is not found under ``AMENT_PREFIX_PATH``.
    """
    pkg = type_name.split("/", 1)[0]
    main = _msg_file(type_name).read_text()
    parts = [main.rstrip("\n")]
    seen: set[str] = set()
    queue = _dependencies(pkg, main)
    while queue:
        dep = queue.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        text = _msg_file(dep).read_text()
        parts.append(f"{_SEPARATOR}\nMSG: {dep}\n{text.rstrip(chr(10))}")
        queue.extend(_dependencies(dep.split("/", 1)[0], text))
    return "\n".join(parts) + "\n"


def describe(type_name: str) -> str | None:
    """The rosbag2-style definition of a message type, or None when nobody can describe it.

    From the installed packages (``message_definition``) first, else from the ``rosbags`` type
    store of ROS 2 Jazzy's standard messages.
    """
    try:
        return message_definition(type_name)
    except BadInputError:
        pass
    from rosbags.typesys import Stores, TypesysError, get_typestore

    name = type_name if "/msg/" in type_name else type_name.replace("/", "/msg/", 1)
    try:
        text, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(name, ros_version=2)
    except (KeyError, ValueError, TypesysError):
        return None
    return text


def _label_segments(trace: Trace, origin_s: float) -> str:
    labels = trace.sample_labels()
    if labels is None:
        return ""
    starts = [0] + [i for i in range(1, len(labels)) if labels[i] != labels[i - 1]]
    return ";".join(f"{origin_s + trace.t[i]:.6f}:{labels[i]}" for i in starts)


def write_trace_mcap(
    traces: Iterable[Trace], path: str | Path, *, origin_ns: int | None = None
) -> None:
    """Write traces as ``EscTelemetry`` messages on each thruster's telemetry topic.

    Stamps are ``origin_ns`` plus each sample's time (None: the wall clock now, whole seconds),
    so a simulated recording carries a real date; the origin goes into the ``thruster_fdd``
    metadata record (``time_origin_ns``) with the labels (``labels.<id>`` =
    ``stamp_s:class;...``, on the stamps' clock). A trace without ``thruster_id`` is written
    as ``t0``. The file appears whole or not at all.
    """
    origin = (time.time_ns() // 1_000_000_000) * 1_000_000_000 if origin_ns is None else origin_ns
    with replaced_file(path) as tmp, tmp.open("wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef(TELEMETRY_TYPE, message_definition(TELEMETRY_TYPE))
        metadata: dict[str, str] = {ORIGIN_KEY: str(origin)}
        for trace in traces:
            tid = trace.thruster_id or "t0"
            metadata[f"labels.{tid}"] = _label_segments(trace, origin * 1e-9)
            topic = telemetry_topic(tid)
            pwm = np.rint(1500 + 400 * trace.command).astype(int)
            temperature = trace.extra.get("temperature", np.zeros(len(trace)))
            for i in range(len(trace)):
                stamp_ns = origin + round(float(trace.t[i]) * 1e9)
                sec, nanosec = divmod(stamp_ns, 1_000_000_000)
                message = {
                    "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": tid},
                    "thruster_id": tid,
                    "sequence": i,
                    "command": float(trace.command[i]),
                    "pwm_us": int(pwm[i]),
                    "voltage_v": float(trace.voltage[i]),
                    "current_a": float(trace.current[i]),
                    "rpm": float(trace.rpm[i]),
                    "temperature_c": float(temperature[i]),
                    "status": 0,
                }
                writer.write_message(topic, schema, message, stamp_ns, stamp_ns, i)
        writer._writer.add_metadata(METADATA_NAME, metadata)  # mcap_ros2 exposes no wrapper
        writer.finish()


# What decoding a damaged CDR message can raise (the decoder is generated from the schema), or
# reading a field that another version of the schema does not have.
DECODE_ERRORS = (
    ValueError,
    IndexError,
    KeyError,
    TypeError,
    AttributeError,
    OverflowError,
    MemoryError,
    struct.error,
    UnicodeDecodeError,
)


def read_trace_mcap(path: str | Path) -> list[Trace]:
    """Read every thruster's telemetry from an MCAP file as traces (one per thruster id).

    Labels come from the ``thruster_fdd`` metadata record when present. A damaged recording
    (cut short, chunks failing their CRC, undecodable messages, a telemetry channel with another
    schema or encoding) gives what can be read and one ``DamagedRecordingWarning`` saying what
    was lost (``core.traces.mcap_read``); samples with non-finite values are left out with a
    ``TraceWarning``.

    Raises
    ------
    BadInputError
        If the file is not an MCAP recording, holds no readable ``EscTelemetry`` on
        ``/thruster/<id>/esc/telemetry``, has malformed label metadata, or a column is
        plausibly in the wrong unit (``data.check_units``).
    """
    contents = read_mcap(path)
    path = contents.path
    meta = contents.metadata.get(METADATA_NAME, {})
    segments = {k.removeprefix("labels."): v for k, v in meta.items() if k.startswith("labels.")}
    columns: dict[str, dict[str, list[float]]] = {}
    try:
        origin_ns = int(meta.get(ORIGIN_KEY, "0"))
    except ValueError:
        raise BadInputError(f"{path}: {ORIGIN_KEY} metadata is not an integer") from None
    problems: list[str] = []
    undecodable = 0
    for channel, messages in _telemetry_channels(contents, problems):
        decode = ros2_decoder(channel)
        if decode is None:
            problems.append(
                f"{channel.topic}: schema does not parse; {len(messages)} message(s) skipped"
            )
            continue
        tid = _TELEMETRY_TOPIC.match(channel.topic)["id"]  # type: ignore[index]
        cols = columns.setdefault(tid, {k: [] for k in ("t", *_FIELDS)})
        for data in messages:
            try:
                msg = decode(data)
                stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                row = [(stamp_ns - origin_ns) * 1e-9]
                row += [float(getattr(msg, field)) for field in _FIELDS.values()]
            except DECODE_ERRORS:
                undecodable += 1
                continue
            for key, value in zip(("t", *_FIELDS), row, strict=True):
                cols[key].append(value)
    if undecodable:
        problems.append(f"{undecodable} telemetry message(s) do not decode")
    warn_if_damaged(contents, tuple(problems))
    columns = {tid: cols for tid, cols in columns.items() if cols["t"]}
    if not columns:
        raise BadInputError(f"{path}: no readable {TELEMETRY_TYPE} on /thruster/<id>/esc/telemetry")
    origin_s = origin_ns * 1e-9
    return [
        _trace(path, tid, cols, segments.get(tid, ""), origin_s)
        for tid, cols in sorted(columns.items())
    ]


TelemetryRow = tuple[str, float, float, float, float, float, float]
"""One decoded telemetry message: thruster id, t (s), command (-1..1), voltage (V), rpm, current
(A), temperature (°C)."""


def iter_trace_mcap(path: str | Path) -> Iterator[TelemetryRow]:
    """Every thruster's telemetry of an MCAP file, one message at a time in file order, as
    ``read_trace_mcap`` decodes it (same times, same values, before its finite filter, sort and
    unit check, which need the whole trace); memory bounded by one chunk.

    The time origin and labels come from the metadata records (read first, without
    decompressing a chunk). At the end, the same ``DamagedRecordingWarning`` as
    ``read_trace_mcap`` says what was lost, and the label metadata of the thrusters seen is
    checked.

    Raises
    ------
    BadInputError
        If the file is not an MCAP recording, its origin metadata is not an integer (at the
        first item); if it held no readable ``EscTelemetry`` or has malformed label metadata
        (at the end).
    """
    path = Path(path)
    meta = read_mcap_metadata(path).get(METADATA_NAME, {})
    try:
        origin_ns = int(meta.get(ORIGIN_KEY, "0"))
    except ValueError:
        raise BadInputError(f"{path}: {ORIGIN_KEY} metadata is not an integer") from None
    stream = McapStream(path)
    plans: dict[int, tuple[McapChannel | None, str | None, object]] = {}
    counts: dict[int, int] = {}
    seen: set[str] = set()
    undecodable = 0
    fields = tuple(_FIELDS.values())
    for cid, channel, _, data in stream:
        plan = plans.get(cid)
        if plan is None or plan[0] is not channel:
            plan = plans[cid] = (channel, *_telemetry_plan(channel))
        _, tid, decode = plan
        if tid is None:
            continue
        counts[cid] = counts.get(cid, 0) + 1
        if decode is None:
            continue
        try:
            msg = decode(data)  # type: ignore[operator]
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            row = (tid, (stamp_ns - origin_ns) * 1e-9, *(float(getattr(msg, f)) for f in fields))
        except DECODE_ERRORS:
            undecodable += 1
            continue
        seen.add(tid)
        yield row  # type: ignore[misc]
    contents = stream.contents
    assert contents is not None
    problems = _channel_problems(contents, counts)
    if undecodable:
        problems.append(f"{undecodable} telemetry message(s) do not decode")
    warn_if_damaged(contents, tuple(problems))
    if not seen:
        raise BadInputError(f"{path}: no readable {TELEMETRY_TYPE} on /thruster/<id>/esc/telemetry")
    segments = {k.removeprefix("labels."): v for k, v in meta.items() if k.startswith("labels.")}
    for tid in sorted(seen):
        _check_label_names(f"{path} ({tid})", segments.get(tid, ""), origin_ns * 1e-9)


def _telemetry_plan(channel: McapChannel | None) -> tuple[str | None, object]:
    """(thruster id, decoder) of a telemetry channel of the right kind; (id, None) of one on a
    telemetry topic that cannot be decoded; (None, None) of any other."""
    match = None if channel is None else _TELEMETRY_TOPIC.match(channel.topic)
    if match is None:
        return None, None
    assert channel is not None
    if not _right_kind(channel):
        return match["id"], None
    return match["id"], ros2_decoder(channel)


def _right_kind(channel: McapChannel) -> bool:
    schema = channel.schema
    kind = None if schema is None else (schema.name, schema.encoding, channel.message_encoding)
    return kind == (TELEMETRY_TYPE, "ros2msg", "cdr")


def _channel_problems(contents: McapContents, counts: dict[int, int]) -> list[str]:
    """What ``read_trace_mcap`` says of telemetry channels of another kind and of schemas that
    do not parse, in its order, from the messages counted per channel."""
    wrong, unparsed = [], []
    for cid, channel in sorted(contents.channels.items()):
        if _TELEMETRY_TOPIC.match(channel.topic) is None:
            continue
        n = counts.get(cid, 0)
        if not _right_kind(channel):
            schema = channel.schema
            got = (
                "no schema"
                if schema is None
                else f"{schema.name} in {schema.encoding} / {channel.message_encoding}"
            )
            wrong.append(
                f"{channel.topic}: {got}, not {TELEMETRY_TYPE} in ros2msg / cdr; "
                f"{n} message(s) skipped"
            )
        elif ros2_decoder(channel) is None:
            unparsed.append(f"{channel.topic}: schema does not parse; {n} message(s) skipped")
    return wrong + unparsed


def _check_label_names(source: str, text: str, origin_s: float) -> None:
    """BadInputError, as ``read_trace_mcap`` gives it, when label metadata is malformed or names
    an unknown class."""
    _labels_from_segments(source, np.zeros(0), text, origin_s)
    names = {p.partition(":")[2] for p in text.split(";")} if text else set()
    unknown = names - set(CLASS_NAMES)
    if unknown:
        raise BadInputError(
            f"{source}: unknown condition {sorted(unknown)}; expected one of "
            f"{', '.join(CLASS_NAMES)}"
        )


# Trace column -> EscTelemetry field.
_FIELDS = {
    "command": "command",
    "voltage": "voltage_v",
    "rpm": "rpm",
    "current": "current_a",
    "temperature": "temperature_c",
}


def _telemetry_channels(
    contents: McapContents, problems: list[str]
) -> list[tuple[McapChannel, list[bytes]]]:
    """The telemetry channels of a recording with their messages' data; channels on a telemetry
    topic with another type or encoding are named in ``problems`` and left out."""
    by_channel: dict[int, list[bytes]] = {}
    for cid, _, data in contents.messages:
        by_channel.setdefault(cid, []).append(data)
    out = []
    for cid, channel in sorted(contents.channels.items()):
        if _TELEMETRY_TOPIC.match(channel.topic) is None:
            continue
        schema = channel.schema
        kind = None if schema is None else (schema.name, schema.encoding, channel.message_encoding)
        if kind != (TELEMETRY_TYPE, "ros2msg", "cdr"):
            got = "no schema" if kind is None else f"{kind[0]} in {kind[1]} / {kind[2]}"
            problems.append(
                f"{channel.topic}: {got}, not {TELEMETRY_TYPE} in ros2msg / cdr; "
                f"{len(by_channel.get(cid, []))} message(s) skipped"
            )
            continue
        out.append((channel, by_channel.get(cid, [])))
    return out


def _trace(
    path: Path, tid: str, cols: dict[str, list[float]], segments: str, origin_s: float
) -> Trace:
    """One thruster's trace from its decoded columns: non-finite samples left out, sorted by
    time, a sample recorded twice (a re-sent frame) kept once, labels attached, units checked."""
    source = f"{path} ({tid})"
    arrays = finite_rows({k: np.asarray(v, dtype=float) for k, v in cols.items()}, source)
    order = np.argsort(arrays["t"], kind="stable")
    arrays = {k: v[order] for k, v in arrays.items()}
    first = np.concatenate(([True], np.diff(arrays["t"]) > 0))
    arrays = {k: v[first] for k, v in arrays.items()}
    labels = _labels_from_segments(source, arrays["t"], segments, origin_s)
    uniform = labels is not None and bool((labels == labels[0]).all())
    try:
        trace = Trace(
            t=arrays["t"],
            command=arrays["command"],
            voltage=arrays["voltage"],
            rpm=arrays["rpm"],
            current=arrays["current"],
            condition=str(labels[0]) if uniform else None,
            thruster_id=tid,
            extra={"temperature": arrays["temperature"]},
            labels=None if uniform else labels,
        )
    except BadInputError as exc:
        raise BadInputError(f"{source}: {exc}") from None
    check_units(trace, source)
    return trace


def _labels_from_segments(
    source: str, t: np.ndarray, text: str, origin_s: float
) -> np.ndarray | None:
    """Per-sample class names from ``start_s:class;...`` metadata (starts on the stamps' clock,
    ``origin_s`` subtracted); None when there is none."""
    if not text:
        return None
    try:
        segments = [
            (float(start), name) for start, _, name in (p.partition(":") for p in text.split(";"))
        ]
    except ValueError:
        raise BadInputError(
            f"{source}: label metadata {text[:60]!r} is not start_s:class;..."
        ) from None
    labels = np.full(len(t), segments[0][1], dtype=object)
    for start, name in segments[1:]:
        # Segment starts are on the stamps' clock, printed to the microsecond.
        labels[t >= start - origin_s - 1e-5] = name
    return labels
