"""What every node of the package does the same way: parameters, status, executor, running."""

from __future__ import annotations

import os
import re
import signal
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.context import Context
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.subscription import Subscription
from rclpy.task import Future
from rclpy.utilities import remove_ros_args

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.names import check_thruster_id
from thruster_fdd.lifetime import stop_with_parent

RELIABLE_10 = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)

# rclpy gives every publisher and subscription two QoS event handlers by default (warnings for
# an incompatible QoS or type on the other side); each is a waitable that the executor adds to
# its wait set again on every wake, in Python. Without them the nodes' publishers and
# subscriptions cost a fraction per message (bench_latency, 4 thrusters at 50 Hz: diagnosis
# published median 4.1-5.3 -> 2.2-3.6 ms over three A/B pairs). The peer still warns about a
# mismatch from its side; the recorder keeps them (a mismatch there would lose data silently).
NO_PUB_EVENTS = PublisherEventCallbacks(use_default_callbacks=False)
NO_SUB_EVENTS = SubscriptionEventCallbacks(use_default_callbacks=False)


Limit = tuple[float, float] | tuple[str, ...]
"""What a parameter may be: ``(low, high)`` (inclusive, as a descriptor's range) for a number,
the allowed values for a string."""

SHARED_LIMITS: dict[str, Limit] = {
    "diagnostics_period_s": (0.01, 3600.0),
    "stale_after_s": (0.01, 3600.0),
    "period_s": (0.01, 3600.0),
    "hop_s": (0.01, 3600.0),
    "hysteresis": (1, 100),
    "unknown_threshold": (-1.0, 1.0e6),
    "false_alarms_per_hour": (1.0e-9, 100.0),
    "unit_allowance": (0.0, 13.8),
}
"""Limits of parameters that mean the same in every node that has them (used where a node's
module gives none of its own)."""

_UNIT = re.compile(r", ([^\s,()]+)(?: \(.*\))?$")
_KINDS = {bool: "bool", int: "integer", float: "double", str: "string", list: "string list"}
_ARTICLES = {"integer": "an integer", "double": "a number", "bool": "true or false"}


class BadParameterError(BadInputError):
    """A parameter given to a node (``-p name:=value``, a parameters file) has the wrong type or
    is out of its range; the text names it and what it may be."""


def parameter_unit(description: str) -> str:
    """The unit a parameter's description ends with (``"serial baud rate, bit/s"`` -> ``bit/s``,
    a note in parentheses after it allowed), ``""`` when it names none."""
    match = _UNIT.search(description)
    return match[1] if match else ""


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


def _limit_text(limit: Limit | None) -> str:
    if limit is None:
        return ""
    if limit and isinstance(limit[0], str):
        return "one of " + ", ".join(str(v) for v in limit)
    return f"{_number(limit[0])}..{_number(limit[1])}"  # type: ignore[arg-type]


def parameter_descriptor(
    name: str, default: object, description: str, limit: Limit | None = None
) -> ParameterDescriptor:
    """The descriptor of one parameter: its description (with the allowed values of a string)
    and, for a number with ``limit``, its ``IntegerRange`` or ``FloatingPointRange``."""
    descriptor = ParameterDescriptor(name=name, description=description)
    if limit is None:
        return descriptor
    if isinstance(limit[0], str):
        descriptor.additional_constraints = _limit_text(limit)
    elif isinstance(default, int) and not isinstance(default, bool):
        descriptor.integer_range = [IntegerRange(from_value=int(limit[0]), to_value=int(limit[1]))]
    elif isinstance(default, float):
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(limit[0]), to_value=float(limit[1]))
        ]
    return descriptor


def _limit(name: str, limits: Mapping[str, Limit] | None) -> Limit | None:
    return (limits or {}).get(name, SHARED_LIMITS.get(name))


def _given(node: Node, name: str) -> object:
    """The value given for ``name`` (command line, parameters file, overrides); rclpy keeps
    them in ``Node._parameter_overrides`` and has no public accessor."""
    given = getattr(node, "_parameter_overrides", {}).get(name)
    return "?" if given is None else given.value


def declare_parameters(
    node: Node,
    parameters: Iterable[tuple[str, object, str]],
    limits: Mapping[str, Limit] | None = None,
) -> None:
    """Declare ``(name, default, description)`` parameters with their descriptors.

    Parameters
    ----------
    node : Node
        The node.
    parameters : iterable of (name, default, description)
        The node's table (``PARAMETERS`` of its module); a description ends with the unit.
    limits : mapping of name to Limit, optional
        Ranges of numbers and allowed values of strings (``LIMITS`` of the module; otherwise
        ``SHARED_LIMITS``).

    Raises
    ------
    BadParameterError
        If a value given for a parameter has another type than its default, is out of range or
        not one of the allowed values.
    """
    for name, default, description in parameters:
        limit = _limit(name, limits)
        try:
            value = node.declare_parameter(
                name, default, parameter_descriptor(name, default, description, limit)
            ).value
        except InvalidParameterTypeException:
            given = _given(node, name)
            if isinstance(default, float) and type(given) is int:
                raise BadParameterError(
                    f"parameter {name}: {given} is an integer, the parameter a double "
                    f"(write {given}.0)"
                ) from None
            kind = _KINDS.get(type(default), "value")
            kind = _ARTICLES.get(kind, f"a {kind}")
            raise BadParameterError(
                f"parameter {name}: {given!r} is not {kind} (default {default!r})"
            ) from None
        except InvalidParameterValueException:
            raise BadParameterError(
                f"parameter {name}: {_given(node, name)!r} is out of range {_limit_text(limit)}"
            ) from None
        if limit and isinstance(limit[0], str) and value not in limit:
            raise BadParameterError(f"parameter {name}: {value!r} is not {_limit_text(limit)}")


def parameters_help(
    prog: str,
    summary: str,
    parameters: Iterable[tuple[str, object, str]],
    limits: Mapping[str, Limit] | None = None,
) -> str:
    """The ``--help`` text of a node executable: usage, ``summary`` and every parameter with its
    type, default, unit and range (the same as its descriptor)."""
    lines = [
        f"usage: {prog} [-h] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] ...]",
        "",
        summary,
        "",
        "parameters (-p NAME:=VALUE; a change at run time is checked against the same ranges):",
    ]
    for name, default, description in parameters:
        facts = [_KINDS.get(type(default), type(default).__name__), f"default {default!r}"]
        unit = parameter_unit(description)
        if unit:
            facts.append(f"unit {unit}")
        limit = _limit_text(_limit(name, limits))
        if limit:
            facts.append(f"range {limit}" if not limit.startswith("one of") else limit)
        lines += [f"  {name}  ({'; '.join(facts)})", f"      {description}"]
    return "\n".join(lines) + "\n"


def _node_tables(
    factory: Callable[..., Node],
) -> tuple[str, tuple[tuple[str, object, str], ...], Mapping[str, Limit]]:
    """The summary line, parameter table and limits of a node class's module."""
    module = sys.modules.get(getattr(factory, "__module__", ""))
    doc = (getattr(module, "__doc__", None) or factory.__doc__ or "").strip()
    return (
        doc.splitlines()[0] if doc else "",
        tuple(getattr(module, "PARAMETERS", ())),
        getattr(module, "LIMITS", {}),
    )


def refuse_start_only(
    params: Iterable[Any], declared: Iterable[tuple[str, object, str]], runtime: set[str]
) -> SetParametersResult | None:
    """The refusal of a parameter change that touches a parameter read at start only (one of
    ``declared`` not in ``runtime``), naming it; None when every change may go ahead."""
    fixed = {name for name, _, _ in declared} - runtime
    for param in params:
        if param.name in fixed:
            return SetParametersResult(
                successful=False, reason=f"{param.name} is read at start only"
            )
    return None


def diagnostics_publisher(node: Node) -> Publisher:
    """The node's publisher on ``/diagnostics`` (reliable, depth 10)."""
    return node.create_publisher(
        DiagnosticArray, "/diagnostics", RELIABLE_10, event_callbacks=NO_PUB_EVENTS
    )


def subscribe_thrusters(
    node: Node,
    thruster_ids: Iterable[str],
    msg_type: type,
    topic: str,
    callback: Callable[[str, Any], None],
    qos: QoSProfile,
) -> dict[str, Subscription]:
    """Subscribe ``node`` to ``/thruster/<id>/<topic>`` of every thruster; ``callback(id, msg)``
    gets each message with the id of the thruster that sent it. Returns the subscriptions by id.

    Raises
    ------
    BadParameterError
        If an id is not a valid thruster id (``core.names.check_thruster_id``).
    """
    thruster_ids = list(thruster_ids)
    for tid in thruster_ids:
        try:
            check_thruster_id(tid)
        except BadInputError as exc:
            raise BadParameterError(f"parameter thruster_ids: {exc}") from None
    return {
        tid: node.create_subscription(
            msg_type,
            f"/thruster/{tid}/{topic}",
            lambda msg, tid=tid: callback(tid, msg),
            qos,
            event_callbacks=NO_SUB_EVENTS,
        )
        for tid in thruster_ids
    }


RecordSink = Callable[[str, type, bytes], None]
"""Where a node of a container hands each message it publishes or takes, as ``(topic,
message class, CDR bytes)``: the recorder of the same process (``Recorder.record``)."""


def publish_recorded(publisher: Publisher, msg: Any, sink: RecordSink | None) -> None:
    """Publish ``msg``; with a ``sink``, serialise it once and hand the same bytes to DDS and to
    the sink (the recorder then never takes the message again over DDS)."""
    if sink is None:
        publisher.publish(msg)
        return
    data = serialize_message(msg)
    publisher.publish(data)
    sink(publisher.topic_name, type(msg), data)


STATUS_PREFIX = "thruster_fdd: "
"""Start of every status name on ``/diagnostics`` (diagnostic_updater's ``<node>: <task>`` form,
the package standing for the node: a vehicle runs several of each node)."""


def status_name(task: str, thruster_id: str = "") -> str:
    """The ``/diagnostics`` status name of ``task`` (``esc``, ``nominal_model``, ``classifier``,
    ``recorder``, ``health``) for one thruster or the vehicle: ``thruster_fdd: esc t0``."""
    return f"{STATUS_PREFIX}{task} {thruster_id}" if thruster_id else f"{STATUS_PREFIX}{task}"


def parse_status_name(name: str) -> tuple[str, str] | None:
    """``(task, thruster id)`` of a status name made by ``status_name`` (id ``""`` for the
    vehicle), or None for another name."""
    if not name.startswith(STATUS_PREFIX):
        return None
    task, _, thruster_id = name.removeprefix(STATUS_PREFIX).partition(" ")
    return task, thruster_id


def publish_status(
    node: Node,
    publisher: Publisher,
    level: int | bytes,
    name: str,
    message: str,
    hardware_id: str,
    values: Iterable[tuple[str, str]],
) -> None:
    """Publish one ``DiagnosticStatus`` (``name`` from ``status_name``; ``hardware_id`` stable:
    the thruster id, or the vehicle for vehicle-wide nodes)."""
    status = DiagnosticStatus(
        level=level if isinstance(level, bytes) else bytes([level]),
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=k, value=v) for k, v in values],
    )
    array = DiagnosticArray(status=[status])
    array.header.stamp = node.get_clock().now().to_msg()
    publisher.publish(array)


EXECUTOR_ENV = "THRUSTER_FDD_EXECUTOR"
"""Environment variable choosing the executor of every node process: ``events`` (default) or
``single`` (rclpy's SingleThreadedExecutor, the fallback)."""
EXECUTORS = ("events", "single")

SPIN_SLICE_S = 0.25
"""Longest single wait of an EventsExecutor spin, s: how late an idle process notices Ctrl-C."""


def executor_kind() -> str:
    """The executor named by ``THRUSTER_FDD_EXECUTOR`` (``events`` when unset).

    Raises
    ------
    ValueError
        If the variable names another executor.
    """
    kind = os.environ.get(EXECUTOR_ENV, "events") or "events"
    if kind not in EXECUTORS:
        raise ValueError(f"{EXECUTOR_ENV}={kind!r}: expected one of {', '.join(EXECUTORS)}")
    return kind


def make_executor(kind: str | None = None, context: Context | None = None) -> Any:
    """A new executor of ``kind`` (default: ``executor_kind()``) on ``context``.

    ``events`` is rclpy's EventsExecutor (``rclpy.experimental``): the middleware calls it back
    per entity that has work, instead of the wait set that rclpy's own executors rebuild from
    every entity of their nodes on each wake (``docs/development.md``). In rclpy 7.1.6 it supports
    no guard conditions (a thread wakes it with ``executor.create_task``, which works with both
    kinds) and no subscription callback that takes the message info (it passes ``(msg, info)`` as
    one argument and fails). Spin it with :func:`spin`, never with its own ``spin()`` (see there).
    """
    if (kind or executor_kind()) == "events":
        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def spin(executor: Any) -> None:
    """Spin ``executor`` until its context shuts down (or Ctrl-C, or a callback raises).

    rclpy 7.1.6's ``EventsExecutor.spin()`` waits on a condition variable until
    ``steady_clock::time_point::max()``; the wheel's libstdc++ (built for glibc 2.28, without
    ``pthread_cond_clockwait``) converts that deadline to the system clock, which overflows, so
    every wait returns at once: the thread spins at full CPU holding the event queue's lock,
    the middleware threads that queue events block on it, callbacks starve and Ctrl-C is never
    seen (measured: a node with one timer and one subscription ran none of them at 0.2-0.6
    cores). A finite deadline converts correctly, so an EventsExecutor is spun in slices of
    ``SPIN_SLICE_S`` (each runs every event that arrives within it).

    On Ctrl-C rclpy shuts the context down before Python sees the interrupt, so an event
    already queued can run into the closed context (``RCLError`` from a publish): that ends the
    spin like the shutdown itself.

    Raises
    ------
    ExternalShutdownException
        When the context shuts down while spinning (from the EventsExecutor).
    """
    if isinstance(executor, Executor):
        executor.spin()
        return
    never = Future()
    while executor.context.ok():
        try:
            executor.spin_until_future_complete(never, timeout_sec=SPIN_SLICE_S)
        except _rclpy.RCLError:
            if executor.context.ok():
                raise
            return


def spin_until(
    executor: Any, predicate: Callable[[], bool], deadline: float, step_s: float = 0.05
) -> bool:
    """Spin ``executor`` until ``predicate()`` holds (True) or ``time.monotonic()`` passes
    ``deadline`` (False); ``predicate`` is checked at least every ``step_s`` s."""
    never = Future()
    while not predicate():
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        if isinstance(executor, Executor):
            executor.spin_once(timeout_sec=min(step_s, left))
        else:
            executor.spin_until_future_complete(never, timeout_sec=min(step_s, left))
    return True


def init_rclpy(args: list[str] | None) -> None:
    """``rclpy.init(args=args)`` for a node process, with a Ctrl-C that ends only the spin.

    rclpy's SIGINT handler shuts the context down, which ends the spin, and then calls the
    handler installed before it; Python's default one raises KeyboardInterrupt at whatever line
    runs next, which is in the teardown (seen: at ``release_and_destroy``'s first line, so the
    recorder never finished its bag). So the handler before rclpy's only notes the signal; one
    that came before ``rclpy.init`` returned is raised here as KeyboardInterrupt.

    Raises
    ------
    KeyboardInterrupt
        If Ctrl-C came while rclpy was starting.
    """
    interrupted: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, _frame: interrupted.append(signum))
    rclpy.init(args=args)
    if interrupted:
        raise KeyboardInterrupt


def wants_help(args: list[str] | None) -> bool:
    """Whether a node's command line (``sys.argv`` when None) asks for ``-h`` / ``--help``
    outside its ``--ros-args`` part."""
    argv = sys.argv if args is None else args
    return bool({"-h", "--help"} & set(remove_ros_args(argv)[1:]))


def _rcl_reason(exc: Exception) -> str:
    """The first sentence of an rcl error (without rcl's source locations)."""
    return str(exc).splitlines()[0].split(". Error:")[0].split(", at /")[0]


def run(factory: Callable[[], Node], args: list[str] | None = None) -> None:
    """Run one node until Ctrl-C; exit 1 with the reason when it cannot start (ValueError).

    ``-h`` / ``--help`` prints the parameters (``parameters_help``, from the module's
    ``PARAMETERS`` and ``LIMITS``) and exits 0 without starting a node; a bad parameter
    (``BadParameterError``) or a command line rcl cannot parse is one line on stderr and exit 2.
    The executor is ``make_executor()``'s. A node with a ``shutdown()`` method gets it called
    before it is destroyed.
    """
    # The executable's name (``esc_driver``), also under ``python -m thruster_fdd.nodes.X``.
    module = str(getattr(factory, "__module__", ""))
    name = Path(sys.argv[0]).stem if module == "__main__" else module.rpartition(".")[2]
    try:
        help_asked = wants_help(args)
    except _rclpy.RCLError as exc:
        print(f"{name}: bad command line: {_rcl_reason(exc)}", file=sys.stderr)
        sys.exit(2)
    if help_asked:
        summary, parameters, limits = _node_tables(factory)
        sys.stdout.write(parameters_help(name, summary, parameters, limits))
        sys.exit(0)
    stop_with_parent()
    try:
        kind = executor_kind()
    except ValueError as exc:
        print(f"{name}: cannot start: {exc}", file=sys.stderr)
        sys.exit(1)
    try:
        init_rclpy(args)
    except KeyboardInterrupt:
        rclpy.try_shutdown()
        return
    except _rclpy.RCLError as exc:
        print(f"{name}: bad command line: {_rcl_reason(exc)}", file=sys.stderr)
        sys.exit(2)
    try:
        node = factory()
    except BadParameterError as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(2)
    except ValueError as exc:
        print(f"{name}: cannot start: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(1)
    executor = make_executor(kind)
    executor.add_node(node)
    try:
        spin(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        release_and_destroy([executor], [node])
        rclpy.try_shutdown()


TEARDOWN_TIMEOUT_S = 10
"""Longest teardown of a node process after Ctrl-C, s; then the process is ended."""


def release_and_destroy(executors: Iterable[Any], nodes: Iterable[Node]) -> None:
    """Shut the ``executors`` down, then call each node's ``shutdown()`` (if any) and destroy it.

    For the end of a node process only. A Ctrl-C inside a callback can leave handles in use,
    and rclpy's ``destroy_node`` then spins forever in C++ holding the GIL (seen: orphaned nodes
    at full CPU for half an hour). Shutting the executors down first drops their wait generators,
    which avoids most of it; for the rest an alarm ends the process ``TEARDOWN_TIMEOUT_S``
    after teardown began. SIGALRM's default action needs no Python code, so it works where a
    Python signal handler or thread could never run. The nodes' ``shutdown()`` hooks (files
    closed, neutral commands sent) come before anything that can hang.

    SIGINT is ignored from here on: a second Ctrl-C would land inside a hook (seen: a recorder
    stopped in the middle of finishing its bag's metadata; :func:`init_rclpy` keeps the first
    one from raising at all); the alarm bounds the teardown instead.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.alarm(TEARDOWN_TIMEOUT_S)
    for executor in executors:
        executor.shutdown(timeout_sec=1.0)
    for node in nodes:
        shutdown = getattr(node, "shutdown", None)
        if shutdown is not None:
            shutdown()
        node.destroy_node()
