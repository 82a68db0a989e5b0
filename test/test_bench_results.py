"""Benchmark scripts write their numbers into a machine-readable results file."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_a_benchmark_run_writes_one_results_file(tmp_path: Path):
    done = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "bench_simulator.py"), "--duration", "20",
         "--repeats", "1", "--results", str(tmp_path)],
        capture_output=True, text=True, timeout=300, cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    (path,) = tmp_path.glob("*-bench_simulator.json")
    doc = json.loads(path.read_text())
    assert doc["bench"] == "bench_simulator"
    assert doc["command"].startswith("python bench/bench_simulator.py --duration 20")
    assert doc["machine"]["cores"] >= 1
    assert doc["machine"]["python"].startswith("3.")
    assert {"start", "end"} <= set(doc["load_average"])
    assert [r["metric"].split(" at ")[1] for r in doc["results"]] == [
        "10 Hz, mission signal",
        "100 Hz, mission signal",
    ]
    assert all(r["unit"] == "x" and r["median"] > 0 for r in doc["results"])


def test_no_results_file_with_a_dash(tmp_path: Path):
    done = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "bench_simulator.py"), "--duration", "5",
         "--repeats", "1", "--results", "-"],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "wrote" not in done.stdout
    assert not list(tmp_path.iterdir())
