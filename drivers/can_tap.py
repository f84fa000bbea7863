"""A passive listener on the CAN bus that hands every frame to a pick's recorder (``candump`` into the log).

It opens its own connection to the bus the configuration names, so it sees the frames of the master
and of every drive alike (python-can's virtual bus and udp_multicast deliver each frame to every
other connection, SocketCAN loops frames back to every socket on the interface), and it sends nothing.
"""

from __future__ import annotations

from typing import Any

import can

from agf.clock import Clock, Periodic, SimulatedClock
from agf.recorder import Recorder
from drivers.can_bus import handle_waiting, open_bus


class _ToRecorder(can.Listener):
    def __init__(self, recorder: Recorder) -> None:
        self.recorder = recorder

    def on_message_received(self, msg: can.Message) -> None:
        self.recorder.can_frame(msg.timestamp, msg.arbitration_id, bytes(msg.data), extended=msg.is_extended_id,
                                remote=msg.is_remote_frame, error=msg.is_error_frame)


class CanTap:
    """Records the bus into ``recorder`` from construction until :meth:`close`; a context manager.

    Parameters
    ----------
    bus_mapping : mapping
        The ``bus:`` section of the configuration (see :func:`drivers.can_bus.open_bus`).
    where : str
        Where the mapping comes from, for errors.
    recorder : Recorder
        Receives every frame with its receive timestamp.
    clock : Clock, optional
        The time of the nodes on the bus. On a simulated clock (a virtual bus) the frames are recorded as
        the clock settles, in its thread, as its nodes handle theirs; otherwise by a notifier thread.
    """

    def __init__(self, bus_mapping: Any, where: str, recorder: Recorder, clock: Clock | None = None) -> None:
        self.bus = open_bus(bus_mapping, where)
        listeners = [_ToRecorder(recorder)]
        self.notifier: can.Notifier | None = None
        self._settler: Periodic | None = None
        if isinstance(clock, SimulatedClock):
            self._settler = clock.add_settler(lambda: handle_waiting(self.bus, listeners))
        else:
            self.notifier = can.Notifier(self.bus, listeners, timeout=0.1)

    def close(self) -> None:
        if self._settler is not None:
            self._settler.cancel()
        if self.notifier is not None:
            self.notifier.stop()
        self.bus.shutdown()

    def __enter__(self) -> CanTap:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
