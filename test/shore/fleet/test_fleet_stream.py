"""The streaming scan against a whole-recording computation, and its memory against the
recording's length."""

from __future__ import annotations

import subprocess
import sys
import tracemalloc
from pathlib import Path

import pytest

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd_shore.core.fleet.archive import find_recordings, read_recording
from thruster_fdd_shore.core.fleet.scan import ScanConfig, ThrusterScan, load_pair, scan_recording

ROOT = Path(__file__).resolve().parents[3]


def _archive(out: Path, *args: str) -> Path:
    script = ROOT / "scripts" / "make_fleet_archive.py"
    subprocess.run([sys.executable, str(script), str(out), *args], check=True, timeout=300,
                   capture_output=True)  # fmt: skip
    return out


@pytest.fixture(scope="module")
def config() -> ScanConfig:
    return ScanConfig(str(default_models_dir()))


def _whole(path: Path, config: ScanConfig) -> dict[str, dict]:
    """Rows computed from the whole decoded recording, thruster after thruster."""
    contents = read_recording(path)
    rows = {}
    for trace in contents.traces:
        scan = ThrusterScan(load_pair(config.models), config)
        columns = (trace.t, trace.command, trace.voltage, trace.rpm, trace.current)
        for sample in zip(*(a.tolist() for a in columns), strict=True):
            scan.push(*sample)
        row = scan.row()
        for key in ("start_s", "end_s", "first_fault_s"):
            if row.get(key) is not None:
                row[key] += contents.origin_s
        rows[trace.thruster_id] = row
    return rows


def test_streaming_scan_equals_the_whole_recording_computation(tmp_path: Path, config: ScanConfig):
    archive = _archive(tmp_path / "a", "--days", "3", "--duration", "60", "--blade-day", "1",
                       "--damaged", "0@2")  # fmt: skip
    compared = 0
    for rec in find_recordings(archive):
        rows = scan_recording(rec, "digest", config)
        if rows[0]["error"]:
            with pytest.raises(Exception, match="not an MCAP recording"):
                read_recording(rec.path)
            continue
        whole = _whole(rec.path, config)
        assert [r["thruster"] for r in rows] == sorted(whole)
        for row in rows:
            want = whole[row["thruster"]]
            assert {k: row[k] for k in want if k != "problems"} == {
                k: v for k, v in want.items() if k != "problems"
            }
            compared += 1
    assert compared == 5 * 3


def _peak_bytes(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_scan_memory_does_not_grow_with_the_recording(tmp_path: Path, config: ScanConfig):
    args = ("--vehicles", "1", "--thrusters", "1", "--rate", "50", "--days", "1", "--fouling",
            "--blade", "", "--damaged", "")  # fmt: skip
    short = find_recordings(_archive(tmp_path / "short", *args, "--duration", "300"))[0]
    long = find_recordings(_archive(tmp_path / "long", *args, "--duration", "1200"))[0]
    scan_recording(short, "d", config)  # models loaded, kernels compiled
    stream = {r: _peak_bytes(lambda r=r: scan_recording(r, "d", config)) for r in (short, long)}
    whole = {r: _peak_bytes(lambda r=r: read_recording(r.path)) for r in (short, long)}
    # 4 times the samples, both beyond one 1 MiB chunk: the whole-recording reader's peak grows
    # with them, the scan's stays at about one chunk's records.
    assert whole[long] > 3 * whole[short]
    assert stream[long] < 1.3 * stream[short]
    print(f"scan peak {stream[short] / 1e6:.2f} MB (300 s) / {stream[long] / 1e6:.2f} MB (1200 s);"
          f" whole reader {whole[short] / 1e6:.2f} / {whole[long] / 1e6:.2f} MB")  # fmt: skip


def test_compare_finds_the_differences_of_another_pair(tmp_path: Path, config: ScanConfig):
    from thruster_fdd_shore.core.fleet.compare import differences

    archive = _archive(tmp_path / "a", "--vehicles", "1", "--days", "2", "--duration", "60",
                       "--damaged", "", "--blade", "")  # fmt: skip
    strict = tmp_path / "strict-models"
    subprocess.run([sys.executable, str(ROOT / "scripts" / "make_fleet_models.py"), str(strict),
                    "--probability-threshold", "0.999"], check=True, timeout=60)  # fmt: skip
    other = ScanConfig(str(strict))
    recs = find_recordings(archive)
    old = [row for rec in recs for row in scan_recording(rec, rec.relative, config)]
    new = [row for rec in recs for row in scan_recording(rec, rec.relative, other)]
    assert {r["models_digest"] for r in old}.isdisjoint(r["models_digest"] for r in new)
    found, compared = differences(old, new)
    assert compared == len(old) == 6
    assert found
    assert all(d.share > 0 for d in found)
    assert differences(old, old) == ([], 6)
