"""The command line as a clumsy user or an attacker meets it.

Every bad input gives exit 2 and one line on stderr naming the input (never a traceback);
damaged recordings are read in part with one warning line; a tampered model never runs code;
a failed export leaves the model it was to replace.
"""

from __future__ import annotations

import json
import pickle
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from thruster_fdd.core.artifact import CARD_FILE, default_models_dir, file_sha256
from thruster_fdd_shore.cli import main
from thruster_fdd_shore.core.sim.scenario import run_scenario
from thruster_fdd_shore.core.traces.files import write_trace

MODELS = default_models_dir()


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of inputs: good traces and recordings, and every kind of bad one."""
    d = tmp_path_factory.mktemp("cli")
    trace = run_scenario("t100", "nominal_15v", signal="sine:0.05", duration_s=60.0, rate_hz=10.0)
    write_trace(trace, d / "ok.csv")
    write_trace(trace, d / "ok.mcap")
    good = (d / "ok.mcap").read_bytes()
    (d / "short5.mcap").write_bytes(good[:-5])
    (d / "tiny.mcap").write_bytes(good[:70])
    (d / "csv.mcap").write_bytes((d / "ok.csv").read_bytes())
    flipped = bytearray(good)
    for i in (3000, 3001, 3002):
        flipped[i] ^= 0xFF
    (d / "flip.mcap").write_bytes(bytes(flipped))
    text = (d / "ok.csv").read_text().splitlines()
    header, rows = text[0].split(","), [r.split(",") for r in text[1:]]
    c, t = header.index("command"), header.index("t")
    pwm = [[*r[:c], f"{1500 + 400 * float(r[c]):.0f}", *r[c + 1 :]] for r in rows]
    ms = [[f"{1000 * float(r[t]):.0f}", *r[t + 1 :]] for r in rows]
    (d / "pwm.csv").write_text("\n".join(",".join(r) for r in [header, *pwm]) + "\n")
    (d / "ms.csv").write_text("\n".join(",".join(r) for r in [header, *ms]) + "\n")
    r = header.index("rpm")
    dup = [[*header, "rpm"], *([*row, row[r]] for row in rows)]
    (d / "dup.csv").write_text("\n".join(",".join(row) for row in dup) + "\n")
    (d / "afile").write_text("not a folder\n")
    (d / "one.csv").write_text("t,command,voltage,rpm,current\n0,0,15,0,0\n")
    (d / "tag.yaml").write_text("rate_hz: !!python/object/apply:os.system [ls]\nthrusters: []\n")
    (d / "types.yaml").write_text("rate_hz: fast\nthrusters: [{id: t0}]\n")
    (d / "seed.yaml").write_text("thrusters: [{id: t0, seed: abc}]\n")
    (d / "list.yaml").write_text("- a\n- b\n")
    (d / "entry.yaml").write_text("thrusters: [5]\n")
    (d / "keys.yaml").write_text("1: a\nb: c\nthrusters: [{id: t0}]\n")
    (d / "bigseed.yaml").write_text("thrusters: [{id: t0, seed: 100000000000000000000000}]\n")
    (d / "dupkey.yaml").write_text("rate_hz: 50\nrate_hz: 10\nthrusters: [{id: t0}]\n")
    bomb = "a: &a [x, x, x, x, x, x, x, x, x]\n"
    bomb += "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(8)
    )
    (d / "bomb.yaml").write_text(bomb + "thrusters: [*i]\n")
    (d / "binary.yaml").write_bytes(bytes(range(256)) * 4)
    (d / "ttylink").symlink_to("/dev/null")
    (d / "samedev.yaml").write_text(
        f"thrusters: [{{id: t0, port: /dev/null}}, {{id: t1, port: {d / 'ttylink'}}}]\n"
    )
    (d / "umlaut.yaml").write_text("thrusters: [{id: tä}]\n", encoding="utf-8")
    (d / "longid.yaml").write_text(f"thrusters: [{{id: {'t' * 300}}}]\n")
    for name, value in DRIVER_OUT_OF_RANGE:
        (d / f"driver_{name}_{value}.yaml").write_text(
            f"thrusters: [{{id: t0, port: /dev/null, {name}: {value}}}]\n"
        )
    return d


def _models(work: Path, name: str, change: Callable[[Path], None]) -> Path:
    """A copy of the committed models with ``change`` applied to it."""
    dst = work / name
    if not dst.exists():
        shutil.copytree(MODELS, dst)
        change(dst)
    return dst


def _set_card(folder: Path, **fields: object) -> None:
    card = json.loads((folder / CARD_FILE).read_text())
    card.update(fields)
    (folder / CARD_FILE).write_text(json.dumps(card))


def _infinite_temperature(d: Path) -> None:
    text = (d / "classifier" / CARD_FILE).read_text()
    card = json.loads(text)
    card["temperature"] = float("inf")
    (d / "classifier" / CARD_FILE).write_text(json.dumps(card))  # writes Infinity


def _deep_window(d: Path) -> None:
    card = json.loads((d / "classifier" / CARD_FILE).read_text())
    card["lookbacks"]["window_samples"] = 10**10
    (d / "classifier" / CARD_FILE).write_text(json.dumps(card))


def _appended(name: str) -> Callable[[Path], None]:
    def change(models: Path) -> None:
        with (models / "nominal" / name).open("ab") as f:
            f.write(b"x")

    return change


DRIVER_OUT_OF_RANGE: list[tuple[str, str]] = [
    ("bridge_timeout_ms", "70000"),
    ("bridge_timeout_ms", "0"),
    ("rate_hz", "100000.0"),
    ("baud", "1e23"),
    ("command_rate_hz", "1e-300"),
]
"""Driver settings outside the esc_driver's declared ranges (name, YAML value)."""

# (arguments with {w} for the work folder and {m} for the models, words the one line holds)
BAD_INPUT: list[tuple[str, str]] = [
    ("up --config {w}/umlaut.yaml", "must be a ROS name token"),
    ("up --config {w}/samedev.yaml", "same serial device /dev/null"),
    ("up --config {w}/longid.yaml", "at most 64"),
    *(
        (f"up --config {{w}}/driver_{name}_{value}.yaml", f"{name}")
        for name, value in DRIVER_OUT_OF_RANGE
    ),
    ("simulate --command-csv {w} --out {w}/x.csv", "--command-csv"),
    ("simulate --duration 1e9 --rate 100 --out {w}/x.csv", "at most"),
    ("simulate --fault-at nan --fault-condition biofouling --out {w}/x.csv", "finite"),
    ("simulate --fault-at 500 --fault-condition biofouling --out {w}/x.csv", "within the run"),
    ("simulate --fault-at 5 --out {w}/x.csv", "--fault-condition"),
    ("simulate --seed -1 --out {w}/x.csv", "--seed"),
    ("simulate --out {w}/afile/x.csv", "is a file"),
    ("simulate --out {w}/x.txt", ".csv or .mcap"),
    ("simulate --config {w}/bomb.yaml --out {w}/x.csv", "anchors"),
    ("simulate --config {w}/binary.yaml --out {w}/x.csv", "not valid YAML"),
    ("simulate --thruster-id 'bad id' --out {w}/x.csv", "ROS name"),
    ("up --config {w}/types.yaml", "rate_hz must be a number"),
    ("up --config {w}/seed.yaml", "seed must be an integer"),
    ("up --config {w}/tag.yaml", "tags"),
    ("up --config {w}/bomb.yaml", "anchors"),
    ("up --config {w}/list.yaml", "expected a mapping"),
    ("up --config {w}/entry.yaml", "must be a mapping"),
    ("up --config {w}/dupkey.yaml", "repeated"),
    ("up --config {w}/keys.yaml", "unknown key(s) 1, b"),
    ("up --config {w}/bigseed.yaml", "seed must be within"),
    ("up --config {w}", "Is a directory"),
    ("up --fault t0:biofouling@nan", "--fault"),
    ("up --fault t0:biofouling@abc", "--fault"),
    ("up --fault t7:biofouling@3", "--fault"),
    ("up --fault t0:X@3", "unknown fault_condition"),
    ("up --thrusters 1000", "1..16"),
    ("up --signal sine:99", "sine frequency"),
    ("up --rate nan", "telemetry rate"),
    ("up --preset {w}/bomb.yaml", "anchors"),
    ("up --record-dir {w}/afile", "--record-dir"),
    ("up --models {w}/weights", "SHA-256"),
    ("up --models {w}/tiny_temperature", "temperature 5e-324"),
    ("up --models {w}/deep_window", "window_samples"),
    ("train nominal --data {w}/ok.csv --out {w}/afile", "exists and is a file"),
    ("train nominal --data {w}/ok.csv --out {w}/afile/sub", "is a file, not a folder"),
    ("train nominal --data {w} --out {w}", "also a --data folder"),
    ("train nominal --data {w}/pwm.csv --out {w}/n", "pulse width"),
    ("train nominal --data {w}/ms.csv --out {w}/n", "looks like ms"),
    ("train nominal --data {w}/dup.csv --out {w}/n", "more than once"),
    ("train nominal --data {w}/csv.mcap --out {w}/n", "not an MCAP recording"),
    ("train nominal --data {w}/one.csv --out {w}/n", "at least 10 s"),
    (
        "train classifier --data {w}/ok.csv --nominal {m}/nominal --out {w}/c --window 0.05",
        "--window",
    ),
    (
        "train classifier --data {w}/ok.csv --nominal {m}/nominal --out {w}/c --window 1e300",
        "--window",
    ),
    ("train classifier --data {w}/ok.csv --nominal {m}/nominal --out {m}/nominal", "replaced"),
    ("train classifier --data {w}/ok.csv --nominal {w}/weights/nominal --out {w}/c", "SHA-256"),
    ("evaluate nominal --rate nan", "--rate"),
    ("evaluate nominal --seeds 100000", "--seeds"),
    ("evaluate nominal --model {m}/nominal --data {w}/tiny.mcap", "no message could be read"),
    ("evaluate nominal --model {m}/nominal --data {w}/one.csv", "too short"),
    ("evaluate nominal --model {m}/nominal --data {w}/ok.csv --json {w}/afile/x", "is a file"),
    ("discrepancy --measured {w}/ok.csv --start t100 --out {w}/afile", "exists and is a file"),
    ("discrepancy --measured {w}/ok.csv --start t100 --out {w}/d --workers 1000", "--workers"),
    ("discrepancy --measured {w}/csv.mcap --start t100 --out {w}/d", "not an MCAP"),
    ("replay {w}/ok.mcap --rate -1", "--rate"),
    ("replay {w}/ok.mcap --min-agreement 5", "--min-agreement"),
    ("replay {w}/csv.mcap", "not an MCAP recording"),
    ("replay {w}/tiny.mcap", "no message could be read"),
    ("replay {w}/ok.mcap --models {w}/weights", "SHA-256"),
    ("emulate --link {w}/afile", "not a symlink"),
    ("emulate --link {w}/t.tty --fault-at 3", "go together"),
    ("emulate --link {w}/t.tty --rate 5000", "1..1000"),
    ("diagnose {w}/csv.mcap", "not an MCAP recording"),
    ("diagnose {w}/tiny.mcap", "no message could be read"),
    ("diagnose {w}/flip.mcap", "damaged chunk"),
    ("diagnose {w}/pwm.csv", "pulse width"),
    ("diagnose {w}/one.csv", "no full decision window"),
    ("diagnose {w}/ok.csv --models {w}/infinite", "'temperature' is inf"),
    ("diagnose {w}/ok.csv --models {w}/program", "model.pt2: SHA-256"),
    ("replay {w}/ok.mcap --models {w}/tiny_temperature", "temperature 5e-324"),
]


@pytest.fixture(scope="module")
def variants(work: Path) -> Path:
    _models(work, "weights", _appended("weights.npz"))
    _models(work, "program", _appended("model.pt2"))
    _models(work, "infinite", _infinite_temperature)
    # Cards whose digests hold (the card lists the other files') but that the node refuses.
    _models(work, "tiny_temperature", lambda d: _set_card(d / "classifier", temperature=5e-324))
    _models(work, "deep_window", _deep_window)
    return work


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors
        code = int(exc.code or 0)
    return code, capsys.readouterr().err


@pytest.mark.parametrize(("command", "words"), BAD_INPUT, ids=[c for c, _ in BAD_INPUT])
def test_bad_input_is_exit_2_and_one_line(
    variants: Path, capsys: pytest.CaptureFixture[str], command: str, words: str
) -> None:
    import shlex

    argv = shlex.split(command.format(w=variants, m=MODELS))
    if argv[0] == "diagnose" and "--models" not in argv:
        argv += ["--models", str(MODELS)]
    code, err = _run(argv, capsys)
    lines = [line for line in err.splitlines() if line and not line.startswith("[")]
    assert code == 2, err
    assert len(lines) == 1, err
    assert words in lines[0], lines[0]
    assert lines[0].startswith("thruster-fdd")


def test_emulate_link_leaves_the_file(variants: Path) -> None:
    assert (variants / "afile").read_text() == "not a folder\n"


@pytest.mark.parametrize(
    ("name", "words"),
    [("short5.mcap", "closing magic"), ("cut.mcap", "ends early")],
)
def test_damaged_recording_is_read_with_one_warning_line(
    variants: Path, capsys: pytest.CaptureFixture[str], name: str, words: str
) -> None:
    """A recording cut by kill -9 (the recorder's chunks: one a second) diagnoses what it holds."""
    if name == "cut.mcap":
        _cut_recording(variants / name)
    code, err = _run(["diagnose", str(variants / name), "--models", str(MODELS)], capsys)
    lines = [line for line in err.splitlines() if line]
    assert code == 0, err
    assert len(lines) == 1, err
    assert lines[0].startswith("thruster-fdd diagnose: warning:")
    assert words in lines[0]


def _cut_recording(path: Path) -> None:
    """A 60 s recording in 1 s chunks, cut in the middle of its 45th chunk."""
    from mcap_ros2.writer import Writer

    from thruster_fdd.core.traces.mcap_io import TELEMETRY_TYPE, message_definition, telemetry_topic

    trace = run_scenario("t100", "nominal_15v", signal="sine:0.05", duration_s=60.0, rate_hz=10.0)
    with path.open("wb") as f:
        writer = Writer(f, chunk_size=900)
        schema = writer.register_msgdef(TELEMETRY_TYPE, message_definition(TELEMETRY_TYPE))
        for i in range(len(trace)):
            ns = round(float(trace.t[i]) * 1e9)
            message = {
                "header": {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}},
                "command": float(trace.command[i]),
                "voltage_v": float(trace.voltage[i]),
                "rpm": float(trace.rpm[i]),
                "current_a": float(trace.current[i]),
            }
            writer.write_message(telemetry_topic("t0"), schema, message, ns, ns, i)
        writer.finish()
    data = path.read_bytes()
    path.write_bytes(data[: int(0.75 * len(data))])


def test_a_traceback_is_kept_for_a_bug(capsys: pytest.CaptureFixture[str], monkeypatch) -> None:
    """The contract's other half: what is not bad input is a bug and keeps its traceback."""
    from thruster_fdd_shore.commands import simulate

    def broken(args: object) -> int:
        raise ValueError("a bug")

    monkeypatch.setattr(simulate, "run", broken)
    with pytest.raises(ValueError, match="a bug"):
        main(["simulate", "--out", "x.csv"])


def test_real_process_exit_code_and_no_traceback(variants: Path) -> None:
    """One case through the installed entry point: the exit code a shell sees."""
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "thruster_fdd_shore.cli",
            "up",
            "--config",
            str(variants / "tag.yaml"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


# ----------------------------------------------------------------------------- models


class _Payload:
    """Unpickling this touches a file: proof that code ran."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[object, tuple[str]]:
        return (Path.touch, (str(self.marker),))  # type: ignore[return-value]


def test_a_model_file_that_would_run_code_never_runs(tmp_path: Path) -> None:
    """model.pt2 replaced by a pickle that runs code when loaded, with the card's digest updated
    to match (a careful attacker): the runtime loaders, the offline diagnosis and the replay's
    model checks read the weights with numpy and never unpickle anything."""
    from thruster_fdd.core.diagnosis.model import ClassifierModel
    from thruster_fdd.core.nominal.runtime import NominalModel
    from thruster_fdd_shore.core.diagnosis.offline import diagnose_trace

    marker = tmp_path / "pwned"
    payload = pickle.dumps(_Payload(marker))
    pickle.loads(payload)  # the payload works: this run creates the marker
    assert marker.exists()
    marker.unlink()
    models = tmp_path / "models"
    shutil.copytree(MODELS, models)
    for stage in ("nominal", "classifier"):
        (models / stage / "model.pt2").write_bytes(payload)
        card = json.loads((models / stage / CARD_FILE).read_text())
        card["files"]["model.pt2"] = file_sha256(models / stage / "model.pt2")
        (models / stage / CARD_FILE).write_text(json.dumps(card))
    NominalModel.load(models / "nominal")
    ClassifierModel.load(models / "classifier")
    trace = run_scenario("t100", "nominal_15v", signal="sine:0.05", duration_s=40.0, rate_hz=10.0)
    result = diagnose_trace(trace, models / "nominal", models / "classifier")
    assert result["windows"]
    assert not marker.exists()


def test_pickled_weights_are_refused_without_running(tmp_path: Path) -> None:
    """weights.npz holding a pickled object array (digest updated): refused, never unpickled."""
    from thruster_fdd.core.errors import ModelMismatchError
    from thruster_fdd.core.nominal.runtime import NominalModel

    marker = tmp_path / "pwned"
    folder = tmp_path / "nominal"
    shutil.copytree(MODELS / "nominal", folder)
    arrays = dict(np.load(folder / "weights.npz"))
    arrays["evil"] = np.array([_Payload(marker)], dtype=object)
    with (folder / "weights.npz").open("wb") as f:
        np.savez(f, **arrays)
    card = json.loads((folder / CARD_FILE).read_text())
    card["files"]["weights.npz"] = file_sha256(folder / "weights.npz")
    (folder / CARD_FILE).write_text(json.dumps(card))
    with pytest.raises(ModelMismatchError, match=r"weights\.npz"):
        NominalModel.load(folder)
    assert not marker.exists()


def test_a_failed_train_nominal_leaves_the_old_model(
    work: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Item 5: the export's last check fails (as a program that does not reproduce the weights
    would): the folder it was to replace is byte for byte as before, and nothing is left beside
    it."""
    from thruster_fdd.core.errors import ModelMismatchError
    from thruster_fdd_shore.core.nominal import export

    out = work / "existing"
    shutil.copytree(MODELS / "nominal", out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def failing_check(*args: object) -> None:
        raise ModelMismatchError("the program's graph differs (injected)")

    monkeypatch.setattr(export, "check_program", failing_check)
    argv = ["train", "nominal", "--data", str(work / "ok.csv"), "--out", str(out)]
    argv += ["--mode", "series-parallel", "--epochs", "2", "--validation-fraction", "0"]
    code, err = _run(argv, capsys)
    assert code == 2, err
    assert "injected" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in work.iterdir() if p.name.startswith(".existing")) == []


def _huge_header_weights(path: Path) -> None:
    """A weights.npz whose one array header claims 10^12 float64 (8 TB) over 80 bytes of data."""
    import io
    import zipfile

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buf, {"descr": "<f8", "fortran_order": False, "shape": (10**12,)}
    )
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("out.bias.npy", buf.getvalue() + bytes(80))


def _nested_card(path: Path) -> None:
    """A model card of 200,000 nested brackets."""
    path.write_text('{"kind": "nominal", "files": ' + "[" * 200_000 + "]" * 200_000 + "}")


@pytest.mark.parametrize(
    ("damage", "words"),
    [(_huge_header_weights, "header claims"), (_nested_card, "nested too deep")],
    ids=["weights-header-1e12", "card-200000-brackets"],
)
def test_hostile_model_files_are_one_line_exit_2(
    work: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    damage: Callable[[Path], None],
    words: str,
) -> None:
    """Loaders bound what they read before allocating: no MemoryError or RecursionError."""
    models = tmp_path / "models"
    shutil.copytree(MODELS, models)
    nominal = models / "nominal"
    if damage is _nested_card:
        damage(nominal / CARD_FILE)
    else:
        damage(nominal / "weights.npz")
        card = json.loads((nominal / CARD_FILE).read_text())
        card["files"]["weights.npz"] = file_sha256(nominal / "weights.npz")
        (nominal / CARD_FILE).write_text(json.dumps(card))
    code, err = _run(["diagnose", str(work / "ok.csv"), "--models", str(models)], capsys)
    lines = [line for line in err.splitlines() if line]
    assert code == 2, err
    assert len(lines) == 1, err
    assert words in lines[0], lines[0]


def test_oversized_card_is_refused_unread(tmp_path: Path) -> None:
    from thruster_fdd.core.artifact import MAX_CARD_BYTES
    from thruster_fdd.core.errors import ModelMismatchError
    from thruster_fdd.core.nominal.card import read_nominal_card

    folder = tmp_path / "nominal"
    shutil.copytree(MODELS / "nominal", folder)
    (folder / CARD_FILE).write_text('{"kind": "nominal", "pad": "' + "x" * MAX_CARD_BYTES + '"}')
    with pytest.raises(ModelMismatchError, match="larger than"):
        read_nominal_card(folder)


def test_an_empty_split_of_a_bag_is_skipped_with_one_warning(
    work: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A full disk leaves an empty split in the bag folder: the rest is diagnosed."""
    bag = tmp_path / "bag"
    bag.mkdir()
    shutil.copy(work / "ok.mcap", bag / "bag_0.mcap")
    (bag / "bag_1.mcap").write_bytes(b"")
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  relative_file_paths: [bag_0.mcap, bag_1.mcap]\n"
    )
    code, err = _run(["diagnose", str(bag), "--models", str(MODELS)], capsys)
    lines = [line for line in err.splitlines() if line]
    assert code == 0, err
    assert len(lines) == 1, err
    assert "bag_1.mcap: split skipped (empty)" in lines[0]
    (bag / "bag_0.mcap").write_bytes(b"")
    code, err = _run(["diagnose", str(bag), "--models", str(MODELS)], capsys)
    assert code == 2, err
