"""``thruster-fdd replay``: a recording's telemetry through the model nodes, checked.

Starts a ``nominal_model`` (and, when a classifier is exported, a ``classifier``) node per
thruster of the bag, publishes the samples the live model used (``core.replay``) over reliable
QoS, collects the published diagnoses and compares them with the bag's recorded diagnoses or
ground truth. Exit 0 when every thruster passes, 1 when one does not.

Pacing, so no queue can overflow and nothing is lost however fast it runs: with a classifier,
the replay stays at most ``MAX_LAG`` samples ahead of the classifier's last decision, and the
nodes' residual counters on ``/diagnostics`` confirm at the end that every sample reached the
classifier; without one, at most ``IN_FLIGHT`` samples ahead of the residuals it gets back.
(Listening to every residual as well costs the replay about a fifth of its speed.)
"""

from __future__ import annotations

import argparse
import json
import struct
import subprocess
import sys
import time
from collections import deque
from pathlib import Path

from thruster_fdd.core.traces.replay_check import ReplayCheck, ThrusterBag, check_replay, load_bag
from thruster_fdd.lifetime import child_env, stop_children

DESCRIPTION = (
    "Replay the telemetry of an MCAP recording through freshly started model nodes "
    "(nominal_model, classifier) as fast as they answer, or at --rate times real time, and "
    "check the diagnoses they publish against the diagnoses recorded in the bag or the "
    "ground-truth labels of a simulated recording. Exit 0 when all thrusters pass, 1 if not."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd replay``."""
    p.add_argument("bag", type=Path, metavar="BAG", help="MCAP recording")
    p.add_argument("--rate", type=float, help="rate factor (default: as fast as possible)")
    p.add_argument("--models", type=Path, help="folder with nominal/ and classifier/")
    p.add_argument("--json", type=Path, metavar="OUT", help="write the result as JSON")
    p.add_argument(
        "--min-agreement", type=float, default=0.9, help="decisions that must match, 0..1"
    )
    p.set_defaults(func=run_replay)


# Samples published ahead of their residual: far below the nominal model's replay queue depth
# (reliable, 1000; ``reliable_telemetry``), so none can be dropped, and enough to keep the nodes
# busy between two answers.
IN_FLIGHT = 32
# Longest wait for the model nodes' statuses that confirm every sample arrived, s.
STATUS_WAIT_S = 3.0
# Start-up: time given to the model nodes to match each other once they match the replayer, s.
SETTLE_S = 1.0
# A residual not back after this long counts as lost, s (generous: a loaded CI machine).
ANSWER_TIMEOUT_S = 5.0
# No new diagnosis for this long ends the replay, s.
QUIET_S = 2.0


def _stamp_ns(cdr: bytes) -> int:
    """Header stamp (ns) of a serialized message that starts with a std_msgs/Header: after the
    4-byte encapsulation, ``int32 sec`` and ``uint32 nanosec`` in the byte order it names.
    Decoding only the stamp keeps the replayer's cost per residual small."""
    order = "<" if cdr[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(f"{order}iI", cdr, 4)
    return sec * 1_000_000_000 + nanosec


def _wait_answer(executor: object, answered: set[int], in_flight: deque[int]) -> int:
    """Wait for the oldest sample in flight to be answered; returns 1 on a time-out, else 0."""
    oldest = in_flight.popleft()
    deadline = time.monotonic() + ANSWER_TIMEOUT_S
    while oldest not in answered:
        if time.monotonic() > deadline:
            return 1
        executor.spin_once(timeout_sec=0.05)  # type: ignore[attr-defined]
    return 0


# Samples the classifier may fall behind the replay, below its queue depth (500) and the
# nominal model's (1000): a window (200 samples) plus slack. Its diagnoses' stamps tell how far
# it has got.
MAX_LAG = 300


def _wait_classifier(executor: object, diagnosed: dict[str, int], tid: str, index: int) -> int:
    """Wait until ``tid``'s classifier has decided on sample ``index``; 1 on a time-out."""
    deadline = time.monotonic() + 10.0
    while diagnosed[tid] < index:
        if time.monotonic() > deadline:
            return 1
        executor.spin_once(timeout_sec=0.05)  # type: ignore[attr-defined]
    return 0


# The residual counter each model node reports in its /diagnostics status.
COUNTERS = {"nominal_model": "residuals_published", "classifier": "residuals_received"}


def _missing_residuals(
    executor: object, bags: tuple[ThrusterBag, ...], counters: dict[str, dict[str, int]]
) -> int:
    """Samples that did not reach the classifier as residuals, from the nodes' counters.

    Waits for the next /diagnostics statuses (one a second) until every thruster's nominal
    model and classifier count all of its samples, at most ``STATUS_WAIT_S``.
    """

    def missing() -> int:
        return sum(
            len(b.stamps_ns) - min(counters[b.thruster_id].get(name, 0) for name in COUNTERS)
            for b in bags
        )

    deadline = time.monotonic() + STATUS_WAIT_S
    while missing() > 0 and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.1)  # type: ignore[attr-defined]
    return missing()


def _start_nodes(bags: tuple[ThrusterBag, ...], models: Path) -> dict[str, subprocess.Popen[bytes]]:
    """The model nodes of every thruster of ``bags``, by name ``<thruster>/<node>``."""
    procs = {}
    for bag in bags:
        for node, folder in (("nominal_model", "nominal"), ("classifier", "classifier")):
            if not (models / folder / "model_card.json").is_file():
                continue
            cmd = [sys.executable, "-m", f"thruster_fdd.nodes.{node}", "--ros-args"]
            cmd += ["-r", f"__ns:=/thruster/{bag.thruster_id}"]
            cmd += ["-p", f"thruster_id:={bag.thruster_id}", "-p", f"model_dir:={models / folder}"]
            if node == "nominal_model":
                cmd += ["-p", "reliable_telemetry:=true"]
            procs[f"{bag.thruster_id}/{node}"] = subprocess.Popen(
                cmd, stdout=subprocess.DEVNULL, env=child_env()
            )
    return procs


def run_replay(args: argparse.Namespace) -> int:
    """Replay ``args.bag`` and check the diagnoses; returns the exit code."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from thruster_fdd_msgs.msg import Diagnosis, EscTelemetry, Residual

    from thruster_fdd.core.artifact import default_models_dir
    from thruster_fdd.core.nominal.card import read_nominal_card

    if not args.bag.is_file():
        raise ValueError(f"{args.bag}: no such recording")
    models = (args.models or default_models_dir()).resolve()
    period = read_nominal_card(models / "nominal").sample_time_s
    bags = load_bag(args.bag, period)
    procs = _start_nodes(bags, models)
    context = Context()
    rclpy.init(context=context)
    node = Node("replay", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    answered: dict[str, set[int]] = {b.thruster_id: set() for b in bags}
    diagnoses: dict[str, list[tuple[float, str]]] = {b.thruster_id: [] for b in bags}
    diagnosed: dict[str, int] = {b.thruster_id: -1 for b in bags}
    pubs = {}
    matched = []  # the entities that must be matched with the model nodes before starting
    with_classifier = (models / "classifier" / "model_card.json").is_file()
    # Per thruster: the residual counters the model nodes report on /diagnostics.
    counters: dict[str, dict[str, int]] = {b.thruster_id: {} for b in bags}

    def on_status(msg: DiagnosticArray) -> None:
        for status in msg.status:
            namespace, _, name = status.name.rpartition("/")
            tid = namespace.rpartition("/")[2]
            for kv in status.values:
                if tid in counters and kv.key == COUNTERS.get(name):
                    counters[tid][name] = int(kv.value)

    node.create_subscription(DiagnosticArray, "/diagnostics", on_status, reliable)
    for bag in bags:
        tid = bag.thruster_id
        pubs[tid] = node.create_publisher(EscTelemetry, f"/thruster/{tid}/esc/telemetry", reliable)
        matched.append(pubs[tid].get_subscription_count)
        index = {stamp: i for i, stamp in enumerate(bag.stamps_ns)}

        def on_diagnosis(msg: Diagnosis, tid: str = tid, index: dict[int, int] = index) -> None:
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if stamp_ns in index:  # not the UNKNOWN a silent classifier says on its own clock
                diagnosed[tid] = max(diagnosed[tid], index[stamp_ns])
                diagnoses[tid].append((stamp_ns * 1e-9, msg.label))

        if with_classifier:
            sub = node.create_subscription(
                Diagnosis, f"/thruster/{tid}/fdd/diagnosis", on_diagnosis, reliable
            )
        else:

            def on_residual(data: bytes, tid: str = tid) -> None:
                answered[tid].add(_stamp_ns(data))

            sub = node.create_subscription(
                Residual, f"/thruster/{tid}/fdd/residual", on_residual, reliable, raw=True
            )
        matched.append(sub.get_publisher_count)

    def all_listening() -> bool:
        # Matched endpoints, not only the graph: a sample published before its reader matched
        # would be lost. The classifier's own match with the residuals is not visible from
        # here; transient-local residuals cover it, and SETTLE_S gives it time to happen.
        return all(count() >= 1 for count in matched)

    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not all_listening():
            executor.spin_once(timeout_sec=0.1)
        if not all_listening():
            print("thruster-fdd replay: the model nodes did not start", file=sys.stderr)
            return 1
        settle_end = time.monotonic() + SETTLE_S
        while time.monotonic() < settle_end:
            executor.spin_once(timeout_sec=0.05)
        start = time.monotonic()
        timeouts = 0
        stalls = 0
        total = 0
        first_ns = min(b.stamps_ns[0] for b in bags)
        in_flight: deque[int] = deque()
        for bag in bags:
            for k, (stamp_ns, raw) in enumerate(zip(bag.stamps_ns, bag.raw, strict=True)):
                if with_classifier and k - diagnosed[bag.thruster_id] > MAX_LAG:
                    stalls += _wait_classifier(executor, diagnosed, bag.thruster_id, k - MAX_LAG)
                    if stalls:
                        print(
                            f"thruster-fdd replay: the classifier of {bag.thruster_id} stopped "
                            f"deciding (no decision up to sample {k - MAX_LAG}); aborting",
                            file=sys.stderr,
                        )
                        break
                if args.rate:
                    due = start + (stamp_ns - first_ns) * 1e-9 / args.rate
                    while time.monotonic() < due:
                        executor.spin_once(timeout_sec=due - time.monotonic())
                while not with_classifier and len(in_flight) >= IN_FLIGHT:
                    timeouts += _wait_answer(executor, answered[bag.thruster_id], in_flight)
                pubs[bag.thruster_id].publish(raw)
                if not with_classifier:
                    in_flight.append(stamp_ns)
                total += 1
            while in_flight:
                timeouts += _wait_answer(executor, answered[bag.thruster_id], in_flight)
            if stalls:
                break
        # The classifier may still work through its queue: wait until diagnoses stop coming.
        count, quiet_since = -1, time.monotonic()
        deadline = time.monotonic() + 120.0
        while time.monotonic() - quiet_since < QUIET_S and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            now_count = sum(len(d) for d in diagnoses.values())
            if now_count != count:
                count, quiet_since = now_count, time.monotonic()
        wall = time.monotonic() - start - QUIET_S
        if with_classifier and not stalls:
            timeouts = _missing_residuals(executor, bags, counters)
    finally:
        for name in stop_children(procs, timeout_s=15.0):
            print(f"thruster-fdd replay: node {name} did not stop; killed", file=sys.stderr)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    span = max((b.stamps_ns[-1] - b.stamps_ns[0]) * 1e-9 for b in bags)
    results: list[ReplayCheck] = [
        check_replay(b, diagnoses[b.thruster_id], min_agreement=args.min_agreement) for b in bags
    ]
    print(
        f"replayed {total} samples ({span:.0f} s of {len(bags)} thruster(s)) in {wall:.1f} s "
        f"= {span / wall:.0f}x real time; {timeouts} samples got no residual, "
        f"{stalls} classifier stalls"
    )
    for r in results:
        agreement = "-" if r.agreement is None else f"{r.agreement:.1%}"
        print(
            f"{r.thruster_id}: {r.decisions} diagnoses, sequence {' -> '.join(r.sequence) or '-'}; "
            f"expected ({r.source}) {' -> '.join(r.expected_sequence or []) or '-'}; "
            f"agreement {agreement}: {'PASS' if r.passed else 'FAIL'}"
        )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(
            json.dumps(
                {
                    "samples": total,
                    "wall_s": wall,
                    "speedup": span / wall,
                    "timeouts": timeouts,
                    "classifier_stalls": stalls,
                    "residual_counters": counters,
                    "thrusters": [
                        r.__dict__ | {"diagnoses": diagnoses[r.thruster_id]} for r in results
                    ],
                },
                indent=2,
            )
        )
    return 0 if all(r.passed for r in results) and timeouts == 0 and stalls == 0 else 1
