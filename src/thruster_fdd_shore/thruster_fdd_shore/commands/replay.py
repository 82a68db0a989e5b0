"""``thruster-fdd replay``: a recording's telemetry through the model nodes, checked.

Starts a ``nominal_model`` (and, when a classifier is exported, a ``classifier``) node per
thruster of the bag, publishes the samples the live model used from where fresh nodes
reproduce the live decisions (``traces.replay_check.align_bag``) over reliable QoS, collects
the published diagnoses and compares them with the bag's recorded diagnoses or ground truth.
Exit 0 when every thruster passes, 1 when one does not.

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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from thruster_fdd.core.artifact import CARD_FILE
from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.lifetime import child_env, node_command, stop_children
from thruster_fdd_shore.commands.common import (
    EXIT_FAILED,
    EXIT_OK,
    check_models,
    check_output,
    positive_float,
)
from thruster_fdd_shore.core.traces.files import is_bag
from thruster_fdd_shore.core.traces.replay_check import (
    NOT_COMPARABLE_REASONS,
    ReplayCheck,
    ThrusterBag,
    WindowDecision,
    chain_timing,
    check_replay,
    diagnosis_of,
    load_recording,
)

NAME = "replay"
HELP = "play a recording through the model nodes and check the diagnoses"
DESCRIPTION = (
    "Replay the telemetry of a recording (a rosbag2 bag folder of MCAP files, or one MCAP file) "
    "through freshly started model nodes "
    "(nominal_model, classifier) as fast as they answer, or at --rate times real time, and "
    "check the diagnoses they publish against the diagnoses recorded in the bag or the "
    "ground-truth labels of a simulated recording. Exit 0 when all thrusters pass, 1 if not."
)

# Samples published ahead of their residual: far below the nominal model's replay queue depth
# (reliable, 1000; ``reliable_telemetry``), so none can be dropped, and enough to keep the nodes
# busy between two answers.
IN_FLIGHT = 32
# Samples the classifier may fall behind the replay, below its queue depth (500) and the
# nominal model's (1000): a window (200 samples) plus slack. Its diagnoses' stamps tell how far
# it has got.
MAX_LAG = 300
# Longest wait for the model nodes' statuses that confirm every sample arrived, s.
STATUS_WAIT_S = 3.0
# Start-up: time given to the model nodes to match each other once they match the replayer, s.
SETTLE_S = 1.0
# A residual not back after this long counts as lost, s (generous: a loaded CI machine).
ANSWER_TIMEOUT_S = 5.0
# No new diagnosis for this long ends the replay, s.
QUIET_S = 2.0
# The residual counter each model node reports in its /diagnostics status.
COUNTERS = {"nominal_model": "residuals_published", "classifier": "residuals_received"}
# The model stages a replay starts per thruster: node module and model folder.
STAGES = (("nominal_model", "nominal"), ("classifier", "classifier"))


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd replay``."""
    p.add_argument("bag", type=Path, metavar="BAG", help="bag folder or MCAP file")
    p.add_argument(
        "--rate", type=positive_float, help="rate factor, > 0 (default: as fast as possible)"
    )
    p.add_argument("--models", type=Path, help="folder with nominal/ and classifier/")
    p.add_argument("--json", type=Path, metavar="OUT", help="write the result as JSON")
    p.add_argument(
        "--min-agreement", type=float, default=0.9, help="decisions that must match, 0..1"
    )


def _stamp_ns(cdr: bytes) -> int:
    """Header stamp (ns) of a serialized message that starts with a std_msgs/Header: after the
    4-byte encapsulation, ``int32 sec`` and ``uint32 nanosec`` in the byte order it names.
    Decoding only the stamp keeps the replayer's cost per residual small."""
    order = "<" if cdr[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(f"{order}iI", cdr, 4)
    return sec * 1_000_000_000 + nanosec


@dataclass(frozen=True)
class Played:
    """What playing a bag gave.

    Attributes
    ----------
    samples : int
        Telemetry samples published.
    wall_s : float
        Wall time of the playing, s (the final quiet wait excluded).
    timeouts : int
        Samples that got no residual (or, with a classifier, that the nodes' counters miss).
    stalls : int
        Times the classifier stopped deciding (the replay is then aborted).
    diagnoses : dict of str to list of WindowDecision
        Per thruster: the diagnoses received for replayed samples.
    counters : dict of str to dict of str to int
        Per thruster: the model nodes' residual counters from ``/diagnostics``.
    """

    samples: int
    wall_s: float
    timeouts: int
    stalls: int
    diagnoses: dict[str, list[WindowDecision]]
    counters: dict[str, dict[str, int]]


class Replayer:
    """A probe node that plays the bags into running model nodes and listens to what comes back.

    Parameters
    ----------
    bags : tuple of ThrusterBag
        The thrusters to replay.
    with_classifier : bool
        Whether classifier nodes run (pace on diagnoses) or only nominal models (on residuals).
    """

    def __init__(self, bags: tuple[ThrusterBag, ...], with_classifier: bool) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from thruster_fdd_msgs.msg import Diagnosis, EscTelemetry, Residual

        from thruster_fdd_shore.nodes.probe import Probe

        self.bags = bags
        self.with_classifier = with_classifier
        self._probe = Probe("replay")
        self._node = self._probe.node
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        ids = [b.thruster_id for b in bags]
        self.answered: dict[str, set[int]] = {tid: set() for tid in ids}
        self.diagnoses: dict[str, list[WindowDecision]] = {tid: [] for tid in ids}
        self.diagnosed: dict[str, int] = {tid: -1 for tid in ids}
        self.counters: dict[str, dict[str, int]] = {tid: {} for tid in ids}
        self._pubs: dict[str, Any] = {}
        # The entities that must be matched with the model nodes before starting.
        self._matched: list[Any] = []
        self._node.create_subscription(DiagnosticArray, "/diagnostics", self._on_status, reliable)
        for bag in bags:
            tid = bag.thruster_id
            topic = f"/thruster/{tid}/esc/telemetry"
            self._pubs[tid] = self._node.create_publisher(EscTelemetry, topic, reliable)
            self._matched.append(self._pubs[tid].get_subscription_count)
            index = {stamp: i for i, stamp in enumerate(bag.stamps_ns)}
            if with_classifier:
                sub = self._node.create_subscription(
                    Diagnosis,
                    f"/thruster/{tid}/fdd/diagnosis",
                    lambda msg, tid=tid, index=index: self._on_diagnosis(tid, index, msg),
                    reliable,
                )
            else:
                sub = self._node.create_subscription(
                    Residual,
                    f"/thruster/{tid}/fdd/residual",
                    lambda data, tid=tid: self.answered[tid].add(_stamp_ns(data)),
                    reliable,
                    raw=True,
                )
            self._matched.append(sub.get_publisher_count)

    def _on_status(self, msg: Any) -> None:
        from thruster_fdd.nodes.common import parse_status_name

        for status in msg.status:
            name, tid = parse_status_name(status.name) or ("", "")
            for kv in status.values:
                if tid in self.counters and kv.key == COUNTERS.get(name):
                    self.counters[tid][name] = int(kv.value)

    def _on_diagnosis(self, tid: str, index: dict[int, int], msg: Any) -> None:
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if stamp_ns in index:  # not the UNKNOWN a silent classifier says on its own clock
            self.diagnosed[tid] = max(self.diagnosed[tid], index[stamp_ns])
            self.diagnoses[tid].append(diagnosis_of(stamp_ns, msg))

    def _spin(self, timeout_s: float) -> None:
        self._probe.executor.spin_once(timeout_sec=timeout_s)

    def _spin_until(self, done: Callable[[], bool], timeout_s: float, step_s: float = 0.05) -> bool:
        return self._probe.spin_until(done, timeout_s, step_s)

    def wait_for_nodes(self, timeout_s: float = 60.0) -> bool:
        """Wait until every publisher and subscription is matched with a model node, then give
        the model nodes ``SETTLE_S`` to match each other; False if they never appear.

        Matched endpoints, not only the graph: a sample published before its reader matched
        would be lost. The classifier's own match with the residuals is not visible from here;
        transient-local residuals cover it, and the settling time gives it time to happen.
        """
        if not self._spin_until(lambda: all(count() >= 1 for count in self._matched), timeout_s):
            return False
        settle_end = time.monotonic() + SETTLE_S
        while time.monotonic() < settle_end:
            self._spin(0.05)
        return True

    def play(self, rate: float | None) -> Played:
        """Publish every bag's samples, paced as the module docstring says, and collect."""
        start = time.monotonic()
        timeouts = stalls = total = 0
        first_ns = min(b.stamps_ns[0] for b in self.bags)
        in_flight: deque[int] = deque()
        for bag in self.bags:
            tid = bag.thruster_id
            for k, (stamp_ns, raw) in enumerate(zip(bag.stamps_ns, bag.raw, strict=True)):
                if self.with_classifier and k - self.diagnosed[tid] > MAX_LAG:
                    upto = k - MAX_LAG
                    if not self._spin_until(lambda tid=tid, upto=upto: self.diagnosed[tid] >= upto,
                                            10.0):  # fmt: skip
                        stalls += 1
                        print(
                            f"thruster-fdd replay: the classifier of {tid} stopped deciding "
                            f"(no decision up to sample {upto}); aborting",
                            file=sys.stderr,
                        )
                        break
                if rate:
                    due = start + (stamp_ns - first_ns) * 1e-9 / rate
                    while time.monotonic() < due:
                        self._spin(due - time.monotonic())
                while not self.with_classifier and len(in_flight) >= IN_FLIGHT:
                    timeouts += self._wait_answer(tid, in_flight)
                self._pubs[tid].publish(raw)
                if not self.with_classifier:
                    in_flight.append(stamp_ns)
                total += 1
            while in_flight:
                timeouts += self._wait_answer(tid, in_flight)
            if stalls:
                break
        # The classifier may still work through its queue: wait until diagnoses stop coming.
        count, quiet_since = -1, time.monotonic()
        deadline = time.monotonic() + 120.0
        while time.monotonic() - quiet_since < QUIET_S and time.monotonic() < deadline:
            self._spin(0.05)
            now_count = sum(len(d) for d in self.diagnoses.values())
            if now_count != count:
                count, quiet_since = now_count, time.monotonic()
        wall = time.monotonic() - start - QUIET_S
        if self.with_classifier and not stalls:
            timeouts = self._missing_residuals()
        return Played(total, wall, timeouts, stalls, self.diagnoses, self.counters)

    def _wait_answer(self, tid: str, in_flight: deque[int]) -> int:
        """Wait for the oldest sample in flight to be answered; 1 on a time-out, else 0."""
        oldest = in_flight.popleft()
        answered = self.answered[tid]
        return 0 if self._spin_until(lambda: oldest in answered, ANSWER_TIMEOUT_S) else 1

    def _missing_residuals(self) -> int:
        """Samples that did not reach the classifier as residuals, from the nodes' counters.

        Waits for the next /diagnostics statuses (one a second) until every thruster's nominal
        model and classifier count all of its samples, at most ``STATUS_WAIT_S``.
        """

        def missing() -> int:
            return sum(
                len(b.stamps_ns)
                - min(self.counters[b.thruster_id].get(name, 0) for name in COUNTERS)
                for b in self.bags
            )

        self._spin_until(lambda: missing() == 0, STATUS_WAIT_S, 0.1)
        return missing()

    def close(self) -> None:
        """Destroy the probe node and its context."""
        self._probe.close()


def report(
    bags: tuple[ThrusterBag, ...], played: Played, results: list[ReplayCheck]
) -> tuple[list[str], dict[str, Any], bool]:
    """The lines to print, the JSON document and whether the replay passed (pure)."""
    span = max((b.stamps_ns[-1] - b.stamps_ns[0]) * 1e-9 for b in bags)
    lines = [
        f"replayed {played.samples} samples ({span:.0f} s of {len(bags)} thruster(s)) in "
        f"{played.wall_s:.1f} s = {span / played.wall_s:.0f}x real time; {played.timeouts} "
        f"samples got no residual, {played.stalls} classifier stalls"
    ]
    for r in results:
        agreement = "-" if r.agreement is None else f"{r.agreement:.1%}"
        lines.append(
            f"{r.thruster_id}: {r.decisions} diagnoses, sequence {' -> '.join(r.sequence) or '-'}; "
            f"expected ({r.source}) {' -> '.join(r.expected_sequence or []) or '-'}; "
            f"agreement {agreement}: {'PASS' if r.passed else 'FAIL'}"
        )
        if r.source == "recorded":
            lines.append(f"  {_compared_line(r)}")
    document = {
        "samples": played.samples,
        "wall_s": played.wall_s,
        "speedup": span / played.wall_s,
        "timeouts": played.timeouts,
        "classifier_stalls": played.stalls,
        "residual_counters": played.counters,
        "thrusters": [
            r.__dict__ | {"diagnoses": [(d.t_s, d.label) for d in played.diagnoses[r.thruster_id]]}
            for r in results
        ],
    }
    passed = all(r.passed for r in results) and played.timeouts == 0 and played.stalls == 0
    return lines, document, passed


def _compared_line(r: ReplayCheck) -> str:
    """What a check against recorded decisions compared and left out, in words."""
    what = (
        "windows and labels"
        if r.labels_compared
        else (
            "windows only (probabilities, coverage, gate): the labels' evidence began before the "
            "recording"
        )
    )
    parts = [f"compared {r.compared} decisions: {what}"]
    for reason, n in (r.not_comparable or {}).items():
        parts.append(f"{n} live decisions not comparable: {NOT_COMPARABLE_REASONS[reason]}")
    if r.after_recorded:
        parts.append(f"{r.after_recorded} replayed after the last recorded diagnosis")
    return "; ".join(parts)


def _start_nodes(bags: tuple[ThrusterBag, ...], models: Path) -> dict[str, subprocess.Popen[bytes]]:
    """The model nodes of every thruster of ``bags``, by name ``<thruster>/<node>``."""
    procs = {}
    for bag in bags:
        for node, folder in STAGES:
            if not (models / folder / CARD_FILE).is_file():
                continue
            params: dict[str, object] = {
                "thruster_id": bag.thruster_id,
                "model_dir": models / folder,
            }
            if node == "nominal_model":
                params["reliable_telemetry"] = "true"
            cmd = node_command(node, f"/thruster/{bag.thruster_id}", params)
            procs[f"{bag.thruster_id}/{node}"] = subprocess.Popen(
                cmd, stdout=subprocess.DEVNULL, env=child_env()
            )
    return procs


def run(args: argparse.Namespace) -> int:
    """Replay ``args.bag`` and check the diagnoses; returns the exit code."""
    from thruster_fdd.core.artifact import default_models_dir

    if not (is_bag(args.bag) or args.bag.is_file()):
        raise BadInputError(f"{args.bag}: no such recording (an MCAP file or a bag folder)")
    if not 0.0 <= args.min_agreement <= 1.0:
        raise BadInputError(f"--min-agreement must be within 0..1, got {args.min_agreement}")
    if args.json is not None:
        check_output(args.json, "--json")
    models = (args.models or default_models_dir()).resolve()
    check_models(models)
    bags = load_recording(args.bag, chain_timing(models))
    empty = [b.thruster_id for b in bags if not b.stamps_ns]
    if empty:
        raise BadInputError(
            f"{args.bag}: no decision of thruster {', '.join(empty)} can be reproduced: "
            f"the recording holds no full window with the model history before it"
        )
    procs = _start_nodes(bags, models)
    try:
        replayer = Replayer(bags, (models / "classifier" / CARD_FILE).is_file())
        try:
            if not replayer.wait_for_nodes():
                print("thruster-fdd replay: the model nodes did not start", file=sys.stderr)
                return EXIT_FAILED
            played = replayer.play(args.rate)
        finally:
            replayer.close()
    finally:
        for name in stop_children(procs, timeout_s=15.0):
            print(f"thruster-fdd replay: node {name} did not stop; killed", file=sys.stderr)
    results = [
        check_replay(b, played.diagnoses[b.thruster_id], min_agreement=args.min_agreement)
        for b in bags
    ]
    lines, document, passed = report(bags, played, results)
    print("\n".join(lines))
    if args.json is not None:
        write_text(args.json, json.dumps(document, indent=2))
    return EXIT_OK if passed else EXIT_FAILED
