"""The serial reader thread's periodic ticks (``core.bridge.ports``)."""

from __future__ import annotations

import itertools
import threading
import time

from thruster_fdd.core.bridge.ports import SerialPorts

PERIOD_S = 0.02


def _ticks_of_two_ports(run_s: float) -> tuple[list[float], list[float], SerialPorts]:
    ports = SerialPorts()
    times: tuple[list[float], list[float]] = ([], [])
    lock = threading.Lock()

    def recorder(out: list[float]):
        def tick() -> None:
            with lock:
                out.append(time.monotonic())

        return tick

    links = [ports.open("/nonexistent/port", 115200, 60.0, lambda d, t: None) for _ in times]
    for link, out in zip(links, times, strict=True):
        ports.start_ticks(link, PERIOD_S, recorder(out))
    time.sleep(run_s)
    for link in links:
        ports.stop_ticks(link)
    stopped = time.monotonic()
    time.sleep(5 * PERIOD_S)
    for link in links:
        ports.close(link)
    assert all(t <= stopped + 0.005 for out in times for t in out), "ticks after stop_ticks"
    return times[0], times[1], ports


def test_ports_of_one_period_tick_together_on_the_grid() -> None:
    first, second, _ = _ticks_of_two_ports(0.5)
    # 25 periods; a loaded machine may skip a few, never add any.
    assert 15 <= len(first) <= 26
    assert 15 <= len(second) <= 26
    common = set(round(t / PERIOD_S) for t in first) & set(round(t / PERIOD_S) for t in second)
    assert len(common) >= 0.8 * min(len(first), len(second)), "ports ticked in separate wakes"
    late = [t % PERIOD_S for t in first]
    assert sorted(late)[len(late) // 2] < 0.005, "ticks are not on whole periods"


def test_a_stalled_tick_is_skipped_not_made_up() -> None:
    ports = SerialPorts()
    times: list[float] = []

    def slow_tick() -> None:
        times.append(time.monotonic())
        if len(times) == 3:
            time.sleep(10 * PERIOD_S)  # the reader thread stalls for ten periods

    link = ports.open("/nonexistent/port", 115200, 60.0, lambda d, t: None)
    ports.start_ticks(link, PERIOD_S, slow_tick)
    time.sleep(0.6)
    ports.stop_ticks(link)
    ports.close(link)
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert max(gaps) >= 9 * PERIOD_S
    assert min(gaps[3:]) > 0.5 * PERIOD_S, "missed ticks were made up in a burst"
