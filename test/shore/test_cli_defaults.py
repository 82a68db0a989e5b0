"""The command line's defaults and help: one models folder for every
command whatever the current folder, nothing shipped replaced without --force, help on every
option, input checked before torch, CSV column names."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from thruster_fdd.core.artifact import MODELS_ENV, default_models_dir
from thruster_fdd_shore.cli import build_parser, main
from thruster_fdd_shore.commands.common import model_folder

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "models"


def _cli(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if k != MODELS_ENV}
    return subprocess.run(
        [sys.executable, "-m", "thruster_fdd_shore.cli", *args],
        cwd=cwd,
        env={**environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=300,
    )


def _options(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options(sub, (*path, name))
        elif not isinstance(action, argparse._HelpAction):
            yield path, action


def test_every_option_has_a_help_text() -> None:
    missing = [
        f"{' '.join(path)} {action.option_strings or action.dest}"
        for path, action in _options(build_parser())
        if not action.help
    ]
    assert missing == []


def test_the_models_folder_is_the_workspace_s_or_the_variable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(MODELS_ENV, raising=False)
    assert model_folder(None, "nominal") == SHIPPED / "nominal"
    monkeypatch.setenv(MODELS_ENV, str(tmp_path / "mine"))
    assert model_folder(None, "classifier") == tmp_path / "mine" / "classifier"
    assert model_folder(tmp_path / "given", "classifier") == tmp_path / "given"


def _short_trace(path: Path) -> Path:
    rows = ["t,command,voltage,rpm,current"] + [
        f"{i * 0.1:.1f},0.2,15.0,900,1.0" for i in range(40)
    ]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_diagnose_finds_the_workspace_models_from_any_folder(tmp_path: Path) -> None:
    """Run outside the workspace (no ./models): the shipped models are used; the 4 s trace then
    holds no decision window (before: ./models/nominal was looked for and missing)."""
    trace = _short_trace(tmp_path / "short.csv")
    done = _cli("diagnose", str(trace), cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert "no full decision window" in done.stderr, done.stderr


def test_diagnose_takes_the_variable(tmp_path: Path) -> None:
    trace = _short_trace(tmp_path / "short.csv")
    done = _cli("diagnose", str(trace), cwd=tmp_path, env={MODELS_ENV: str(tmp_path / "none")})
    assert done.returncode == 2
    assert f"{tmp_path / 'none' / 'nominal'}: no exported model" in done.stderr, done.stderr


def test_diagnose_checks_its_input_before_importing_torch(tmp_path: Path) -> None:
    code = (
        "import sys; from thruster_fdd_shore.cli import main; "
        "rc = main(['diagnose', 'no-such-trace.csv']); print(rc, 'torch' in sys.modules)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert done.stdout.split() == ["2", "False"], (done.stdout, done.stderr)
    assert "no-such-trace.csv: no such trace file" in done.stderr


@pytest.mark.parametrize(
    "args",
    [
        ["train", "nominal", "--data", "x.csv"],
        ["train", "nominal", "--data", "x.csv", "--out", str(SHIPPED / "nominal")],
        ["train", "classifier", "--data", "x.csv"],
    ],
)
def test_train_refuses_to_replace_a_shipped_model_without_force(
    args: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.chdir(ROOT)  # where `train nominal` without --out used to replace the model
    monkeypatch.delenv(MODELS_ENV, raising=False)
    before = (SHIPPED / args[1] / "model_card.json").read_bytes()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "--force" in err, err
    assert err.count("\n") == 1, err
    assert (SHIPPED / args[1] / "model_card.json").read_bytes() == before


def test_train_nominal_defaults_to_the_shipped_model_s_mode() -> None:
    card = json.loads((default_models_dir() / "nominal" / "model_card.json").read_text())
    args = build_parser().parse_args(["train", "nominal", "--data", "x.csv"])
    assert args.mode == card["mode"] == "series-parallel"


def test_evaluate_targets_have_their_own_options(capsys: pytest.CaptureFixture) -> None:
    parser = build_parser()
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(["evaluate", "classifier", "--seeds", "3"])  # a Table 2 option
    assert exc.value.code == 2
    with pytest.raises(SystemExit):
        parser.parse_args(["evaluate", "nominal", "--nominal", "x"])  # a classifier option
    nominal = parser.parse_args(["evaluate", "nominal", "--model", "m", "--data", "a.csv"])
    assert nominal.target == "nominal"
    assert nominal.mode == "parallel"
    classifier = parser.parse_args(["evaluate", "classifier", "--seed", "2"])
    assert classifier.model is None
    assert classifier.seed == 2
    capsys.readouterr()


def test_record_help_says_it_writes_a_bag_folder(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["record", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "rosbag2 bag folder" in out
    assert "MCAP files" in out


def test_a_csv_with_message_field_names_lists_the_expected_columns(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    csv = tmp_path / "fields.csv"
    csv.write_text("t,command,voltage_v,rpm,current_a\n0,0,15,0,0\n0.1,0,15,0,0\n")
    assert main(["diagnose", str(csv)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "missing trace column(s) voltage, current" in err
    assert "expected the columns t, command, voltage, rpm, current" in err
    assert "found t, command, voltage_v, rpm, current_a" in err
