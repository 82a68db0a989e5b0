"""Adversarial bridge input: replayed and stale frames, resets, wrap, a stuck line, the link path
of ``emulate --link``.
"""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path

import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thruster_fdd.core.bridge.kiss import KissDecoder, KissFrame, encode_kiss
from thruster_fdd.core.bridge.link import ERROR, WARN, LinkWindow, assess_link
from thruster_fdd.core.bridge.sequence import SequenceWindow
from thruster_fdd.core.bridge.stuck import STUCK_RUN_BYTES, StuckRun
from thruster_fdd.core.bridge.tfdd import (
    FrameDecoder,
    StatusFlag,
    TelemetryFrame,
    encode_telemetry,
)
from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.core.bridge.emulator import (
    BridgeEmulator,
    BridgeReset,
    EmulatorSettings,
    ReplayFrames,
    StuckLine,
)
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _published(window: SequenceWindow, seqs: list[int]) -> list[int]:
    return [s for s in seqs if window.check(s).publish]


# ----------------------------------------------------------------------------- sequence window


def test_a_replayed_frame_is_published_once() -> None:
    """Frames 0-9, then 5-9 again, then an old 3: each frame is published once, no repeat."""
    window = SequenceWindow()
    seqs = list(range(10)) + list(range(5, 10)) + [3]
    assert _published(window, seqs) == list(range(10))
    counts = window.counts()
    assert (counts.accepted, counts.replayed, counts.duplicates) == (10, 5, 1)


def test_wrap_is_progress_and_a_replay_across_the_wrap_is_dropped() -> None:
    window = SequenceWindow()
    seqs = [65530 + i for i in range(6)] + list(range(5)) + [65534, 65535, 0, 2]
    assert _published(window, seqs) == [65530, 65531, 65532, 65533, 65534, 65535, 0, 1, 2, 3, 4]
    assert window.counts().replayed == 4


def test_lost_frames_are_counted_and_published_frames_continue() -> None:
    window = SequenceWindow()
    decisions = [window.check(s) for s in (10, 11, 15, 16)]
    assert [d.verdict for d in decisions] == ["ok", "ok", "lost", "ok"]
    assert decisions[2].lost == 3
    assert window.counts().lost == 3


def test_reset_flag_reanchors_and_a_replayed_reset_frame_is_dropped() -> None:
    window = SequenceWindow()
    first = window.check(0, reset=True, bridge_time_us=120)
    assert first.verdict == "reset"
    assert window.counts().resets == 0
    assert _published(window, list(range(1, 100))) == list(range(1, 100))
    after = window.check(0, reset=True, bridge_time_us=95)
    assert after.publish
    assert after.verdict == "reset"
    assert _published(window, [1, 2, 3]) == [1, 2, 3]
    assert window.counts().resets == 1
    assert not window.check(0, reset=True, bridge_time_us=95).publish  # the same RESET frame again
    assert _published(window, [4]) == [4]


def test_restart_without_reset_flag_reanchors_after_confirmation() -> None:
    window = SequenceWindow(window=1024, confirm=8)
    _published(window, list(range(5000, 5100)))
    got = _published(window, list(range(0, 20)))
    assert got == list(range(7, 20))  # 7 frames wait for confirmation, then the new numbering
    assert window.counts().resyncs == 1


def test_an_isolated_old_frame_beyond_the_window_is_not_taken() -> None:
    window = SequenceWindow(window=100, confirm=4)
    _published(window, list(range(1000, 1200)))
    assert _published(window, [500, 700, 900, 1200, 1201]) == [1200, 1201]


def test_window_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="window"):
        SequenceWindow(window=0)
    with pytest.raises(ValueError, match="confirm"):
        SequenceWindow(confirm=1)
    with pytest.raises(ValueError, match="seq"):
        SequenceWindow().check(65536)


@FAST
@given(
    start=st.integers(0, 65535),
    n=st.integers(1, 300),
    replays=st.lists(st.tuples(st.integers(0, 299), st.integers(0, 40)), max_size=30),
)
def test_any_replay_within_the_window_publishes_each_frame_once_in_order(
    start: int, n: int, replays: list[tuple[int, int]]
) -> None:
    """A stream of n frames where, after frame i, the bridge re-sends up to ``back`` older
    frames (within the window): exactly the original frames come out, in order."""
    original = [(start + i) % 65536 for i in range(n)]
    after: dict[int, list[int]] = {}
    for at, back in replays:
        if at < n:
            after.setdefault(at, []).extend(original[max(0, at - back) : at + 1])
    arrivals = []
    for i, seq in enumerate(original):
        arrivals.append(seq)
        arrivals.extend(after.get(i, []))
    window = SequenceWindow()
    assert _published(window, arrivals) == original
    counts = window.counts()
    assert counts.duplicates + counts.replayed == len(arrivals) - n


# ----------------------------------------------------------------------------- stuck line


def test_kiss_line_stuck_low_is_never_telemetry() -> None:
    """1000 zero bytes gave 100 messages of 0 V / 0 A / 0 rpm (the CRC-8 of ten zeros is 0)."""
    decoder = KissDecoder()
    assert decoder.feed(bytes(1000)) == []
    stats = decoder.stats()
    assert (stats.frames_ok, stats.stuck_low_bytes) == (0, 1000)
    assert decoder.feed(b"\xff" * 500) == []
    assert decoder.stats().stuck_high_bytes == 500


def test_kiss_frames_around_a_stuck_stretch_still_decode() -> None:
    frame = KissFrame(12.0, 15.0, 3.2, 40, 2100.0)
    data = encode_kiss(frame) * 3 + bytes(300) + encode_kiss(frame) * 3
    assert len(KissDecoder().feed(data)) == 6


def test_tfdd_stuck_line_is_counted_not_decoded() -> None:
    decoder = FrameDecoder()
    frame = encode_telemetry(TelemetryFrame(1, 1500, 15.0, 0.0, 0.0, 20.0, 0), 1)
    out = decoder.feed(frame + bytes(2000) + b"\xff" * 2000 + frame)
    assert len(out) == 2
    stats = decoder.stats()
    assert (stats.stuck_low_bytes, stats.stuck_high_bytes) == (2000, 2000)


@FAST
@given(
    pieces=st.lists(
        st.one_of(
            st.binary(max_size=30),
            st.integers(1, 60).map(bytes),
            st.integers(1, 60).map(lambda n: b"\xff" * n),
        ),
        max_size=20,
    ),
    cuts=st.lists(st.integers(0, 2000), max_size=10),
)
def test_stuck_run_counts_do_not_depend_on_chunking(pieces: list[bytes], cuts: list[int]) -> None:
    data = b"".join(pieces)
    low = sum(n for n in _run_lengths(data, 0) if n >= STUCK_RUN_BYTES)
    high = sum(n for n in _run_lengths(data, 0xFF) if n >= STUCK_RUN_BYTES)
    run = StuckRun()
    bounds = sorted({0, len(data), *(c for c in cuts if c < len(data))})
    for a, b in itertools.pairwise(bounds):
        run.feed(data[a:b])
    assert (run.low_bytes, run.high_bytes) == (low, high)


def _run_lengths(data: bytes, byte: int) -> list[int]:
    """Lengths of the runs of ``byte`` in ``data`` (the reference, byte by byte)."""
    runs, current = [], 0
    for b in data:
        if b == byte:
            current += 1
        elif current:
            runs.append(current)
            current = 0
    if current:
        runs.append(current)
    return runs


def test_stuck_line_without_telemetry_is_a_link_error() -> None:
    window = LinkWindow(1.0, 50.0, True, stuck_low_bytes=11_520, since_frame_s=3.0)
    health = assess_link(window)
    assert health.level == ERROR
    assert "stuck low" in health.message
    between = assess_link(
        LinkWindow(1.0, 50.0, True, frames=50, stuck_high_bytes=40, since_frame_s=0.0)
    )
    assert between.level == WARN
    assert "stuck high" in between.message


@pytest.mark.parametrize(
    ("field", "words"),
    [("replayed", "replayed"), ("resets", "bridge reset"), ("resyncs", "without RESET")],
)
def test_sequence_events_are_named_warnings(field: str, words: str) -> None:
    window = LinkWindow(1.0, 50.0, True, frames=50, since_frame_s=0.0, **{field: 3})
    health = assess_link(window)
    assert health.level == WARN
    assert words in health.message


# ----------------------------------------------------------------------------- emulator


def _emulator(link: Path) -> BridgeEmulator:
    sim = ThrusterSimulator(load_config("t100"), "nominal_15v", seed=2)
    return BridgeEmulator(sim, link, EmulatorSettings(rate_hz=100.0))


def test_emulate_link_never_replaces_a_regular_file(tmp_path: Path) -> None:
    victim = tmp_path / "notes.txt"
    victim.write_text("precious")
    with pytest.raises(BadInputError, match="not a symlink"):
        _emulator(victim).open()
    assert victim.read_text() == "precious"
    folder = tmp_path / "folder"
    folder.mkdir()
    with pytest.raises(BadInputError):
        _emulator(folder).open()
    assert folder.is_dir()


def test_closing_leaves_a_link_that_points_elsewhere(tmp_path: Path) -> None:
    link = tmp_path / "t0.tty"
    emulator = _emulator(link)
    emulator.open()
    link.unlink()
    link.symlink_to("/dev/null")  # someone else's link now
    emulator.close()
    assert link.is_symlink()


def test_emulator_replays_resets_and_sticks_on_the_wire(tmp_path: Path) -> None:
    """The faults the driver's tests inject show on the wire as specified, and the sequence
    window publishes each frame once through them."""
    emulator = _emulator(tmp_path / "t0.tty")
    emulator.open()
    stop = threading.Event()
    thread = threading.Thread(target=emulator.run, args=(stop,), daemon=True)
    thread.start()
    decoder, frames = FrameDecoder(), []
    port = serial.Serial(str(emulator.link), 115200, timeout=0.05)

    def read(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            frames.extend(decoder.feed(port.read(4096)))

    try:
        read(0.3)
        emulator.inject(ReplayFrames(back=5, count=5))
        read(0.3)
        emulator.inject(StuckLine(0x00, 0.3))
        read(0.6)
        emulator.inject(BridgeReset())
        read(0.3)
    finally:
        port.close()
        stop.set()
        thread.join(timeout=5)
    seqs = [f.seq for f in frames]
    assert len(seqs) > len(set(seqs)), "no frame was replayed"
    assert decoder.stats().stuck_low_bytes > 2000
    # The first frame (RESET, sequence 0) may go before the port is open; the injected one not.
    resets = [i for i, f in enumerate(frames) if f.message.status & StatusFlag.RESET]
    assert resets
    assert frames[resets[-1]].seq == 0
    assert frames[resets[-1]].message.timestamp_us < 100_000
    window = SequenceWindow()
    published = [
        f.seq
        for f in frames
        if window.check(
            f.seq, bool(f.message.status & StatusFlag.RESET), f.message.timestamp_us
        ).publish
    ]
    before, after = published[: published.index(0, 1)], published[published.index(0, 1) :]
    assert before == sorted(set(before))
    assert after == list(range(len(after)))
    assert window.counts().resets == 1
