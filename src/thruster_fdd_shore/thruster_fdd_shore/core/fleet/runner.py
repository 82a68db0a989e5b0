"""Running scan tasks on Dask: a ``distributed.LocalCluster`` on this machine (loopback only, one
single-threaded worker process per core) or an existing cluster by its scheduler address.

One task per recording (its file is decoded once; its thrusters run one after another in the
task). A task that raises is retried (``retries``); a task on a worker that dies is rescheduled
by the scheduler on another worker, so a killed worker costs only the tasks it was running. A
task still failing after that is reported and not written: the next scan tries it again.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.core.fleet.archive import Recording, find_recordings, recording_digest
from thruster_fdd_shore.core.fleet.dataset import read_dataset, write_rows, write_scan_info
from thruster_fdd_shore.core.fleet.scan import ScanConfig, load_pair, scan_recording


def default_workers() -> int:
    """Worker processes of a local cluster: the cores this process may use."""
    return max(1, len(os.sched_getaffinity(0)))


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, n_workers: int | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: on ``scheduler`` (``tcp://HOST:PORT``) when given, else on a
    ``LocalCluster`` bound to 127.0.0.1 with ``n_workers`` processes (default: the cores) of
    one thread each and no dashboard. Both are closed on exit.

    Raises
    ------
    BadInputError
        If the scheduler cannot be reached.
    """
    import dask
    from distributed import Client, LocalCluster

    # A worker's task runs numpy/numba code: one thread each, no oversubscription.
    env = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": env}):
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout="20s")
            except (OSError, TimeoutError) as exc:
                raise BadInputError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
            with client:
                yield client
            return
        cluster = LocalCluster(
            n_workers=n_workers or default_workers(),
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        with cluster, Client(cluster) as client:
            yield client


@dataclass(frozen=True)
class ScanResult:
    """What a scan did.

    Attributes
    ----------
    found : int
        Recordings in the archive.
    skipped : int
        Already in the dataset (same digest, or same path, size and time).
    scanned : int
        Recordings scanned now (error rows included).
    rows : int
        Rows written.
    errors : tuple of str
        Recordings written as error rows (unreadable), relative paths.
    failed : tuple of (str, str)
        Tasks that failed even after retries (recording, reason); not written.
    samples : int
        Telemetry samples processed.
    seconds : float
        Wall time of the tasks, s.
    """

    found: int
    skipped: int
    scanned: int
    rows: int
    errors: tuple[str, ...] = ()
    failed: tuple[tuple[str, str], ...] = field(default_factory=tuple)
    samples: int = 0
    seconds: float = 0.0


def known(root: Path) -> tuple[set[str], set[tuple[str, int, int]]]:
    """Digests already in the dataset, and (recording, size, mtime) of its rows."""
    if not root.is_dir() or not any(root.rglob("*.parquet")):
        return set(), set()
    table = read_dataset(root, ["recording", "digest", "size_bytes", "mtime_ns"]).to_pydict()
    stats = set(zip(table["recording"], table["size_bytes"], table["mtime_ns"], strict=True))
    return set(table["digest"]), stats


def pending(recordings: Sequence[Recording], root: Path) -> tuple[list[tuple[Recording, str]], int]:
    """The recordings not yet in the dataset at ``root``, with their digests; how many were."""
    digests, stats = known(root)
    todo, seen = [], set()
    for rec in recordings:
        if (rec.relative, rec.size_bytes, rec.mtime_ns) in stats:
            continue
        digest = recording_digest(rec.path)
        if digest in digests or digest in seen:
            continue
        seen.add(digest)
        todo.append((rec, digest))
    return todo, len(recordings) - len(todo)


def plan_scan(archive: Path, out: Path) -> tuple[list[Recording], list[tuple[Recording, str]], int]:
    """The recordings of ``archive``, those of them to scan into ``out`` (with digests), and
    how many it holds already."""
    recordings = find_recordings(archive)
    tasks, skipped = pending(recordings, out)
    return recordings, tasks, skipped


def run_tasks(
    client: Any,
    tasks: Sequence[tuple[Recording, str]],
    config: ScanConfig,
    *,
    retries: int = 2,
    progress: bool = False,
    on_rows: Callable[[list[dict[str, Any]]], None] | None = None,
    on_done: Callable[[int], None] | None = None,
) -> tuple[list[dict[str, Any]], list[tuple[str, str]]]:
    """Run ``scan_recording`` on every task; rows of all tasks, and the failed ones.

    Parameters
    ----------
    client : distributed.Client
        Where the tasks run.
    tasks : sequence of (Recording, str)
        Recordings with their digests.
    config : ScanConfig
        Models and decision settings.
    retries : int
        Extra attempts of a task that raises.
    progress : bool
        Show a progress bar (tqdm, on stderr).
    on_rows : callable or None
        Called with each finished task's rows, as they come (the scan writes them).
    on_done : callable or None
        Called with the count of finished tasks after each one (tests kill a worker here).
    """
    from distributed import as_completed
    from tqdm import tqdm

    pair = load_pair(config.models).digest[:12]
    futures = {
        client.submit(
            scan_recording, rec, digest, config, key=f"fleet-{pair}-{digest[:20]}", retries=retries
        ): rec
        for rec, digest in tasks
    }
    rows: list[dict[str, Any]] = []
    failed: list[tuple[str, str]] = []
    bar = tqdm(total=len(futures), unit="rec", disable=not progress, desc="fleet scan")
    with bar:
        for done, future in enumerate(as_completed(futures), start=1):
            rec = futures[future]
            try:
                result = future.result()
            except Exception as exc:  # a task's failure is reported, not fatal
                failed.append((rec.relative, f"{type(exc).__name__}: {exc}"))
            else:
                rows.extend(result)
                if on_rows is not None:
                    on_rows(result)
            future.release()
            bar.update(1)
            if on_done is not None:
                on_done(done)
    return rows, failed


def scan_archive(
    archive: Path,
    out: Path,
    config: ScanConfig,
    client: Any,
    *,
    retries: int = 2,
    progress: bool = False,
    batch_rows: int = 256,
    on_done: Callable[[int], None] | None = None,
    plan: tuple[list[Recording], list[tuple[Recording, str]], int] | None = None,
) -> ScanResult:
    """Scan every recording of ``archive`` not yet in the dataset ``out`` and append its rows.

    Rows are written in batches of about ``batch_rows`` as tasks finish, so an interrupted
    scan keeps what it finished and the next one goes on from there.

    Raises
    ------
    BadInputError
        If the archive holds no recording or the models do not load.
    """
    load_pair(config.models)  # refuse bad models before any task is sent
    recordings, tasks, skipped = plan or plan_scan(archive, out)
    if tasks and client is None:
        raise ValueError("scan_archive needs a client when there is something to scan")
    write_scan_info(
        out,
        {
            "archive": str(archive.absolute()),
            "models": str(Path(config.models).absolute()),
            "hop_s": config.hop_s,
            "hysteresis": config.hysteresis,
        },
    )
    tag = time.strftime("%Y%m%dT%H%M%S")
    buffer: list[dict[str, Any]] = []
    written = 0

    def flush() -> None:
        nonlocal written
        write_rows(out, buffer, tag)
        written += len(buffer)
        buffer.clear()

    def take(rows: list[dict[str, Any]]) -> None:
        buffer.extend(rows)
        if len(buffer) >= batch_rows:
            flush()

    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = []
    failed: list[tuple[str, str]] = []
    if tasks:
        rows, failed = run_tasks(
            client, tasks, config, retries=retries, progress=progress, on_rows=take,
            on_done=on_done,
        )  # fmt: skip
    flush()
    errors = tuple(sorted({r["recording"] for r in rows if r.get("error")}))
    return ScanResult(
        found=len(recordings),
        skipped=skipped,
        scanned=len(tasks) - len(failed),
        rows=written,
        errors=errors,
        failed=tuple(sorted(failed)),
        samples=sum(int(r.get("samples") or 0) for r in rows),
        seconds=time.perf_counter() - t0,
    )
