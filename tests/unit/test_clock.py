"""The clocks of the control loop: wall time, and the simulated world's discrete-event time."""

from __future__ import annotations

import threading
import time

import pytest

from agf.clock import SimulatedClock, WallClock


def test_simulated_time_stands_still_until_its_driver_sleeps():
    clock = SimulatedClock(start=5.0)
    time.sleep(0.02)
    assert clock.monotonic() == 5.0
    clock.sleep(0.25)
    assert clock.monotonic() == pytest.approx(5.25)


def test_periodic_events_run_in_time_order_at_their_simulated_times():
    clock = SimulatedClock()
    runs = []
    clock.every(0.01, lambda: runs.append(("sync", round(clock.monotonic(), 9))))
    clock.every(0.025, lambda: runs.append(("heartbeat", round(clock.monotonic(), 9))))
    clock.sleep(0.05)
    assert runs == [
        ("sync", 0.01), ("sync", 0.02), ("heartbeat", 0.025), ("sync", 0.03), ("sync", 0.04),
        ("sync", 0.05), ("heartbeat", 0.05),
    ]


def test_a_cancelled_event_runs_no_more():
    clock = SimulatedClock()
    runs = []
    event = clock.every(0.01, lambda: runs.append(clock.monotonic()))
    clock.sleep(0.03)
    event.cancel()
    clock.sleep(0.1)
    assert len(runs) == 3


def test_wait_returns_at_the_event_that_sets_it_and_times_out_in_simulated_time():
    clock = SimulatedClock()
    ready = threading.Event()
    count = {"n": 0}

    def tick():
        count["n"] += 1
        if count["n"] == 7:
            ready.set()

    clock.every(0.01, tick)
    assert clock.wait(ready, timeout=1.0)
    assert clock.monotonic() == pytest.approx(0.07)
    never = threading.Event()
    start = time.perf_counter()
    assert not clock.wait(never, timeout=1000.0)  # a thousand simulated seconds, no wall time to speak of
    assert clock.monotonic() == pytest.approx(1000.07)
    assert time.perf_counter() - start < 30.0


def test_the_world_settles_after_each_event_before_time_moves_on():
    """A settler waits for work an event handed to another thread (a CAN frame to another node)."""
    clock = SimulatedClock()
    handled, seen = [], []
    inbox: list[float | None] = []
    done = threading.Condition()

    def worker():
        while True:
            with done:
                done.wait_for(lambda: inbox)
                stamp = inbox.pop()
            if stamp is None:
                return
            time.sleep(0.005)  # slower than the clock would go
            with done:
                handled.append(clock.monotonic())  # still the time it was sent at: the clock waited
                done.notify_all()

    def settle() -> bool:
        with done:
            idle = len(handled) == len(seen)
            done.wait_for(lambda: len(handled) == len(seen), 5.0)
        return idle

    def send():
        seen.append(clock.monotonic())
        with done:
            inbox.append(clock.monotonic())
            done.notify_all()

    thread = threading.Thread(target=worker, daemon=True)
    thread.start()
    clock.add_settler(settle)
    clock.every(0.01, send)
    clock.sleep(0.1)
    assert handled == pytest.approx([0.01 * k for k in range(1, 11)])
    with done:
        inbox.append(None)
        done.notify_all()
    thread.join(1.0)


def test_an_event_cannot_advance_its_own_clock():
    clock = SimulatedClock()
    failures = []

    def nested():
        try:
            clock.sleep(0.01)
        except RuntimeError as exc:
            failures.append(str(exc))

    clock.every(0.01, nested)
    clock.sleep(0.01)
    assert failures and "must not sleep" in failures[0]


def test_periods_must_be_positive():
    with pytest.raises(ValueError, match="positive period"):
        SimulatedClock().every(0.0, lambda: None)
    with pytest.raises(ValueError, match="positive period"):
        WallClock().every(-1.0, lambda: None)


def test_wall_clock_periodic_work_runs_on_its_own_thread_until_cancelled():
    clock = WallClock()
    ticks = threading.Semaphore(0)
    periodic = clock.every(0.005, ticks.release)
    assert all(ticks.acquire(timeout=5.0) for _ in range(3))
    periodic.cancel()
    while ticks.acquire(timeout=0.05):  # drain what ran before the cancel took effect
        continue
    assert not ticks.acquire(timeout=0.05)
    event = threading.Event()
    threading.Timer(0.01, event.set).start()
    assert clock.wait(event, timeout=5.0)
    assert not clock.wait(threading.Event(), timeout=0.01)


def test_simulated_compute_time_counts_work_not_waiting():
    clock = SimulatedClock()
    start = clock.compute_seconds()
    time.sleep(0.3)  # a busy machine delays us: that is not the vision's compute time
    assert clock.compute_seconds() - start < 0.2
    start = clock.compute_seconds()
    deadline = time.perf_counter() + 0.3
    while time.perf_counter() < deadline:
        continue
    assert clock.compute_seconds() - start > 0.0
    wall = WallClock()
    start = wall.compute_seconds()
    time.sleep(0.05)
    assert wall.compute_seconds() - start >= 0.05
