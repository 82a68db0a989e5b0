"""A bag written by a thread of its own: callers hand messages over and never wait for the disk.

:class:`BagWriter` owns a :class:`core.traces.recording.McapRecorder` and the only thread that
touches it. Publishers (the drivers' serial reader, the model stages, the executor) call
:meth:`BagWriter.write` with the CDR bytes they publish: an append to a bounded queue, no I/O.
The thread takes the queue every ``BATCH_S`` and flushes so that no message waits longer than
``flush_period_s`` from its hand-over to the disk (what a killed process can lose) and, when
the disk fails (full, folder removed or unwritable), drops the file, counts what it cannot
write as dropped, reports the error in :meth:`BagWriter.status` and tries again every
``retry_s`` (the bag's next file, or a bag folder when none could be made). No ROS here.
"""

from __future__ import annotations

import errno
import threading
import time
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from thruster_fdd.core.traces.recording import McapRecorder, RecordingPolicy

BATCH_S = 0.1
"""How often the writer thread takes the queue, s (at most half the flush period)."""

MAX_BAG_SUFFIX = 1000
"""Most bag folders of one prefix: ``<prefix>``, ``<prefix>_2``, ... ``<prefix>_1000``."""


def create_bag(
    output_dir: str | Path, prefix: str, policy: RecordingPolicy, metadata: dict[str, str]
) -> McapRecorder:
    """A recorder in a bag folder made here: ``<output_dir>/<prefix>``, or with ``_2``,
    ``_3``... when that folder exists (another recorder's bag, or one made by a recorder
    started in the same second with the same prefix).

    Raises
    ------
    OSError
        If no folder can be created (``MAX_BAG_SUFFIX`` names taken, or not writable).
    """
    base = Path(output_dir) / prefix
    for n in range(1, MAX_BAG_SUFFIX + 1):
        path = base if n == 1 else base.with_name(f"{base.name}_{n}")
        try:
            return McapRecorder(path, policy, metadata)
        except FileExistsError:
            if not path.parent.is_dir():
                raise  # output_dir is a file: no name will do
    raise FileExistsError(errno.EEXIST, f"{base} and {base.name}_2..{MAX_BAG_SUFFIX} exist")


@dataclass(frozen=True)
class WriterStatus:
    """What a :class:`BagWriter` has done so far.

    Attributes
    ----------
    bag_dir : str
        The bag folder being written, empty while none is open.
    files : tuple of str
        Its MCAP files so far.
    written, dropped : int
        Messages written, and messages lost (queue full, no usable file).
    queued : int
        Messages waiting for the thread now.
    error : str
        The last write failure, empty when writing works (a failure stays until one status
        with ``report=True`` carried it, even when the next file works).
    """

    bag_dir: str
    files: tuple[str, ...]
    written: int
    dropped: int
    queued: int
    error: str


class BagWriter:
    """Writes a rosbag2 MCAP bag from a thread of its own (see the module docstring).

    Parameters
    ----------
    output_dir, prefix : str or Path, str
        The bag folder is ``output_dir/prefix`` (``create_bag``).
    policy : RecordingPolicy
        Splitting, chunking, flushing, compression.
    metadata : dict of str to str
        The bag's custom data; read when a file starts, so the caller may add to it.
    max_queued : int
        Most messages waiting for the thread; past it a message is dropped, not waited for.
    retry_s : float
        Delay between attempts to open a bag after a failure, s.
    """

    def __init__(
        self,
        output_dir: str | Path,
        prefix: str,
        policy: RecordingPolicy,
        metadata: dict[str, str],
        *,
        max_queued: int = 100_000,
        retry_s: float = 1.0,
    ) -> None:
        self.output_dir = Path(output_dir)
        self._prefix = prefix
        # The file is flushed a batch early, so that a message waits at most flush_period_s
        # from its write() call to the disk: a kill -9 loses no more than that.
        self._policy = replace(
            policy, flush_period_s=max(policy.flush_period_s - BATCH_S, policy.flush_period_s / 2)
        )
        self._batch_s = min(BATCH_S, policy.flush_period_s / 2)
        self.metadata = metadata
        self._max_queued = max_queued
        self._retry_s = retry_s
        # Items: ("topic", name, type, offered QoS, type hash) or ("msg", name, type, data, ns).
        self._queue: deque[tuple[Any, ...]] = deque()
        self._wake = threading.Condition()
        self._stopping = False
        self._final: dict[str, str] = {}
        self._topics: dict[str, tuple[str, list[dict[str, Any]], str]] = {}
        self._recorder: McapRecorder | None = None
        self._retry_at = 0.0
        self._written = 0
        self._dropped = 0
        self._error = ""
        self._error_reported = True
        self._bag_dir = ""
        self._files: tuple[str, ...] = ()
        # The first attempt here: the bag folder (or why there is none) is known at once.
        self._open()
        self._thread = threading.Thread(target=self._run, name="bag-writer", daemon=True)
        self._thread.start()

    # ---- any thread ------------------------------------------------------------------------

    def add_topic(
        self, topic: str, type_name: str, offered_qos: list[dict[str, Any]], type_hash: str = ""
    ) -> None:
        """Declare ``topic`` (or take its publishers' QoS profiles and type hash anew)."""
        self._put(("topic", topic, type_name, offered_qos, type_hash), control=True)

    def write(self, topic: str, type_name: str, data: bytes, log_time_ns: int) -> None:
        """Queue one CDR message for writing; never blocks (dropped when the queue is full)."""
        self._put(("msg", topic, type_name, data, log_time_ns))

    def _put(self, item: tuple[Any, ...], control: bool = False) -> None:
        # No wake per message: the thread takes the queue every BATCH_S (a thread switch per
        # message would cost more than the write).
        if not control and len(self._queue) >= self._max_queued:
            self._dropped += 1
            return
        self._queue.append(item)

    def status(self, report: bool = False) -> WriterStatus:
        """What has been done so far; ``report``: the caller publishes it (an error shown once
        may then clear)."""
        status = WriterStatus(
            self._bag_dir, self._files, self._written, self._dropped, len(self._queue), self._error
        )
        if report and self._error:
            self._error_reported = True
        return status

    def close(self, final_metadata: dict[str, str] | None = None, timeout_s: float = 10.0) -> None:
        """Write what is queued, finish the bag (with ``final_metadata`` as its last record)
        and end the thread; waits at most ``timeout_s``."""
        with self._wake:
            self._final = dict(final_metadata or {})
            self._stopping = True
            self._wake.notify()
        self._thread.join(timeout_s)

    # ---- the writer thread -----------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._wake:
                if not self._stopping:
                    self._wake.wait(self._batch_s)
                stopping = self._stopping
            if self._recorder is None and time.monotonic() >= self._retry_at:
                self._open()
            while self._queue:
                self._handle(self._queue.popleft())
            if self._recorder is not None:
                try:
                    self._recorder.flush_if_due()
                except OSError as exc:
                    self._failed("writing", exc)
            if stopping:
                self._finish()
                return

    def _open(self) -> None:
        try:
            rec = create_bag(self.output_dir, self._prefix, self._policy, self.metadata)
            for topic, (type_name, offered, type_hash) in self._topics.items():
                rec.add_topic(topic, type_name, offered, type_hash)
        except OSError as exc:
            self._error = f"cannot record to {self.output_dir}: {exc.strerror or exc}"
            self._error_reported = False
            self._retry_at = time.monotonic() + self._retry_s
            return
        self._recorder = rec
        self._bag_dir = str(rec.bag_dir)
        self._files = ()

    def _handle(self, item: tuple[Any, ...]) -> None:
        kind, topic, type_name, payload, extra = item
        if kind == "topic":
            self._topics[topic] = (type_name, payload, extra)
            if self._recorder is not None:
                self._recorder.add_topic(topic, type_name, payload, extra)
            return
        rec = self._recorder
        if rec is None or (self._error and time.monotonic() < self._retry_at):
            self._dropped += 1
            return
        try:
            rec.write(topic, type_name, payload, extra)
        except OSError as exc:
            self._dropped += 1
            self._failed("writing", exc)
            return
        self._written += 1
        if len(rec.files) != len(self._files):
            self._files = tuple(str(f) for f in rec.files)
        if self._error and self._error_reported:
            self._error = ""

    def _failed(self, what: str, exc: OSError) -> None:
        # The file is unusable (full disk, vanished folder): drop it; the first message after
        # ``retry_s`` opens the bag's next file.
        self._error = f"{what} to {self.output_dir} failed: {exc.strerror or exc}"
        self._error_reported = False
        if self._recorder is not None:
            self._recorder.abandon()
        self._retry_at = time.monotonic() + self._retry_s

    def _finish(self) -> None:
        if self._recorder is None:
            return
        final = {**self.metadata, **self._final, "messages": str(self._recorder.messages_written)}
        try:
            self._recorder.close(final)
        except OSError as exc:
            self._error = f"could not finish {self._bag_dir}: {exc.strerror or exc}"
        self._files = tuple(str(f) for f in self._recorder.files)
        self._recorder = None
