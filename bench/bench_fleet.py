#!/usr/bin/env python3
"""Fleet scan throughput: telemetry samples per second of the serial loop (one process, no Dask),
a LocalCluster of 1 worker and of 2 workers on the same synthetic 50 Hz archive in the same run,
the memory of each worker, and the hours a month of a 20-vehicle x 8-thruster fleet at 50 Hz
would take on N cores. Writes bench/results/<date>-bench_fleet.json.

    python bench/bench_fleet.py [--vehicles 4 --thrusters 2 --days 4 --duration 120]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

from results_file import Run, add_results_option

ROOT = Path(__file__).resolve().parents[1]
FLEET_SAMPLES_PER_MONTH = 20 * 8 * 50 * 86400 * 30
"""20 vehicles x 8 thrusters at 50 Hz for 30 days."""


def _rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--vehicles", type=int, default=4)
    p.add_argument("--thrusters", type=int, default=2)
    p.add_argument("--days", type=int, default=4)
    p.add_argument("--duration", type=float, default=120.0, help="recording length, s")
    add_results_option(p)
    args = p.parse_args()
    started, load_start = datetime.now(UTC).isoformat(timespec="seconds"), os.getloadavg()[0]

    from thruster_fdd.core.artifact import default_models_dir
    from thruster_fdd_shore.core.fleet.archive import find_recordings, recording_digest
    from thruster_fdd_shore.core.fleet.runner import dask_client, run_tasks
    from thruster_fdd_shore.core.fleet.scan import ScanConfig, scan_recording

    tmp = Path(tempfile.mkdtemp(prefix="bench_fleet_"))
    archive = tmp / "archive"
    subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "make_fleet_archive.py"), str(archive),
         "--vehicles", str(args.vehicles), "--thrusters", str(args.thrusters),
         "--days", str(args.days), "--duration", str(args.duration), "--rate", "50",
         "--fouling", "0/1", "--blade", "", "--damaged", ""],
        check=True, capture_output=True,
    )  # fmt: skip
    tasks = [(r, recording_digest(r.path)) for r in find_recordings(archive)]
    config = ScanConfig(str(default_models_dir()))
    results: dict[str, dict[str, float]] = {}

    t0 = time.perf_counter()
    rows = [row for rec, digest in tasks for row in scan_recording(rec, digest, config)]
    serial_s = time.perf_counter() - t0
    samples = sum(r["samples"] for r in rows)
    results["serial"] = {"seconds": serial_s, "samples_per_s": samples / serial_s,
                         "rss_mb": _rss_mb()}  # fmt: skip
    print(f"serial: {samples} samples in {serial_s:.1f} s = {samples / serial_s:.0f} samples/s")

    for n in (1, 2):
        with dask_client(n_workers=n) as client:
            run_tasks(client, tasks[:n], config)  # warm-up: models loaded in every worker
            t0 = time.perf_counter()
            rows, failed = run_tasks(client, tasks, config)
            seconds = time.perf_counter() - t0
            rss = client.run(_rss_mb)
        assert not failed, failed
        rate = sum(r["samples"] for r in rows) / seconds
        results[f"workers_{n}"] = {
            "seconds": seconds,
            "samples_per_s": rate,
            "rss_mb_per_worker": max(rss.values()),
        }
        print(
            f"{n} worker(s): {seconds:.1f} s = {rate:.0f} samples/s "
            f"({rate / results['serial']['samples_per_s']:.2f} x serial), "
            f"worker RSS {max(rss.values()):.0f} MB"
        )
    per_worker = results["workers_1"]["samples_per_s"]
    efficiency = results["workers_2"]["samples_per_s"] / (2 * per_worker)
    cores_list = (2, 8, 32, 128)
    ideal = {str(c): FLEET_SAMPLES_PER_MONTH / (per_worker * c) / 3600 for c in cores_list}
    projection = {k: v / min(efficiency, 1.0) for k, v in ideal.items()}
    for cores in ideal:
        print(
            f"20 vehicles x 8 thrusters x 50 Hz, one month on {cores} cores: "
            f"{ideal[cores]:.0f} h at the 1-worker rate per core, {projection[cores]:.0f} h at "
            f"the measured 2-worker efficiency {efficiency:.2f}"
        )
    run = Run("bench_fleet", started=started, load_start=load_start)
    run.add("serial loop, no Dask", "samples/s", results["serial"]["samples_per_s"],
            seconds=serial_s, rss_mb=results["serial"]["rss_mb"])  # fmt: skip
    for n in (1, 2):
        r = results[f"workers_{n}"]
        run.add(f"LocalCluster, {n} worker(s)", "samples/s", r["samples_per_s"],
                seconds=r["seconds"], rss_mb_per_worker=r["rss_mb_per_worker"])  # fmt: skip
    run.write(
        args.results,
        archive={"recordings": len(tasks), "samples": samples, "rate_hz": 50,
                 "thrusters_per_recording": args.thrusters},
        ratio_1_worker_vs_serial=per_worker / results["serial"]["samples_per_s"],
        ratio_2_vs_1_workers=results["workers_2"]["samples_per_s"] / per_worker,
        fleet_samples_per_month=FLEET_SAMPLES_PER_MONTH,
        scaling_efficiency_2_workers=efficiency,
        projected_hours_per_month_by_cores_ideal=ideal,
        projected_hours_per_month_by_cores=projection,
        projection_note="ideal: 1-worker rate x cores; projected: also x the measured 2-worker "
        "scaling efficiency (capped at 1), which on a shared machine is pessimistic",
    )  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
