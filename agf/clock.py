"""Time for the control loop: wall-clock time on a truck, simulated time in the simulated world.

Everything that measures or waits for time in the control path (the controller's motion timeouts,
the CANopen master's SYNC and heartbeat producers and its heartbeat watchdog, the simulated drives'
heartbeat, supervision and motion) reads one injected :class:`Clock`:

* :class:`WallClock` is the truck's time (``agf run``, hardware in the loop): periodic work runs on
  threads (or python-can's own periodic sender), waits block for real.
* :class:`SimulatedClock` is a discrete-event clock. Time stands still until the one thread that
  drives it (the controller's) sleeps or waits; it then jumps from one scheduled event to the next,
  running each event (a SYNC, a heartbeat, a watchdog check) in that thread. Before and after each
  event, and when work starts outside one, it lets the world settle: its settlers do, or wait for,
  the work an event started (the CAN frames it sent handled by every node). The simulated world thus runs the same
  setpoints, drive physics and CAN messages as on the wall clock, as fast as the CPU allows, and
  nothing it does depends on wall time, so CPU load cannot fault a simulated pick. Rendering and
  measuring take no simulated time: the world stands still while the vision works.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Protocol


class Periodic(Protocol):
    """A periodic activity started by :meth:`Clock.every`."""

    def cancel(self) -> None:
        """Stop it; an activity already running finishes."""


class Clock(ABC):
    """Monotonic time (s), sleeping, waiting for an event, and periodic work.

    ``realtime`` is True when the clock is the wall clock: periodic CAN messages may then be sent by
    the bus's own scheduler (a kernel one on SocketCAN), which keeps better time than a thread.
    """

    realtime: bool

    @abstractmethod
    def monotonic(self) -> float:
        """Seconds since an arbitrary origin; never goes backwards."""

    @abstractmethod
    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass (a simulated clock runs the events due meanwhile)."""

    @abstractmethod
    def wait(self, event: threading.Event, timeout: float) -> bool:
        """Wait until ``event`` is set or ``timeout`` seconds have passed; whether it was set."""

    @abstractmethod
    def every(self, period: float, callback: Callable[[], None], name: str = "periodic") -> Periodic:
        """Call ``callback()`` every ``period`` seconds, the first time one period from now."""

    @abstractmethod
    def compute_seconds(self) -> float:
        """A reading (s) whose differences time the controller's own computing (the vision), which
        takes no time on a simulated clock but must still be bounded."""


class _Thread:
    """A daemon thread calling a function every period of wall time until cancelled."""

    def __init__(self, period: float, callback: Callable[[], None], name: str) -> None:
        self._stop = threading.Event()
        self._period, self._callback = period, callback
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            self._callback()

    def cancel(self) -> None:
        self._stop.set()
        if self.thread is not threading.current_thread():
            self.thread.join(timeout=max(1.0, 2 * self._period))


class WallClock(Clock):
    """The real time of the machine (``time.monotonic``)."""

    realtime = True

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(seconds, 0.0))

    def wait(self, event: threading.Event, timeout: float) -> bool:
        return event.wait(max(timeout, 0.0))

    def every(self, period: float, callback: Callable[[], None], name: str = "periodic") -> Periodic:
        _check_period(period)
        return _Thread(period, callback, name)

    def compute_seconds(self) -> float:
        """Wall time: a truck's deadlines are real."""
        return time.perf_counter()


class _Settler:
    """A function a :class:`SimulatedClock` calls to let the world settle, until cancelled."""

    def __init__(self, settlers: list[_Settler], settle: Callable[[], bool]) -> None:
        self._settlers, self.settle = settlers, settle

    def cancel(self) -> None:
        if self in self._settlers:
            self._settlers.remove(self)


class _Event:
    """One periodic activity of a :class:`SimulatedClock`; its n-th run is due at ``start + n * period``
    (integer nanoseconds, so events of different periods due together are equally due)."""

    def __init__(self, start: int, period: int, callback: Callable[[], None], order: int) -> None:
        self.start, self.period, self.callback, self.order = start, period, callback, order
        self.runs = 0
        self.cancelled = False

    @property
    def due(self) -> int:
        return self.start + (self.runs + 1) * self.period

    def cancel(self) -> None:
        self.cancelled = True


class SimulatedClock(Clock):
    """Discrete-event time: it advances only when its driving thread sleeps or waits.

    Events run in the order they are due (at equal times, in the order they were scheduled), in
    the thread that advanced the clock. Only one thread may advance it; any thread may read it or
    schedule events. An event must not advance the clock itself.

    Parameters
    ----------
    start : float
        The clock's reading at creation, s.
    """

    realtime = False

    def __init__(self, start: float = 0.0) -> None:
        self._now = _ns(start)
        self._queue: list[tuple[int, int, _Event]] = []
        self._order = itertools.count()
        self._lock = threading.Lock()
        self._driver: threading.Thread | None = None
        self._settlers: list[_Settler] = []
        self._settle_lock = threading.Lock()
        self._settling: threading.Thread | None = None  # the thread calling the settlers

    def monotonic(self) -> float:
        return self._now / 1e9

    def every(self, period: float, callback: Callable[[], None], name: str = "periodic") -> Periodic:
        _check_period(period)
        with self._lock:
            event = _Event(self._now, max(_ns(period), 1), callback, next(self._order))
            heapq.heappush(self._queue, (event.due, event.order, event))
        return event

    def compute_seconds(self) -> float:
        """The process's CPU time: a machine busy with other work cannot time a simulated pick out."""
        return time.process_time()

    def add_settler(self, settle: Callable[[], bool]) -> Periodic:
        """Call ``settle()`` before and after every event until it is cancelled.

        ``settle`` does the work started meanwhile (or waits until other threads have done it), and
        returns whether there was none; the settlers are called again until none of them had any. Only
        one thread settles at a time.
        """
        settler = _Settler(self._settlers, settle)
        with self._lock:
            self._settlers.append(settler)
        return settler

    def settle(self) -> None:
        """Let the world settle now, between events: after work started outside them (a CAN frame the
        controller sends between two waits, an SDO request whose answer it waits for).

        Does nothing while a thread drives the clock, or from within a settler: the settling the
        driver or that settler is part of handles the new work before time moves on.
        """
        if self._driver is None:
            self._settle()

    def sleep(self, seconds: float) -> None:
        self._advance(self._now + _ns(max(seconds, 0.0)), None)

    def wait(self, event: threading.Event, timeout: float) -> bool:
        return self._advance(self._now + _ns(max(timeout, 0.0)), event)

    def _advance(self, until: int, event: threading.Event | None) -> bool:
        """Run the events due up to ``until`` (stopping early once ``event`` is set) and move there."""
        me = threading.current_thread()
        if self._driver is me:
            raise RuntimeError("a simulated-clock event must not sleep or wait on the clock it runs on")
        if self._driver is not None:
            raise RuntimeError(f"the simulated clock is already driven by thread {self._driver.name}")
        self._driver = me
        try:
            while event is None or not event.is_set():
                due = self._run_next(until)
                if due is None:
                    self._now = max(self._now, until)
                    break
            return event is not None and event.is_set()
        finally:
            self._driver = None

    def _run_next(self, until: int) -> int | None:
        """Run the next event due at or before ``until``; its time, or None if there is none."""
        self._settle()
        with self._lock:
            while self._queue and self._queue[0][2].cancelled:
                heapq.heappop(self._queue)
            if not self._queue or self._queue[0][0] > until:
                return None
            due, _, periodic = heapq.heappop(self._queue)
        self._now = max(self._now, due)
        periodic.callback()
        periodic.runs += 1
        self._settle()
        if not periodic.cancelled:
            with self._lock:
                heapq.heappush(self._queue, (periodic.due, periodic.order, periodic))
        return due

    def _settle(self) -> None:
        me = threading.current_thread()
        if self._settling is me:  # work a settler does started more: its loop below runs again
            return
        with self._settle_lock:
            self._settling = me
            try:
                while not all([settler.settle() for settler in list(self._settlers)]):
                    continue
            finally:
                self._settling = None


def _ns(seconds: float) -> int:
    return round(seconds * 1e9)


def _check_period(period: float) -> None:
    if not period > 0:
        raise ValueError(f"a periodic activity needs a positive period, got {period} s")
