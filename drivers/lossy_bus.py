"""A python-can bus that misbehaves on purpose: lost, corrupted and foreign frames, a pulled adapter.

:class:`LossyBus` wraps the master's connection to the bus (as python-can's ``BusABC`` intends, it
overrides ``send`` and ``_recv_internal`` only), so what it does is what the master would see on a
bad cable: frames it sends that never arrive, frames from the drives that never reach it, frames it
did not expect, and an adapter that is gone. The fault tests (``tests/integration/test_faults*.py``)
and ``agf bench``'s ``faults.reaction_ms`` put it between the master and the simulated drives; on a
hardware-in-the-loop bench the same wrapper sits in front of a real adapter.

Every decision is drawn from one seeded generator, so a run with the same seed loses the same frames.
"""

from __future__ import annotations

import collections
import random
import threading
import time
from collections.abc import Callable, Iterable

import can

Mangle = Callable[[can.Message], can.Message | None]


class LossyBus(can.BusABC):
    """A bus in front of ``bus`` that loses, mangles or injects frames, or fails like an unplugged adapter.

    Parameters
    ----------
    bus : can.BusABC
        The real connection; shut down with this one.
    loss : float
        Probability (0..1) that a frame, sent or received, is lost.
    seed : int
        Seed of the generator that decides which frames are lost.
    """

    def __init__(self, bus: can.BusABC, *, loss: float = 0.0, seed: int = 0) -> None:
        self._bus = bus
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._injected: collections.deque[can.Message] = collections.deque()
        self._burst_until = 0.0
        self._mangle: Mangle | None = None
        self.loss = 0.0
        self.set_loss(loss)
        self.unplugged = False
        self.sent = self.received = self.lost = 0
        super().__init__(channel=bus.channel_info)
        self.channel_info = f"{bus.channel_info} (lossy)"

    # -- what a test does to the bus ------------------------------------------------------------------
    def set_loss(self, probability: float) -> None:
        """Lose each frame, in both directions, with this probability from now on."""
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"loss probability must be within 0..1, got {probability}")
        self.loss = probability

    def burst(self, seconds: float) -> None:
        """Lose every frame, both ways, for the next ``seconds`` s (a loose connector)."""
        self._burst_until = time.monotonic() + seconds

    def mangle(self, function: Mangle | None) -> None:
        """Pass every received frame through ``function`` (None drops the frame); None stops it."""
        self._mangle = function

    def inject(self, messages: Iterable[can.Message]) -> None:
        """Frames the master will receive next, as if another node had sent them."""
        with self._lock:
            self._injected.extend(messages)

    def unplug(self) -> None:
        """The adapter is gone: every send raises, nothing is received any more."""
        self.unplugged = True

    # -- BusABC ---------------------------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.unplugged:
            raise can.CanOperationError(f"{self._bus.channel_info}: CAN adapter unplugged (send failed)")
        self.sent += 1
        if self._lose():
            return
        self._bus.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            with self._lock:
                if self._injected:
                    return self._injected.popleft(), False
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            msg = self._bus.recv(min(remaining, 0.01) if remaining is not None else 0.01)
            if msg is None or self.unplugged:
                if deadline is not None and time.monotonic() >= deadline:
                    return None, False
                continue
            self.received += 1
            if self._lose():
                continue
            mangle = self._mangle
            msg = mangle(msg) if mangle is not None else msg
            if msg is not None:
                return msg, False

    def _lose(self) -> bool:
        with self._lock:
            lost = time.monotonic() < self._burst_until or (self.loss > 0 and self._rng.random() < self.loss)
        self.lost += lost
        return lost

    def fileno(self) -> int:
        return -1  # injected frames have no file descriptor: the notifier must poll recv()

    def shutdown(self) -> None:
        super().shutdown()
        self._bus.shutdown()


def truncate(cob_id: int, length: int) -> Mangle:
    """A :meth:`LossyBus.mangle` function: frames with ``cob_id`` arrive with only ``length`` data bytes."""

    def cut(msg: can.Message) -> can.Message:
        if msg.arbitration_id != cob_id:
            return msg
        return can.Message(arbitration_id=msg.arbitration_id, data=bytes(msg.data[:length]),
                           is_extended_id=msg.is_extended_id, timestamp=msg.timestamp)

    return cut


def scramble(cob_id: int, seed: int = 0) -> Mangle:
    """A :meth:`LossyBus.mangle` function: frames with ``cob_id`` arrive with their length but random data."""
    rng = random.Random(seed)

    def garble(msg: can.Message) -> can.Message:
        if msg.arbitration_id != cob_id:
            return msg
        return can.Message(arbitration_id=msg.arbitration_id, data=rng.randbytes(len(msg.data)),
                           is_extended_id=msg.is_extended_id, timestamp=msg.timestamp)

    return garble


def drop(cob_id: int) -> Mangle:
    """A :meth:`LossyBus.mangle` function: frames with ``cob_id`` never arrive, all others do."""
    return lambda msg: None if msg.arbitration_id == cob_id else msg


def flood(cob_ids: Iterable[int], count: int, seed: int = 0) -> list[can.Message]:
    """``count`` frames of random data (0..8 bytes) from COB-IDs no node of the bus uses."""
    rng = random.Random(seed)
    ids = list(cob_ids)
    return [can.Message(arbitration_id=rng.choice(ids), is_extended_id=False,
                        data=bytes(rng.randrange(256) for _ in range(rng.randrange(9)))) for _ in range(count)]
