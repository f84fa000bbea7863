"""VDA 5050 2.1 messages: headers, checks of what the fleet sends, and error objects.

Incoming ``order`` and ``instantActions`` messages are checked against the standard's own JSON
schemas, shipped in ``agf/fleet/schemas/`` with their MIT licence. A message that fails a check
raises :class:`RejectedMessage` carrying the VDA 5050 error the vehicle reports in its state.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from datetime import UTC, datetime
from importlib import resources
from typing import Any

from jsonschema import Draft202012Validator

from agf.errors import AgfError

VERSION = "2.1.0"
MAJOR = VERSION.split(".")[0]
INCOMING = ("order", "instantActions")
QOS = {"connection": 1}  # section 6.2: QoS 1 for connection, 0 for every other topic
RETAINED = ("connection", "factsheet")  # sections 6.14 and 6.15


class RejectedMessage(AgfError):
    """A message from the fleet that the vehicle does not take; ``error`` is the VDA 5050 error object."""

    def __init__(self, error: dict[str, Any]) -> None:
        super().__init__(error.get("errorDescription", error["errorType"]))
        self.error = error


def vda_error(
    error_type: str,
    description: str,
    references: Mapping[str, Any],
    level: str = "WARNING",
    hint: str | None = None,
) -> dict[str, Any]:
    """A VDA 5050 error object; ``references`` key -> value (values become strings, None ones are left out)."""
    error: dict[str, Any] = {
        "errorType": error_type,
        "errorLevel": level,
        "errorDescription": description,
        "errorReferences": [
            {"referenceKey": key, "referenceValue": str(value)}
            for key, value in references.items()
            if value is not None
        ],
    }
    if hint:
        error["errorHint"] = hint
    return error


def timestamp(now: datetime | None = None) -> str:
    """ISO 8601 UTC with hundredths, as the standard writes it: ``2017-04-15T11:40:03.12Z``."""
    now = now or datetime.now(UTC)
    return now.strftime("%Y-%m-%dT%H:%M:%S.") + f"{now.microsecond // 10000:02d}Z"


class Headers:
    """Header fields of the vehicle's messages; ``headerId`` counts per topic (section 6.4)."""

    def __init__(self, manufacturer: str, serial_number: str) -> None:
        self.manufacturer, self.serial_number = manufacturer, serial_number
        self._ids: dict[str, int] = {}

    def __call__(self, topic: str) -> dict[str, Any]:
        self._ids[topic] = self._ids.get(topic, -1) + 1
        return {
            "headerId": self._ids[topic],
            "timestamp": timestamp(),
            "version": VERSION,
            "manufacturer": self.manufacturer,
            "serialNumber": self.serial_number,
        }


@functools.cache
def schema_validator(topic: str) -> Draft202012Validator:
    """The validator of the shipped 2.1.0 schema of ``topic`` (``order`` or ``instantActions``)."""
    text = resources.files("agf.fleet").joinpath("schemas", f"{topic}.schema").read_text(encoding="utf-8")
    return Draft202012Validator(json.loads(text))


def parse_incoming(topic: str, payload: bytes) -> dict[str, Any]:
    """The message of ``topic`` once it is JSON, passes its schema and speaks version 2.x.

    Raises
    ------
    RejectedMessage
        A ``validationError`` naming the topic (and the ``headerId`` where the message has one).
    """
    refs: dict[str, Any] = {"topic": topic}
    try:
        message = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RejectedMessage(vda_error("validationError", f"{topic}: not JSON ({exc})", refs)) from None
    if isinstance(message, dict) and isinstance(message.get("headerId"), int):
        refs["headerId"] = message["headerId"]
    problem = next(iter(sorted(schema_validator(topic).iter_errors(message), key=lambda e: list(e.path))), None)
    if problem is not None:
        where = "/".join(str(p) for p in problem.absolute_path) or "the message"
        raise RejectedMessage(
            vda_error("validationError", f"{topic}: {where}: {problem.message} (VDA 5050 {VERSION} schema)", refs)
        )
    if message["version"].split(".")[0] != MAJOR:
        raise RejectedMessage(
            vda_error(
                "validationError",
                f"{topic}: version {message['version']!r}, this vehicle speaks VDA 5050 {VERSION} (major {MAJOR})",
                {**refs, "version": message["version"]},
            )
        )
    return message


def parameters(action: Mapping[str, Any]) -> dict[str, Any]:
    """An action's ``actionParameters`` as ``{key: value}``."""
    return {p["key"]: p["value"] for p in action.get("actionParameters") or ()}
