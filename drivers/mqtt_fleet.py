"""The VDA 5050 transport over MQTT, on paho-mqtt (``plugins.fleet``).

paho's network thread does the work: it connects in the background, re-connects with exponential
back-off (``reconnect_min_s`` doubling up to ``reconnect_max_s``) and leaves the last will
(CONNECTIONBROKEN, QoS 1, retained) with the broker on every connect. Subscriptions are re-made on
every connect, since the session is clean. The password is read from the environment variable or
the file the config names, when the link starts.
"""

from __future__ import annotations

import os
import sys
from typing import Any

import paho.mqtt.client as mqtt

from agf.config import BrokerConfig
from agf.errors import ConfigError
from agf.fleet.link import FleetLink, LinkListener


def broker_password(broker: BrokerConfig) -> str | None:
    """The password from ``password_env`` or ``password_file`` (None when neither is set).

    Raises
    ------
    ConfigError
        The variable is unset or empty, or the file cannot be read.
    """
    if broker.password_env:
        value = os.environ.get(broker.password_env)
        if not value:
            raise ConfigError(f"fleet.broker.password_env: the environment variable {broker.password_env} is not set")
        return value
    if broker.password_file:
        try:
            return broker.password_file.read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise ConfigError(f"fleet.broker.password_file: cannot read {broker.password_file} ({exc})") from exc
    return None


class MqttFleetLink(FleetLink):
    """:class:`agf.fleet.link.FleetLink` on an MQTT broker (VDA 5050 section 6.2: QoS 0, connection QoS 1)."""

    def __init__(self, broker: BrokerConfig, prefix: str, listener: LinkListener, will: bytes) -> None:
        super().__init__(broker, prefix, listener, will)
        client_id = prefix.replace("/", "-")
        self._client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=True)
        self._client.will_set(f"{prefix}/connection", will, qos=1, retain=True)
        self._client.reconnect_delay_set(broker.reconnect_min, broker.reconnect_max)
        if broker.tls:
            self._client.tls_set(ca_certs=str(broker.ca_file) if broker.ca_file else None)
        if broker.username:
            self._client.username_pw_set(broker.username, broker_password(broker))
        self._client.on_connect = self._on_connect
        self._client.on_disconnect = self._on_disconnect
        self._client.on_message = self._on_message

    def start(self) -> None:
        self._client.connect_async(self.broker.host, self.broker.port, keepalive=round(self.broker.keepalive))
        self._client.loop_start()

    def publish(self, topic: str, payload: bytes, qos: int, retain: bool) -> None:
        self._client.publish(f"{self.prefix}/{topic}", payload, qos=qos, retain=retain)

    def close(self, farewell: bytes) -> None:
        if self._client.is_connected():
            info = self._client.publish(f"{self.prefix}/connection", farewell, qos=1, retain=True)
            info.wait_for_publish(timeout=2.0)
            self._client.disconnect()
        self._client.loop_stop()

    # -- paho callbacks (its network thread) -------------------------------------------------------
    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: Any, properties: Any) -> None:
        if reason.is_failure:
            print(f"agf serve: the broker refused the connection: {reason}", file=sys.stderr, flush=True)
            return
        client.subscribe([(f"{self.prefix}/order", 0), (f"{self.prefix}/instantActions", 0)])
        self.listener.on_link(True)

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: Any, properties: Any) -> None:
        self.listener.on_link(False)

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        self.listener.on_message(message.topic, message.payload)
