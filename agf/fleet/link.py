"""The transport between the vehicle and its fleet manager (MQTT in ``drivers/mqtt_fleet.py``)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Protocol

from agf.config import BrokerConfig


class LinkListener(Protocol):
    """What a link calls: a message arrived on ``topic``, the link came up or went down."""

    def on_message(self, topic: str, payload: bytes) -> None: ...

    def on_link(self, up: bool) -> None: ...


class FleetLink(ABC):
    """One vehicle's connection to the fleet: subscribes ``prefix/order`` and ``prefix/instantActions``,
    publishes below ``prefix``, leaves ``will`` on ``prefix/connection`` when it breaks, and reconnects
    by itself with back-off.

    Parameters
    ----------
    broker : where and how to connect
    prefix : ``interface_name/v2/manufacturer/serial_number``
    listener : receives messages and link changes, on the link's own thread
    will : the ``connection`` message (CONNECTIONBROKEN) the broker publishes if the link breaks
    """

    def __init__(self, broker: BrokerConfig, prefix: str, listener: LinkListener, will: bytes) -> None:
        self.broker, self.prefix, self.listener, self.will = broker, prefix, listener, will

    @abstractmethod
    def start(self) -> None:
        """Connect in the background; ``listener.on_link(True)`` once connected and subscribed."""

    @abstractmethod
    def publish(self, topic: str, payload: bytes, qos: int, retain: bool) -> None:
        """Send ``payload`` on ``prefix/topic``; dropped while the link is down (a state follows on reconnect)."""

    @abstractmethod
    def close(self, farewell: bytes) -> None:
        """Publish ``farewell`` (OFFLINE) on ``connection``, then disconnect cleanly (no last will)."""
