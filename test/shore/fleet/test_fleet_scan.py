"""``fleet scan`` on a real LocalCluster of two worker processes over a small synthetic archive
(scripts/make_fleet_archive.py): trends, the blade loss, the damaged recording, a killed
worker, a second scan; then report, compare and the healthy export on the same dataset."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd_shore.core.fleet.compare import differences
from thruster_fdd_shore.core.fleet.dataset import as_rows, read_dataset
from thruster_fdd_shore.core.fleet.healthy import stretches, write_stretches
from thruster_fdd_shore.core.fleet.report import summarize
from thruster_fdd_shore.core.fleet.runner import dask_client, run_tasks, scan_archive
from thruster_fdd_shore.core.fleet.scan import ERROR_THRUSTER, ScanConfig
from thruster_fdd_shore.core.traces.files import read_traces

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[3]
FOULING = {"auv01/t1", "auv02/t0"}
BLADE = "auv02/t2"
HEALTHY = {"auv01/t0", "auv01/t2", "auv02/t1"}


@pytest.fixture(scope="module")
def archive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fleet") / "archive"
    subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "make_fleet_archive.py"), str(out)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return out


@pytest.fixture(scope="module")
def manifest(archive: Path) -> dict[str, Any]:
    return json.loads((archive / "manifest.json").read_text())


@pytest.fixture(scope="module")
def client() -> Iterator[Any]:
    with dask_client(n_workers=2) as c:
        yield c


@pytest.fixture(scope="module")
def config() -> ScanConfig:
    return ScanConfig(str(default_models_dir()))


@pytest.fixture(scope="module")
def scanned(archive: Path, client: Any, config: ScanConfig) -> tuple[Path, Any]:
    out = archive.parent / "dataset"
    return out, scan_archive(archive, out, config, client)


def _comparable(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    drop = {"scanned_at_s"}
    keep = [{k: v for k, v in r.items() if k not in drop} for r in rows]
    return sorted(keep, key=lambda r: (r["recording"], r["thruster"]))


def test_scan_writes_every_recording_and_thruster(scanned: tuple[Path, Any], manifest: dict):
    out, result = scanned
    n = len(manifest["recordings"])
    assert (result.found, result.skipped, result.scanned, result.failed) == (n, 0, n, ())
    rows = as_rows(read_dataset(out))
    assert len(rows) == result.rows == (n - 1) * 3 + 1
    assert {(r["vehicle"], r["thruster"]) for r in rows if not r["error"]} == {
        (f"auv0{v}", f"t{k}") for v in (1, 2) for k in range(3)
    }
    assert (out / "vehicle=auv01" / "thruster=t1").is_dir()
    good = [r for r in rows if not r["error"]]
    assert all(r["samples"] == 1200 and r["decisions"] > 50 for r in good)
    assert all(abs(sum(r[f"frac_{c}"] for c in _labels()) - 1.0) < 1e-9 for r in good)


def _labels() -> tuple[str, ...]:
    from thruster_fdd_shore.core.fleet.scan import LABELS

    return LABELS


def test_damaged_recording_is_an_error_row(scanned: tuple[Path, Any], manifest: dict):
    out, result = scanned
    damaged = [r["recording"] for r in manifest["recordings"] if r["damaged"]]
    assert list(result.errors) == damaged
    errors = [r for r in as_rows(read_dataset(out)) if r["error"]]
    assert [(r["recording"], r["thruster"]) for r in errors] == [(damaged[0], ERROR_THRUSTER)]
    assert "not an MCAP recording" in errors[0]["error"]


def test_fouling_flagged_on_the_right_thrusters_and_no_trend_on_healthy(
    scanned: tuple[Path, Any],
):
    summary = summarize(read_dataset(scanned[0]))
    trends = summary["trends"]
    assert set(trends) == FOULING | HEALTHY | {BLADE}
    assert {k for k in FOULING if trends[k]["flagged"]} == FOULING
    assert all(trends[k]["slope_per_30d"] < -0.3 for k in FOULING)
    assert not any(trends[k]["flagged"] for k in HEALTHY)
    assert "Mann-Kendall" in summary["test"]


def test_blade_loss_found_on_the_right_day(scanned: tuple[Path, Any], manifest: dict):
    day = next(
        r
        for r in manifest["recordings"]
        if r["thrusters"].get("t2", {}).get("blade_lost_at_s") and r["vehicle"] == "auv02"
    )
    faults = summarize(read_dataset(scanned[0]))["faults"]
    assert faults[BLADE]["label"] == "broken_blade_1"
    assert faults[BLADE]["date"] == day["date"]
    assert faults[BLADE]["recording"] == day["recording"]
    assert not set(faults) & HEALTHY


def test_second_scan_adds_nothing(
    scanned: tuple[Path, Any], archive: Path, client: Any, config: ScanConfig
):
    out, first = scanned
    before = sorted(p.name for p in out.rglob("*.parquet"))
    again = scan_archive(archive, out, config, client)
    assert (again.skipped, again.scanned, again.rows) == (first.found, 0, 0)
    assert sorted(p.name for p in out.rglob("*.parquet")) == before


def test_killed_worker_does_not_change_the_result(
    scanned: tuple[Path, Any], archive: Path, client: Any, config: ScanConfig
):
    out = archive.parent / "dataset-killed"
    killed: list[int] = []

    def kill_one(done: int) -> None:
        if done != 3 or killed:
            return
        busy = [w for w, keys in client.processing().items() if keys]
        pid = client.run(os.getpid, workers=busy[:1])[busy[0]]
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)

    result = scan_archive(archive, out, config, client, on_done=kill_one)
    assert killed
    assert result.failed == ()
    assert _comparable(as_rows(read_dataset(out))) == _comparable(as_rows(read_dataset(scanned[0])))


def _wait_for(path: Path, seconds: float) -> dict[str, Any]:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if path.is_file() and path.stat().st_size:
            return json.loads(path.read_text())
        time.sleep(0.2)
    raise AssertionError(f"{path} not written in {seconds:g} s")


def test_scan_on_an_existing_cluster_equals_the_local_one(
    scanned: tuple[Path, Any], archive: Path, tmp_path: Path
):
    """``--scheduler`` runs the same tasks on a cluster started outside the command (a separate
    ``dask scheduler`` and ``dask worker`` process, as a Slurm or PBS job would start them)."""
    from distributed import Client

    info = tmp_path / "scheduler.json"
    common = {"cwd": tmp_path, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    scheduler = subprocess.Popen(
        ["dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
         "--scheduler-file", str(info)], **common,
    )  # fmt: skip
    worker = None
    try:
        address = _wait_for(info, 60)["address"]
        worker = subprocess.Popen(
            ["dask", "worker", "--scheduler-file", str(info), "--nthreads", "1", "--nworkers",
             "1", "--host", "127.0.0.1", "--no-dashboard"], **common,
        )  # fmt: skip
        with Client(address, timeout="20s") as probe:
            probe.wait_for_workers(1, timeout=60)
        out = tmp_path / "dataset"
        done = subprocess.run(
            ["thruster-fdd", "fleet", "scan", str(archive), "--out", str(out), "--scheduler",
             address], capture_output=True, text=True, timeout=600,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-2000:]
        with Client(address, timeout="20s") as probe:
            ran = probe.run_on_scheduler(lambda dask_scheduler: list(dask_scheduler.task_prefixes))
        assert "fleet" in ran
    finally:
        for proc in (worker, scheduler):
            if proc is not None:
                proc.terminate()
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(timeout=10)
    assert _comparable(as_rows(read_dataset(out))) == _comparable(as_rows(read_dataset(scanned[0])))


def test_compare_with_the_same_pair_finds_no_difference(
    scanned: tuple[Path, Any], archive: Path, client: Any, config: ScanConfig
):
    from thruster_fdd_shore.core.fleet.archive import find_recordings, recording_digest

    old = as_rows(read_dataset(scanned[0]))
    tasks = [(r, recording_digest(r.path)) for r in find_recordings(archive)]
    new, failed = run_tasks(client, tasks, config)
    found, compared = differences(old, new)
    assert (found, failed, compared) == ([], [], len(old) - 1)


def test_healthy_stretches_leave_out_faulty_units(scanned: tuple[Path, Any], archive: Path):
    rows = as_rows(read_dataset(scanned[0]))
    found = stretches(rows)
    units = {f"{s.vehicle}/{s.thruster}" for s in found}
    assert units >= HEALTHY
    assert BLADE not in units or all(
        s.recording < "auv02/auv02_20260312" for s in found if f"{s.vehicle}/{s.thruster}" == BLADE
    )
    files = write_stretches(archive, found[:3], archive.parent / "healthy")
    traces = read_traces(files)
    assert [t.condition for t in traces] == [s.label for s in found[:3]]
    assert all(len(t) >= 300 and t.t[0] >= 0 for t in traces)


def test_cli_report_and_dataset(scanned: tuple[Path, Any], tmp_path: Path):
    out = subprocess.run(
        ["thruster-fdd", "fleet", "report", str(scanned[0]), "--out", str(tmp_path / "rep")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    page = (tmp_path / "rep" / "index.html").read_text()
    assert page.count("data:image/png;base64,") == 2
    assert "Mann-Kendall" in page
    assert "auv01/t1" in (tmp_path / "rep" / "summary.md").read_text()
    out = subprocess.run(
        ["thruster-fdd", "fleet", "dataset", str(scanned[0]), "--healthy", "--out",
         str(tmp_path / "healthy")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert list((tmp_path / "healthy" / "auv01" / "t0").glob("*.csv"))


def test_cli_bad_input_is_one_line_exit_2(tmp_path: Path):
    out = subprocess.run(
        ["thruster-fdd", "fleet", "report", str(tmp_path / "nope"), "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0
    assert "no such dataset folder" in out.stderr
