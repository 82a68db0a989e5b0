"""Model reload on a running thruster: each node's refusals, and ``thruster-fdd reload`` changing
the nominal model and classifier together (both or neither).

The model nodes run in the container, as ``up`` runs them (the classifier takes its residuals
in-process). A "retrained" pair is the committed pair with new model ids (the classifier's card
naming the new nominal id): the nodes identify models by id, so this exercises every check and
switch without a training run; a test of nominal_model.py trains a real new model.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from probe import Probe

from thruster_fdd.core.artifact import CARD_FILE, default_models_dir
from thruster_fdd.lifetime import stop_children
from thruster_fdd_shore.core.sim.scenario import run_scenario

pytestmark = pytest.mark.ros

MODELS = default_models_dir()
TID = "rl"
NS = f"/thruster/{TID}"
RELOAD = ["thruster-fdd", "reload", "--thrusters", TID, "--timeout", "20"]


def retrained_pair(out: Path, suffix: str) -> tuple[str, str]:
    """Copy the committed pair to ``out`` with new ids; returns (nominal id, classifier id)."""
    ids = []
    for stage, kind in (("nominal", "nominal"), ("classifier", "classifier")):
        shutil.copytree(MODELS / stage, out / stage)
        card_path = out / stage / CARD_FILE
        card = json.loads(card_path.read_text())
        card["model_id"] = f"{card['model_id'].rsplit('-', 1)[0]}-{suffix}"
        if kind == "classifier":
            card["nominal_model_id"] = ids[0]
        card_path.write_text(json.dumps(card))
        ids.append(card["model_id"])
    return ids[0], ids[1]


@dataclass
class Rig:
    probe: Probe
    pub: object
    residual_ids: list = field(default_factory=list)
    diagnosis_ids: list = field(default_factory=list)
    diagnosis_stamps: list = field(default_factory=list)
    status: dict = field(default_factory=dict)
    t: float = 5000.0

    def feed(self, seconds: float) -> None:
        """Publish ``seconds`` of a simulated healthy thruster's telemetry at 10 Hz."""
        from thruster_fdd_msgs.msg import EscTelemetry

        trace = run_scenario("t100", "nominal_15v", signal="sine:0.05", duration_s=seconds, seed=3)
        n_res = len(self.residual_ids)
        for i in range(len(trace)):
            msg = EscTelemetry(
                thruster_id=TID,
                command=float(trace.command[i]),
                voltage_v=float(trace.voltage[i]),
                rpm=float(trace.rpm[i]),
                current_a=float(trace.current[i]),
            )
            stamp_ns = round((self.t + float(trace.t[i])) * 1e9)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
            self.pub.publish(msg)  # type: ignore[attr-defined]
            self.probe.spin(0.003)
        self.t += seconds  # the next feed continues without a gap: the window goes on
        self.probe.spin_until(lambda: len(self.residual_ids) - n_res >= len(trace) - 2, 15.0)

    def classifier_status(self) -> dict:
        return self.status.get("classifier", {})


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from thruster_fdd_msgs.msg import Diagnosis, EscTelemetry, Residual

    cmd = [sys.executable, "-m", "thruster_fdd.nodes.container", "nominal_model", "classifier"]
    cmd += ["--thrusters", TID, "-p", f"nominal_model:model_dir={MODELS / 'nominal'}"]
    cmd += ["-p", f"classifier:model_dir={MODELS / 'classifier'}"]
    # Pauses between feeds must not go STALE (which restarts the classifier's window).
    cmd += ["-p", "classifier:stale_after_s=120.0"]
    # The rig feeds telemetry about 30 times faster than real time: the driver's sensor-data
    # QoS (depth 5) would drop samples while a node loads a model and open gaps in the stamps.
    cmd += ["-p", "nominal_model:reliable_telemetry=true"]
    proc = subprocess.Popen(cmd)
    with Probe("reload_probe") as probe:
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        pub = probe.node.create_publisher(EscTelemetry, f"{NS}/esc/telemetry", reliable)
        r = Rig(probe, pub)
        probe.node.create_subscription(
            Residual, f"{NS}/fdd/residual", lambda m: r.residual_ids.append(m.model_id), reliable
        )

        def on_diagnosis(msg: Diagnosis) -> None:
            r.diagnosis_ids.append(msg.model_id)
            r.diagnosis_stamps.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)

        probe.node.create_subscription(Diagnosis, f"{NS}/fdd/diagnosis", on_diagnosis, reliable)

        def on_status(msg: DiagnosticArray) -> None:
            for s in msg.status:
                if s.name.endswith(f" {TID}"):
                    task = s.name.split(": ", 1)[1].split(" ")[0]
                    r.status[task] = {kv.key: kv.value for kv in s.values} | {"_msg": s.message}

        probe.node.create_subscription(DiagnosticArray, "/diagnostics", on_status, reliable)
        try:
            assert probe.spin_until(lambda: pub.get_subscription_count() > 0, 60.0, 0.1)
            r.feed(25.0)
            assert r.diagnosis_ids, "no diagnosis from the committed pair"
            yield r
        finally:
            stop_children({"container": proc}, timeout_s=10.0)


def _set_model_dir(rig: Rig, node: str, folder: Path) -> tuple[bool, str]:
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(rig.probe.node, f"{NS}/{node}")
    assert client.wait_for_services(timeout_sec=20.0)
    answer = rig.probe.ask(
        lambda: client.set_parameters([Parameter("model_dir", Parameter.Type.STRING, str(folder))]),
        20.0,
    )
    assert answer is not None, f"{node} did not answer"
    return answer.results[0].successful, answer.results[0].reason


@pytest.mark.parametrize(
    ("node", "damage", "words"),
    [
        ("classifier", "empty", "model_card.json"),
        ("classifier", "corrupt", "weights.npz"),
        ("nominal_model", "empty", "model_card.json"),
        ("nominal_model", "corrupt", "weights.npz"),
    ],
)
def test_each_node_refuses_a_bad_model_and_keeps_its_own(
    rig: Rig, tmp_path: Path, node: str, damage: str, words: str
) -> None:
    bad = tmp_path / "bad"
    if damage == "empty":
        bad.mkdir()
    else:
        shutil.copytree(MODELS / ("nominal" if node == "nominal_model" else "classifier"), bad)
        (bad / "weights.npz").write_bytes(b"not a weights file")
    ok, reason = _set_model_dir(rig, node, bad)
    assert not ok
    assert words in reason
    n = len(rig.diagnosis_ids)
    rig.feed(3.0)
    committed = json.loads((MODELS / "nominal" / CARD_FILE).read_text())["model_id"]
    assert set(rig.residual_ids[-20:]) == {committed}
    assert rig.diagnosis_ids[n:], "the diagnosis goes on"


@pytest.mark.parametrize("damage", ["empty", "corrupt", "mismatched"])
def test_reload_refuses_what_is_not_a_pair_before_touching_a_node(
    rig: Rig, tmp_path: Path, damage: str
) -> None:
    retrained_pair(tmp_path, "aaaaaaaaaaaa")
    if damage == "empty":
        shutil.rmtree(tmp_path / "classifier")
        (tmp_path / "classifier").mkdir()
    elif damage == "corrupt":
        (tmp_path / "nominal" / "weights.npz").write_bytes(b"truncated")
    else:
        shutil.rmtree(tmp_path / "classifier")
        shutil.copytree(MODELS / "classifier", tmp_path / "classifier")  # made for the old one
    before = dict(rig.classifier_status())
    out = subprocess.run([*RELOAD, "--models", str(tmp_path)], capture_output=True, text=True)
    assert out.returncode == 2, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert {"empty": "model card", "corrupt": "weights.npz", "mismatched": "made with"}[
        damage
    ] in out.stderr
    rig.probe.spin(1.5)
    assert rig.classifier_status().get("model_id") == before.get("model_id")


def test_bad_thruster_id_is_one_line_and_exit_2() -> None:
    out = subprocess.run(
        ["thruster-fdd", "reload", "--thrusters", "bad id!", "--models", str(MODELS)],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0
    assert "bad id!" in out.stderr


def test_nominal_refusal_sets_the_classifier_back(rig: Rig, tmp_path: Path) -> None:
    from thruster_fdd_shore.commands import reload

    nominal_id, classifier_id = retrained_pair(tmp_path, "bbbbbbbbbbbb")
    old = dict(rig.classifier_status())
    # The nominal folder breaks between the command's check and the node's (a refusal the
    # command cannot foresee): the classifier, already staged, must be set back.
    (tmp_path / "nominal" / "weights.npz").write_bytes(b"broken after the check")
    pair = reload.Pair(tmp_path / "nominal", tmp_path / "classifier", nominal_id, classifier_id)
    session = reload._Session(20.0)
    try:
        why = reload._reload_thruster(session, TID, pair)
    finally:
        session.close()
    assert why is not None
    assert "nominal_model refused" in why
    assert "set back" in why
    rig.feed(3.0)
    status = rig.classifier_status()
    assert status["model_id"] == old["model_id"]
    assert status["staged_model_id"] == ""
    assert status["model_dir"] == old["model_dir"]


def test_reload_switches_the_pair_together(rig: Rig, tmp_path: Path) -> None:
    nominal_id, classifier_id = retrained_pair(tmp_path, "cccccccccccc")
    n_start = len(rig.diagnosis_ids)
    proc = subprocess.Popen(
        [*RELOAD, "--models", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60.0
    while proc.poll() is None and time.monotonic() < deadline:
        rig.feed(2.0)  # telemetry flows while the pair changes
    stdout, stderr = proc.communicate(timeout=10)
    assert proc.returncode == 0, stderr
    assert f"now running nominal model {nominal_id} and classifier {classifier_id}" in stdout
    n_res, n_diag = len(rig.residual_ids), len(rig.diagnosis_ids)
    rig.feed(25.0)
    assert set(rig.residual_ids[n_res:]) == {nominal_id}
    # No gap: while the new classifier fills its first window, the old pair's last diagnosis
    # is published every hop (1 s of telemetry) under the old id; then only the new pair's.
    stamps = rig.diagnosis_stamps[n_start:]
    assert max(np.diff(stamps)) <= 2.0, "a diagnosis every hop through the switch"
    after = rig.diagnosis_ids[n_start:]
    assert after[-1] == classifier_id
    first_new = after.index(classifier_id)
    assert set(after[first_new:]) == {classifier_id}
    old_id = json.loads((MODELS / "classifier" / CARD_FILE).read_text())["model_id"]
    assert set(after[:first_new]) <= {old_id}
    assert rig.probe.spin_until(lambda: rig.classifier_status()["_msg"] != "", 3.0)
    assert "residuals from nominal model" not in rig.classifier_status()["_msg"]

    # A classifier alone, made for another nominal model, is staged and never runs: exit 1.
    other = tmp_path / "other"
    retrained_pair(other, "dddddddddddd")
    alone = subprocess.run(
        [*RELOAD[:-1], "5", "--classifier", str(other / "classifier")],
        capture_output=True,
        text=True,
    )
    assert alone.returncode == 1
    assert "does not run it" in alone.stderr
    n_diag = len(rig.diagnosis_ids)
    rig.feed(25.0)
    assert set(rig.diagnosis_ids[n_diag:]) == {classifier_id}


def _get_model_dir(rig: Rig, node: str) -> str:
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(rig.probe.node, f"{NS}/{node}")
    assert client.wait_for_services(timeout_sec=20.0)
    answer = rig.probe.ask(lambda: client.get_parameters(["model_dir"]), 20.0)
    assert answer is not None, f"{node} did not answer"
    return answer.values[0].string_value


@pytest.mark.parametrize("meanwhile", ["another reload", "set back"])
def test_a_reload_waiting_for_its_staged_classifier_answers_true(
    rig: Rig, tmp_path: Path, meanwhile: str
) -> None:
    """With telemetry idle, a reload stages its classifier, loads its nominal model and waits.
    A second reload meanwhile is refused (one at a time), so the first one's "staged" holds;
    a classifier set back meanwhile makes the first one say it does not stage its pair."""
    nominal_dir = _get_model_dir(rig, "nominal_model")
    rig.probe.spin(1.5)
    classifier_dir = rig.classifier_status()["model_dir"]
    assert rig.classifier_status()["staged_model_id"] == ""
    _, classifier_a = retrained_pair(tmp_path / "a", "eeeeeeeeeeee")
    retrained_pair(tmp_path / "b", "ffffffffffff")
    first = subprocess.Popen(
        [*RELOAD[:-1], "8", "--models", str(tmp_path / "a")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30.0
        loaded = str((tmp_path / "a" / "nominal").resolve())
        while _get_model_dir(rig, "nominal_model") != loaded and time.monotonic() < deadline:
            rig.probe.spin(0.1)
        if _get_model_dir(rig, "nominal_model") != loaded:
            first.kill()
            pytest.fail(f"the first reload never got there: {first.communicate()}")
        if meanwhile == "another reload":
            second = subprocess.run(
                [*RELOAD[:-1], "5", "--models", str(tmp_path / "b")],
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert second.returncode == 1, second.stdout + second.stderr
            assert "a reload is in progress" in second.stderr
        else:
            assert _set_model_dir(rig, "classifier", Path(classifier_dir))[0]
        stdout, stderr = first.communicate(timeout=60)
    finally:
        first.kill()
    rig.probe.spin(1.5)
    staged = rig.classifier_status()["staged_model_id"]
    if meanwhile == "another reload":
        assert first.returncode == 0, stderr
        assert f"classifier {classifier_a} staged" in stdout
        assert staged == classifier_a, "the first reload said staged: the node must agree"
    else:
        assert first.returncode == 1, stdout
        assert f"does not stage {classifier_a}" in stderr
        assert staged == ""
    # Back to the pair of the other tests: cancel the stage, then the nominal model, then the
    # classifier made for it.
    for node, folder in (
        ("classifier", classifier_dir),
        ("nominal_model", nominal_dir),
        ("classifier", classifier_dir),
    ):
        assert _set_model_dir(rig, node, Path(folder))[0]
