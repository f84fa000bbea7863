"""Open a python-can bus from the ``bus:`` section of the configuration.

``interface`` is any python-can interface name (``socketcan``, ``virtual``, ``udp_multicast``,
``pcan``, ``kvaser``, ...); ``channel`` and ``bitrate`` are passed on, and any other key of the
mapping goes to the interface as a keyword argument.

``udp_multicast`` sends every frame to the whole multicast group, its sender included: the bus
returned for it drops the process's own frames (python-can cannot, ``receive_own_messages`` is
unsupported there), so a canopen node never reads back its own SDO requests or PDOs.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

import can

from agf.errors import ConfigError

# channel defaults where python-can has none that works out of the box
_DEFAULT_CHANNEL = {"virtual": "agf", "socketcan": "can0"}
_BITRATES = (10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)
_ECHO_WINDOW_S = 2.0  # an own frame not echoed back within this time is forgotten


def open_bus(mapping: Any, where: str) -> can.BusABC:
    """Open the python-can bus the mapping describes.

    Parameters
    ----------
    mapping : mapping
        ``{interface: str, channel: str|int (optional), bitrate: int (optional), <interface kwargs>}``.
    where : str
        Where the mapping comes from (``"agf.yaml: bus"``), the prefix of every error.

    Raises
    ------
    ConfigError
        Unknown interface, bad channel or bitrate, or the interface could not be opened.
    """
    if not isinstance(mapping, Mapping):
        raise ConfigError(f"{where}: expected a mapping with an 'interface' key, got {type(mapping).__name__}")
    options = dict(mapping)
    interface = options.pop("interface", None)
    if not isinstance(interface, str) or not interface:
        raise ConfigError(f"{where}.interface: expected a python-can interface name, e.g. 'socketcan'")
    if interface not in can.interfaces.VALID_INTERFACES:
        raise ConfigError(
            f"{where}.interface: unknown python-can interface {interface!r}; "
            f"expected one of {sorted(can.interfaces.VALID_INTERFACES)}"
        )
    channel = options.pop("channel", _DEFAULT_CHANNEL.get(interface))
    if channel is not None and (isinstance(channel, bool) or not isinstance(channel, str | int)):
        raise ConfigError(f"{where}.channel: expected a string or an integer, got {channel!r}")
    bitrate = options.pop("bitrate", None)
    if bitrate is not None:
        if isinstance(bitrate, bool) or not isinstance(bitrate, int) or bitrate not in _BITRATES:
            raise ConfigError(f"{where}.bitrate: expected one of {list(_BITRATES)} bit/s, got {bitrate!r}")
        if interface not in ("virtual", "udp_multicast", "socketcan"):  # those ignore or refuse it
            options["bitrate"] = bitrate
    if interface == "udp_multicast":
        options.setdefault("fd", False)  # classic CAN frames, as on the truck
    if channel is not None:
        options["channel"] = channel
    try:
        bus = can.Bus(interface=interface, **options)
    except (can.CanError, OSError, ImportError, TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: cannot open {interface} bus on channel {channel!r}: {exc}") from exc
    return OwnEchoFilter(bus) if interface == "udp_multicast" else bus


def handle_waiting(bus: can.BusABC, listeners: Sequence[can.Listener]) -> bool:
    """Hand every frame waiting on ``bus`` (python-can's virtual bus) to ``listeners`` in this thread, as a
    notifier thread would; whether there was none. A simulated clock's settling reads its buses so
    (:class:`drivers.cia402_axis.ClockedNetwork`)."""
    if not bus.queue.qsize():  # asked a few times an event, mostly idle
        return True
    while (msg := bus.recv(0)) is not None:
        for listener in listeners:
            listener.on_message_received(msg)
    return False


class OwnEchoFilter(can.BusABC):
    """A bus that drops the frames it sent itself when the medium echoes them back (udp_multicast).

    Frames are matched by identifier and data, first in first out, within a short window, so a
    frame with the same content from another process is still delivered once ours has come back.
    """

    def __init__(self, bus: can.BusABC) -> None:
        self._bus = bus
        self._sent: collections.deque[tuple[float, int, bytes]] = collections.deque()
        self._sent_lock = threading.Lock()
        super().__init__(channel=bus.channel_info)
        self.channel_info = f"{bus.channel_info} (own frames filtered)"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        with self._sent_lock:
            self._sent.append((time.monotonic(), msg.arbitration_id, bytes(msg.data)))
        self._bus.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:  # skip our own echoes within the caller's timeout
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            msg = self._bus.recv(remaining)
            if msg is None or not self._is_own(msg):
                return msg, False

    def _is_own(self, msg: can.Message) -> bool:
        key = (msg.arbitration_id, bytes(msg.data))
        now = time.monotonic()
        with self._sent_lock:
            while self._sent and now - self._sent[0][0] > _ECHO_WINDOW_S:
                self._sent.popleft()
            for i, (_, can_id, data) in enumerate(self._sent):
                if (can_id, data) == key:
                    del self._sent[i]
                    return True
        return False

    def fileno(self) -> int:
        return self._bus.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._bus.shutdown()
