"""``agf serve``: the truck on the fleet's broker until Ctrl-C (or SIGTERM); ``reset`` typed on its
terminal is the local reset after a failed pick."""

from __future__ import annotations

import dataclasses
import functools
import signal
import sys
import threading
from typing import Any
from urllib.parse import urlsplit

from agf.config import Config, FleetConfig
from agf.errors import InputError
from agf.fleet.agent import FleetAgent
from agf.fleet.link import FleetLink
from agf.fleet.truck import FleetTruck


def fleet_settings(
    fleet: FleetConfig, broker_url: str | None, manufacturer: str | None, serial: str | None
) -> FleetConfig:
    """``fleet`` with the command line's broker (``mqtt://HOST:PORT``, ``mqtts://`` for TLS), manufacturer
    and serial number.

    Raises
    ------
    InputError
        A URL that is not ``mqtt://HOST[:PORT]`` or ``mqtts://HOST[:PORT]``, or a name that is not a topic level.
    """
    broker = fleet.broker
    if broker_url is not None:
        url = urlsplit(broker_url)
        try:
            port = url.port
        except ValueError:
            port = -1
        if url.scheme not in ("mqtt", "mqtts") or not url.hostname or port == -1 or url.path not in ("", "/"):
            raise InputError(f"--broker: expected mqtt://HOST:PORT or mqtts://HOST:PORT, got {broker_url!r}")
        tls = url.scheme == "mqtts"
        broker = dataclasses.replace(
            broker,
            host=url.hostname,
            port=port or (8883 if tls else 1883),
            tls=tls,
            ca_file=broker.ca_file if tls else None,
        )
    names = {"manufacturer": manufacturer, "serial_number": serial}
    try:
        return dataclasses.replace(fleet, broker=broker, **{k: v for k, v in names.items() if v is not None})
    except ValueError as exc:
        raise InputError(f"--manufacturer/--serial: {exc}") from exc


def serve_command(
    config: Config,
    link_class: type[FleetLink],
    truck: FleetTruck,
    *,
    broker: str | None = None,
    manufacturer: str | None = None,
    serial: str | None = None,
) -> dict[str, Any]:
    """Serve the fleet until interrupted (Ctrl-C, SIGTERM); a ``reset`` line on stdin is the local reset."""
    fleet = fleet_settings(config.fleet, broker, manufacturer, serial)
    agent = FleetAgent(fleet, config.forks, config.vision.search, truck)
    agent.attach(link_class(fleet.broker, agent.prefix, agent, agent.will()))
    say = functools.partial(print, file=sys.stderr, flush=True)
    say(
        f"agf serve: {agent.prefix} on {fleet.broker.host}:{fleet.broker.port}; type 'reset' after a failed pick, "
        "Ctrl-C to stop"
    )
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _interrupt)
    agent.start()
    try:
        for line in sys.stdin:
            if line.strip() == "reset":
                say(f"agf serve: {agent.local_reset()}")
            elif line.strip():
                say("agf serve: the only command is 'reset'")
        threading.Event().wait()  # stdin closed: serve until interrupted
    except KeyboardInterrupt:
        pass
    finally:
        agent.close()
    return {"ok": True, "prefix": agent.prefix, "broker": f"{fleet.broker.host}:{fleet.broker.port}"}


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt
