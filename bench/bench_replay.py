"""Benchmark: replay speed of the committed bags through the real model nodes.

Runs ``thruster-fdd replay BAG --json`` ``--runs`` times per bag (each run starts its own
``nominal_model`` and ``classifier``; start-up is not timed) and prints the median, min and max
real-time factor per bag and over all runs.

Usage (after ``. scripts/bootstrap.sh``): ``python bench/bench_replay.py [--runs 3] [BAG ...]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import tempfile
from pathlib import Path

from results_file import Run, add_results_option


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bags", nargs="*", type=Path, help="default: every bags/*.mcap")
    parser.add_argument("--runs", type=int, default=3, help="replays per bag")
    add_results_option(parser)
    args = parser.parse_args()
    run = Run("bench_replay")
    bags = args.bags or sorted(Path("bags").glob("*.mcap"))
    if not bags:
        raise SystemExit("no bags given and none in bags/")
    every: list[float] = []
    failures = 0
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "replay.json"
        for bag in bags:
            speeds = []
            for _ in range(args.runs):
                out.unlink(missing_ok=True)
                done = subprocess.run(
                    ["thruster-fdd", "replay", str(bag), "--json", str(out)],
                    capture_output=True,
                    text=True,
                    timeout=300,
                )
                if done.returncode != 0:
                    failures += 1
                    print(f"{bag.name}: replay failed (exit {done.returncode}):\n{done.stdout}")
                    print(done.stderr[-2000:])
                if out.is_file():
                    speeds.append(json.loads(out.read_text())["speedup"])
            every += speeds
            print(
                f"{bag.name:36s} median {statistics.median(speeds):5.0f}x real time "
                f"(min {min(speeds):.0f}, max {max(speeds):.0f}; {args.runs} runs)"
            )
    print(
        f"{'all bags':36s} median {statistics.median(every):5.0f}x (min {min(every):.0f}); "
        f"{failures} failed replays"
    )
    run.add(f"replay real-time factor over {len(bags)} bags", "x", statistics.median(every),
            min=min(every), max=max(every), runs=len(every), failed=failures)  # fmt: skip
    run.write(args.results)


if __name__ == "__main__":
    main()
