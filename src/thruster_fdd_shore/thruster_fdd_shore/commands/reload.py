"""``thruster-fdd reload``: load newly exported models into running nodes, without a restart.

A thruster's nominal model and classifier change together, from one models folder (the pair the
classifier was trained with), atomically: both or neither. The pair is checked here first (bad
input, exit 2, no node touched); then per thruster the classifier gets the new model (it runs it
at once when it was made for the nominal model running now, else stages it for the first
residual of the new nominal model), then the nominal model. A refusal of either leaves the old
pair running (the classifier is set back when the nominal model refuses) and exit 1 says which
node refused and why. Success is confirmed by the classifier's ``/diagnostics`` status naming
the new model, or, while telemetry is idle, naming it as staged in a status sent after this
reload's last change. One reload at a time per thruster: while a classifier is staged, the
node refuses another one (exit 1, nothing changed), so two concurrent reloads cannot mix
their pairs; a classifier alone that the node can only stage (made for another nominal model)
is set back.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.commands.common import EXIT_FAILED, EXIT_OK

NAME = "reload"
HELP = "load a newly exported model pair into running nodes without a restart"
DESCRIPTION = (
    "Load a thruster's nominal model and classifier together from one models folder "
    "(--models DIR holding nominal/ and classifier/, or --nominal DIR --classifier DIR), "
    "atomically: both or neither. The pair is checked first (exit 2 when it is not a pair); a "
    "node that refuses leaves the old pair running (exit 1, with the node and the reason). "
    "--classifier alone replaces a classifier for the nominal model running now; --nominal alone "
    "only where no classifier runs (it refuses residuals of another nominal model)."
)

_ID = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class Pair:
    """What to load: folders (None: that stage is not changed) and the new models' ids."""

    nominal: Path | None
    classifier: Path | None
    nominal_id: str
    classifier_id: str


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd reload``."""
    p.add_argument("--thrusters", nargs="+", required=True, metavar="ID", help="e.g. t0 t1")
    p.add_argument(
        "--models",
        type=Path,
        metavar="DIR",
        help="folder with nominal/, classifier/ (without --nominal / --classifier: "
        "$THRUSTER_FDD_MODELS, else the workspace's models/)",
    )
    p.add_argument("--nominal", type=Path, metavar="DIR", help="nominal model folder")
    p.add_argument("--classifier", type=Path, metavar="DIR", help="classifier folder")
    p.add_argument("--timeout", type=float, default=10.0, help="per node and step, s")


def check_pair(args: argparse.Namespace) -> Pair:
    """The folders to load, checked as the nodes will check them (BadInputError if not)."""
    from thruster_fdd.core.diagnosis.model import ClassifierModel
    from thruster_fdd.core.nominal.runtime import NominalModel
    from thruster_fdd_shore.core.diagnosis.offline import check_pair as check_models

    for tid in args.thrusters:
        if not _ID.match(tid):
            raise BadInputError(f"thruster id {tid!r} must be a ROS name token like t0")
    if not args.timeout > 0:
        raise BadInputError(f"--timeout must be > 0 s, got {args.timeout}")
    nominal, classifier = args.nominal, args.classifier
    if args.models is not None:
        if nominal is not None or classifier is not None:
            raise BadInputError("give --models DIR, or --nominal / --classifier, not both")
        nominal, classifier = args.models / "nominal", args.models / "classifier"
    if nominal is None and classifier is None:
        # The one rule of every command: the models folder whatever the current folder.
        from thruster_fdd.core.artifact import default_models_dir

        nominal, classifier = default_models_dir() / "nominal", default_models_dir() / "classifier"
    for folder in (nominal, classifier):
        if folder is not None and not folder.is_dir():
            raise BadInputError(f"{folder}: no such model folder")
    nominal_model = NominalModel.load(nominal) if nominal is not None else None
    classifier_model = ClassifierModel.load(classifier) if classifier is not None else None
    if nominal_model is not None and classifier_model is not None:
        check_models(nominal_model, classifier_model, classifier)
    return Pair(
        nominal=nominal.resolve() if nominal is not None else None,
        classifier=classifier.resolve() if classifier is not None else None,
        nominal_id=nominal_model.model_id if nominal_model else "",
        classifier_id=classifier_model.model_id if classifier_model else "",
    )


class _Session:
    """A private rclpy node that sets the nodes' parameters and reads their statuses."""

    def __init__(self, timeout_s: float) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        from thruster_fdd_shore.nodes.probe import Probe

        self.timeout_s = timeout_s
        self._probe = Probe("thruster_fdd_reload")
        self.status: dict[tuple[str, str], dict[str, str]] = {}
        self._probe.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_status, 50)

    def _on_status(self, msg: Any) -> None:
        from thruster_fdd.nodes.common import parse_status_name

        for status in msg.status:
            parsed = parse_status_name(status.name)
            if parsed is not None:
                self.status[parsed] = {kv.key: kv.value for kv in status.values}

    def client(self, remote: str) -> Any | None:
        """The parameter client of node ``remote``, or None when it does not answer."""
        from rclpy.parameter_client import AsyncParameterClient

        client = AsyncParameterClient(self._probe.node, remote)
        return client if client.wait_for_services(timeout_sec=self.timeout_s) else None

    def present(self, remote: str, wait_s: float) -> bool:
        """Whether node ``remote``'s parameter service shows up within ``wait_s``."""
        from rclpy.parameter_client import AsyncParameterClient

        return AsyncParameterClient(self._probe.node, remote).wait_for_services(timeout_sec=wait_s)

    def get_model_dir(self, client: Any) -> str | None:
        """The node's ``model_dir`` now, or None without an answer."""
        result = self._probe.ask(lambda: client.get_parameters(["model_dir"]), self.timeout_s)
        return None if result is None else result.values[0].string_value

    def set_model_dir(self, client: Any, folder: str) -> tuple[bool, str]:
        """Set ``model_dir``: (accepted, the node's reason or why there is none).

        Asked again when no answer comes: setting the same folder twice loads the same model
        (or stages it again), so the node ends in the same state.
        """
        from rclpy.parameter import Parameter

        result = self._probe.ask(
            lambda: client.set_parameters([Parameter("model_dir", Parameter.Type.STRING, folder)]),
            self.timeout_s,
        )
        if result is None:
            return False, f"no answer within {self.timeout_s:g} s"
        return result.results[0].successful, result.results[0].reason

    def wait_status(self, tid: str, key: str, value: str) -> bool:
        """Wait until the classifier of ``tid`` reports ``key`` = ``value`` on /diagnostics."""
        return self._probe.spin_until(
            lambda: self.status.get(("classifier", tid), {}).get(key) == value,
            self.timeout_s,
            0.05,
        )

    def close(self) -> None:
        """Destroy the node and its context."""
        self._probe.close()


def _reload_thruster(session: _Session, tid: str, pair: Pair) -> str | None:
    """Load ``pair`` into thruster ``tid``; None on success (printed), else why not."""
    ns = f"/thruster/{tid}"
    nominal = session.client(f"{ns}/nominal_model") if pair.nominal is not None else None
    if pair.nominal is not None and nominal is None:
        return f"{ns}/nominal_model: not running; nothing changed"
    if pair.classifier is None:
        if session.present(f"{ns}/classifier", 1.0):
            return (
                f"{ns}/classifier runs and refuses residuals of another nominal model: reload "
                "the pair (--models DIR); nothing changed"
            )
        ok, reason = session.set_model_dir(nominal, str(pair.nominal))
        if not ok:
            return f"{ns}/nominal_model refused: {reason}; the old model keeps running"
        print(f"{tid}: now running nominal model {pair.nominal_id} from {pair.nominal}")
        return None
    classifier = session.client(f"{ns}/classifier")
    if classifier is None:
        return f"{ns}/classifier: not running; nothing changed"
    previous = session.get_model_dir(classifier)
    if previous is None:
        return f"{ns}/classifier: no answer within {session.timeout_s:g} s; nothing changed"
    ok, reason = session.set_model_dir(classifier, str(pair.classifier))
    if not ok:
        return f"{ns}/classifier refused: {reason}; the old pair keeps running"
    if nominal is not None:
        ok, reason = session.set_model_dir(nominal, str(pair.nominal))
        if not ok:
            restored, why = session.set_model_dir(classifier, previous)
            back = "set back" if restored else f"could not be set back ({why})"
            return (
                f"{ns}/nominal_model refused: {reason}; the classifier was {back}: the old "
                "pair keeps running"
            )
    # Only statuses from now on: what the classifier says after this reload's last change.
    session.status.pop(("classifier", tid), None)
    if session.wait_status(tid, "model_id", pair.classifier_id):
        models = f"nominal model {pair.nominal_id} and " if pair.nominal is not None else ""
        print(f"{tid}: now running {models}classifier {pair.classifier_id}")
        return None
    if pair.nominal is not None:
        status = session.status.get(("classifier", tid))
        if status is None or status.get("staged_model_id") != pair.classifier_id:
            said = (
                f"no status within {session.timeout_s:g} s"
                if status is None
                else f"it runs {status.get('model_id')}, stages "
                f"{status.get('staged_model_id') or 'nothing'}"
            )
            return (
                f"{ns}/classifier does not stage {pair.classifier_id} ({said}): another change "
                f"came in between; {ns}/nominal_model runs {pair.nominal_id}"
            )
        # Telemetry may be idle: the classifier takes over at the new model's first residual.
        print(
            f"{tid}: loaded nominal model {pair.nominal_id}; classifier {pair.classifier_id} "
            f"staged, runs from the first residual of the new nominal model (none within "
            f"{session.timeout_s:g} s)"
        )
        return None
    # Made for another nominal model than the one running, it would wait for residuals that
    # never come and hold up every other reload: set back.
    restored, why = session.set_model_dir(classifier, previous)
    back = "set back" if restored else f"could not be set back ({why})"
    return (
        f"{ns}/classifier staged {pair.classifier_id} but does not run it: it was made for "
        f"another nominal model than the one running (reload the pair with --models DIR); {back}"
    )


def run(args: argparse.Namespace) -> int:
    """Load the pair into every named thruster; returns the exit code."""
    pair = check_pair(args)
    failures = 0
    session = _Session(args.timeout)
    try:
        for tid in args.thrusters:
            why = _reload_thruster(session, tid, pair)
            if why is not None:
                failures += 1
                print(f"{tid}: {why}", file=sys.stderr)
    finally:
        session.close()
    return EXIT_FAILED if failures else EXIT_OK
