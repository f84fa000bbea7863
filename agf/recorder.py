"""The recorder: every pick writes one MCAP log of what the controller saw and sent.

The controller tells a :class:`Recorder` about each state transition, frame, measurement, plan and
control cycle; the simulated world (or a truck's drivers) adds the raw CAN traffic. The base class
records nothing; :class:`McapRecorder` writes an MCAP file (https://mcap.dev) that Foxglove and the
ROS 2 tools open: frames as ``foxglove.CompressedImage`` (as the camera sent them: its JPEG, else PNG,
so that ``agf replay`` measures exactly the pixels the pick measured), transitions, faults and
refusals as ``foxglove.Log``, poses as ``foxglove.FrameTransform``, everything else as JSON messages
with a JSON schema (``docs/recorder.md`` lists the topics).

Nothing is lost when the process dies: messages go into small zstd chunks, and a background thread
closes the chunk in progress, writes it and syncs the file every ``flush_period`` (at most a
second), so a log cut by kill -9 or a power loss is readable up to its last flush with
:func:`read_log` (which reads the file front to back and needs no footer).

While a log is written its file holds an exclusive ``flock``; the retention rule
(:func:`enforce_retention`) deletes the oldest logs beyond the folder's size cap and skips a locked
file, so no process ever deletes a log that is still being written.
"""

from __future__ import annotations

import base64
import contextlib
import dataclasses
import fcntl
import json
import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from agf.axis import AxisFeedback
from agf.config import Config, ForkGeometry, SearchVolume, load_calibration
from agf.errors import ConfigError, InputError
from agf.frames import Frame
from agf.geometry import Transform
from agf.measurement import PalletMeasurement, uncertainty_json

# A chunk is closed at this size or at the next flush, whichever comes first; a frame (0.3-0.6 MB of
# JPEG, about 2 MB of PNG) fills one on its own.
CHUNK_SIZE = 256 * 1024
SETUP = "agf.measurement_setup"  # metadata record: what a measurement needs besides the frame
PICK = "agf.pick"  # metadata record: what was picked, by which command


# --------------------------------------------------------------------------------------------------
# message schemas


def _time(description: str) -> dict[str, Any]:
    return {
        "type": "object",
        "title": "time",
        "description": description,
        "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}},
    }


def _xyz(names: str, description: str) -> dict[str, Any]:
    return {"type": "object", "description": description,
            "properties": {name: {"type": "number"} for name in names}}


def _object(title: str, description: str, **properties: Any) -> dict[str, Any]:
    return {"title": title, "description": description, "type": "object", "properties": properties}


_POSE = {"type": "object", "description": "x_mm, y_mm, z_mm, roll_deg, pitch_deg, yaw_deg (DESIGN.md)"}
_TARGETS = {"type": "object", "description": "axis name -> position, m (linear axes) or rad (tilt)"}

#: Foxglove's well-known schemas (the fields this recorder fills), and this project's own.
SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.CompressedImage": _object(
        "foxglove.CompressedImage", "A compressed image",
        timestamp=_time("Timestamp of image"),
        frame_id={"type": "string", "description": "Frame of reference for the image"},
        data={"type": "string", "contentEncoding": "base64", "description": "Compressed image data"},
        format={"type": "string", "description": "Image format: jpeg (as the camera sent it) or png"},
    ),
    "foxglove.Log": _object(
        "foxglove.Log", "A log message",
        timestamp=_time("Timestamp of log message"),
        level={"title": "foxglove.LogLevel", "description": "Log level",
               "oneOf": [{"title": name, "const": value} for value, name in
                         enumerate(("UNKNOWN", "DEBUG", "INFO", "WARNING", "ERROR", "FATAL"))]},
        message={"type": "string", "description": "Log message"},
        name={"type": "string", "description": "Process or node name"},
        file={"type": "string", "description": "Filename"},
        line={"type": "integer", "minimum": 0, "description": "Line number in the file"},
    ),
    "foxglove.FrameTransform": _object(
        "foxglove.FrameTransform", "A transform between two reference frames in 3D space",
        timestamp=_time("Timestamp of transform"),
        parent_frame_id={"type": "string", "description": "Name of the parent frame"},
        child_frame_id={"type": "string", "description": "Name of the child frame"},
        translation=_xyz("xyz", "Translation component of the transform, m"),
        rotation=_xyz("xyzw", "Rotation component of the transform (quaternion)"),
    ),
    "agf.State": _object(
        "agf.State", "A transition of the pick's state machine (agf/controller.py)",
        state={"type": "string"}, event={"type": "string"}, reason={"type": ["string", "null"]},
    ),
    "agf.Measurement": _object(
        "agf.Measurement", "One pallet measurement, or its refusal with the reason",
        stage={"type": "string", "description": "measuring (first frame), verifying (after aligning) or confirming "
               "(a verifying frame's face where the plan expects it, at the pitch measured before)"},
        expected={**_POSE, "description": "confirming only: where the plan put the pallet (fork frame; mm, deg)"},
        frame={"type": "integer", "description": "sequence number of the frame on /camera/image"},
        ok={"type": "boolean"}, refusal={"type": ["string", "null"]},
        pallet_in_fork=_POSE, pallet_in_camera=_POSE, loaded={"type": "boolean"},
        scores={"type": "object"}, uncertainty={"type": "object", "description": "z_mm, pitch_deg (1 sigma)"},
        timing_ms={"type": "object"},
    ),
    "agf.Plan": _object(
        "agf.Plan", "Axis targets of the insertion and the safety check (paper section V.A)",
        safe={"type": "boolean"}, reason={"type": ["string", "null"]}, align=_TARGETS, insert=_TARGETS,
        margin_mm={"type": "number"}, margin_deg={"type": "number"}, pallet_in_truck=_POSE,
    ),
    "agf.AxisCycle": _object(
        "agf.AxisCycle", "One control cycle: the setpoints sent and the feedback received (m or rad, m/s or rad/s)",
        state={"type": "string"}, setpoint=_TARGETS,
        feedback={"type": "object", "description": "axis name -> {position, velocity, state, fault}"},
    ),
    "agf.CanFrame": _object(
        "agf.CanFrame", "One frame seen on the CAN bus",
        timestamp=_time("When the frame was received"),
        id={"type": "integer"}, extended={"type": "boolean"}, remote={"type": "boolean"},
        error={"type": "boolean"}, dlc={"type": "integer"}, data={"type": "string", "description": "hex bytes"},
    ),
}

#: topic -> schema name
TOPICS = {
    "/camera/image": "foxglove.CompressedImage",
    "/log": "foxglove.Log",
    "/tf": "foxglove.FrameTransform",
    "/state": "agf.State",
    "/measurement": "agf.Measurement",
    "/plan": "agf.Plan",
    "/axes": "agf.AxisCycle",
    "/can": "agf.CanFrame",
}

_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def transform_message(ns: int, parent: str, child: str, child_in_parent: Transform) -> dict[str, Any]:
    """A ``foxglove.FrameTransform``: ``child``'s pose in ``parent``."""
    x, y, z = (float(v) for v in child_in_parent.translation)
    qx, qy, qz, qw = (float(v) for v in child_in_parent.quaternion)
    return {"timestamp": _stamp(ns), "parent_frame_id": parent, "child_frame_id": child,
            "translation": {"x": x, "y": y, "z": z}, "rotation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def measurement_message(stage: str, frame: int, measurement: PalletMeasurement | None,
                        refusal: str | None, expected: Transform | None = None) -> dict[str, Any]:
    """The ``agf.Measurement`` message of one measurement (mm and degrees); ``expected``, of a confirmation."""
    message: dict[str, Any] = {"stage": stage, "frame": frame, "ok": measurement is not None, "refusal": refusal}
    if expected is not None:
        message["expected"] = expected.to_dict()
    if measurement is not None:
        message.update(
            pallet_in_fork=measurement.pallet_in_fork.to_dict(),
            pallet_in_camera=measurement.pallet_in_camera.to_dict(),
            loaded=measurement.loaded,
            scores={k: float(v) for k, v in measurement.scores.items()},
            uncertainty=uncertainty_json(measurement),
            timing_ms={k: float(v) for k, v in measurement.timing_ms.items()},
        )
    return message


# --------------------------------------------------------------------------------------------------
# what a measurement needs, recorded so that a log replays on its own


@dataclass(frozen=True)
class MeasurementSetup:
    """Everything a measurement uses besides the frame: camera model file, calibration, pallet type
    (from its catalogue file), search volume and forks (SI)."""

    camera_file: Path
    camera_in_fork: Transform
    pallets_file: Path
    pallet_type: str
    search: SearchVolume
    forks: ForkGeometry

    @classmethod
    def from_config(cls, config: Config, pallet_type: str | None = None) -> MeasurementSetup:
        """The setup the configuration names; ``pallet_type`` overrides ``vision.pallet_type``."""
        vision = config.vision
        return cls(vision.camera, load_calibration(vision.calibration), vision.pallets,
                   pallet_type or vision.pallet_type, vision.search, config.forks)

    def metadata(self) -> dict[str, str]:
        """The MCAP metadata record (strings only); the two files go in as attachments."""
        return {
            "camera_file": self.camera_file.name,
            "camera_in_fork_matrix": json.dumps(self.camera_in_fork.matrix.tolist()),
            "pallets_file": self.pallets_file.name,
            "pallet_type": self.pallet_type,
            "search": json.dumps(dataclasses.asdict(self.search)),
            "forks": json.dumps(dataclasses.asdict(self.forks)),
        }


# --------------------------------------------------------------------------------------------------
# recorders


class Recorder:
    """What the controller reports during a pick. This base records nothing (a pick without a log);
    :class:`McapRecorder` writes the MCAP file. Methods may be called from any thread."""

    def state(self, state: str, event: str, reason: str | None = None) -> None:
        """The machine entered ``state`` on ``event``; ``reason`` says why (a fault's cause)."""

    def note(self, level: str, message: str) -> None:
        """A line of the pick's log: ``level`` is debug, info, warning, error or fatal."""

    def frame(self, frame: Frame) -> None:
        """A frame the controller acquired."""

    def measurement(self, stage: str, frame: Frame, measurement: PalletMeasurement | None,
                    refusal: str | None = None, expected: Transform | None = None) -> None:
        """The measurement of ``frame`` at ``stage`` (measuring, verifying or confirming), or why it was refused;
        ``expected``, of a confirmation, is where the plan put the pallet (``pallet_in_fork``)."""

    def plan(self, plan: Any) -> None:
        """The insertion plan: axis targets and the safety check (:class:`agf.insertion.InsertionPlan`)."""

    def cycle(self, state: str, setpoints: Mapping[str, float], feedback: Mapping[str, AxisFeedback]) -> None:
        """One control cycle: setpoints sent (m or rad) and the feedback read back."""

    def can_frame(self, timestamp: float, arbitration_id: int, data: bytes, *, extended: bool = False,
                  remote: bool = False, error: bool = False) -> None:
        """One CAN frame seen on the bus at ``timestamp`` (s since the epoch)."""

    def close(self) -> None:
        """Finish the log."""

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class McapRecorder(Recorder):
    """One pick's MCAP log at ``path`` (created, never overwritten).

    Parameters
    ----------
    path : Path
        The new file.
    setup : MeasurementSetup
        Recorded (metadata and attachments) so that ``agf replay`` needs nothing but the log.
    context : mapping of str to str
        What was picked, by which command (the ``agf.pick`` metadata record).
    flush_period : float
        Seconds between flushes to the disk (0.01..1).
    fork_in_truck : callable, optional
        Axis positions -> fork frame F in truck frame T; with it every cycle records the forks' pose.
    """

    def __init__(self, path: Path, setup: MeasurementSetup, *, context: Mapping[str, str] | None = None,
                 flush_period: float = 0.5,
                 fork_in_truck: Callable[[Mapping[str, float]], Transform] | None = None) -> None:
        self.path = Path(path)
        self._file = self.path.open("xb")
        fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)  # "being written", for enforce_retention
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="agf recorder")
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        self._closed = False
        self._fork_in_truck = fork_in_truck
        started = datetime.now(UTC).isoformat()
        self._writer.add_metadata(PICK, {"started_utc": started, **(context or {})})
        self._writer.add_metadata(SETUP, setup.metadata())
        now = time.time_ns()
        for folder, file in (("camera", setup.camera_file), ("pallets", setup.pallets_file)):
            self._writer.add_attachment(now, now, f"{folder}/{file.name}", "application/octet-stream",
                                        file.read_bytes())
        self._write("/tf", transform_message(now, "fork", "camera", setup.camera_in_fork), now)
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_every, args=(flush_period,), name="recorder-flush",
                                         daemon=True)
        self._flusher.start()

    # -- events -----------------------------------------------------------------------------------
    def state(self, state: str, event: str, reason: str | None = None) -> None:
        now = time.time_ns()
        self._write("/state", {"state": state, "event": event, "reason": reason}, now)
        text = f"{event} -> {state}" + (f": {reason}" if reason else "")
        self._log("error" if state == "fault" else "info", text, now)

    def note(self, level: str, message: str) -> None:
        self._log(level, message, time.time_ns())

    def frame(self, frame: Frame) -> None:
        """The frame as the camera sent it: its JPEG when it sent one (the pixels measured are that JPEG's
        decoding; the default pick's 1920 x 1920 frames: 0.34 MB of JPEG, 2.3 MB and about 100 ms of CPU as
        PNG), else a PNG."""
        if frame.jpeg is not None:
            data, kind = frame.jpeg, "jpeg"
        else:
            ok, png = cv2.imencode(".png", frame.image, [cv2.IMWRITE_PNG_COMPRESSION, 1])  # lossless, fast
            if not ok:
                self.note("error", f"frame {frame.index}: PNG encoding failed, frame not recorded")
                return
            data, kind = png.tobytes(), "png"
        now = time.time_ns()
        image = {"timestamp": _stamp(now), "frame_id": "camera", "format": kind,
                 "data": base64.b64encode(data).decode("ascii")}
        self._write("/camera/image", image, now, sequence=frame.index)

    def measurement(self, stage: str, frame: Frame, measurement: PalletMeasurement | None,
                    refusal: str | None = None, expected: Transform | None = None) -> None:
        now = time.time_ns()
        self._write("/measurement", measurement_message(stage, frame.index, measurement, refusal, expected), now)
        if measurement is None:
            self._log("error", f"{stage}: measurement refused: {refusal}", now)
            return
        self._write("/tf", transform_message(now, "fork", "pallet", measurement.pallet_in_fork), now)

    def plan(self, plan: Any) -> None:
        message = {
            "safe": bool(plan.safe), "reason": plan.reason,
            "align": {k: float(v) for k, v in plan.align.items()},
            "insert": {k: float(v) for k, v in plan.insert.items()},
            "margin_mm": float(plan.margin_mm), "margin_deg": float(plan.margin_deg),
            "pallet_in_truck": plan.pallet_in_truck.to_dict(),
        }
        self._write("/plan", message, time.time_ns())

    def cycle(self, state: str, setpoints: Mapping[str, float], feedback: Mapping[str, AxisFeedback]) -> None:
        now = time.time_ns()
        axes = {name: {"position": f.position, "velocity": f.velocity, "state": f.state.value, "fault": f.fault}
                for name, f in feedback.items()}
        self._write("/axes", {"state": state, "setpoint": {k: float(v) for k, v in setpoints.items()},
                              "feedback": axes}, now)
        if self._fork_in_truck is not None:
            fork = self._fork_in_truck({name: f.position for name, f in feedback.items()})
            self._write("/tf", transform_message(now, "truck", "fork", fork), now)

    def can_frame(self, timestamp: float, arbitration_id: int, data: bytes, *, extended: bool = False,
                  remote: bool = False, error: bool = False) -> None:
        ns = int(timestamp * 1e9)
        self._write("/can", {"timestamp": _stamp(ns), "id": arbitration_id, "extended": extended, "remote": remote,
                             "error": error, "dlc": len(data), "data": data.hex()}, ns)

    def close(self) -> None:
        """Write the footer (summary and indexes), sync and release the file; idempotent."""
        self._stop.set()
        self._flusher.join()
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._writer.finish()
            self._file.flush()
            _sync(self._file)
            self._file.close()  # closing drops the flock

    # -- writing ----------------------------------------------------------------------------------
    def _log(self, level: str, message: str, ns: int) -> None:
        self._write("/log", {"timestamp": _stamp(ns), "level": _LEVELS[level], "message": message,
                             "name": "agf", "file": "", "line": 0}, ns)

    def _write(self, topic: str, message: dict[str, Any], ns: int, sequence: int = 0) -> None:
        data = json.dumps(message).encode()
        with self._lock:
            if self._closed:  # a CAN frame arriving after the pick ended
                return
            channel = self._channels.get(topic)
            if channel is None:
                name = TOPICS[topic]
                schema = self._writer.register_schema(name, "jsonschema", json.dumps(SCHEMAS[name]).encode())
                channel = self._channels[topic] = self._writer.register_channel(topic, "json", schema)
            self._writer.add_message(channel, ns, data, ns, sequence)

    def _flush_every(self, period: float) -> None:
        while not self._stop.wait(period):
            with self._lock:
                self._writer.flush()  # closes the chunk in progress and writes it
            # outside the lock: a slow disk must not hold up the control cycle; close() waits for us
            _sync(self._file)


def _sync(file: Any) -> None:
    """Push the file to the disk: kill -9 loses nothing written, a power cut nothing synced."""
    os.fsync(file.fileno())


# --------------------------------------------------------------------------------------------------
# the log folder


def open_pick_log(config: Config, name: str, setup: MeasurementSetup, **options: Any) -> McapRecorder:
    """A new log ``<UTC time>_<name>.mcap`` in the configured folder (``recorder.folder``, relative to
    the config file, created if needed), after retention made room.

    ``options`` go to :class:`McapRecorder` (``context``, ``fork_in_truck``).

    Raises
    ------
    ConfigError
        The folder cannot be created or written.
    """
    folder = (config.root / config.recorder.folder).resolve()
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S.%fZ")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        recorder = McapRecorder(folder / f"{stamp}_{name}.mcap", setup, flush_period=config.recorder.flush_period,
                                **options)
    except OSError as exc:
        raise ConfigError(f"{config.source}: recorder.folder: cannot write a log in {folder} ({exc})") from exc
    enforce_retention(folder, config.recorder.max_total_mb * 1e6, keep=recorder.path)
    return recorder


def enforce_retention(folder: Path, max_bytes: float, keep: Path | None = None) -> list[Path]:
    """Delete the oldest ``*.mcap`` logs of ``folder`` until the rest fit in ``max_bytes``.

    Never ``keep``, and never a log another recorder is still writing (its file is locked). Returns
    the deleted files, oldest first.
    """
    logs = []
    for path in folder.glob("*.mcap"):
        with contextlib.suppress(FileNotFoundError):  # another process's retention got there first
            stat = path.stat()
            logs.append((stat.st_mtime, stat.st_size, path))
    logs.sort()
    total = sum(size for _, size, _ in logs)
    deleted = []
    for _, size, path in logs:
        if total <= max_bytes:
            break
        if (keep is not None and path == Path(keep)) or _being_written(path):
            continue
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
            deleted.append(path)
        total -= size
    return deleted


def _being_written(path: Path) -> bool:
    try:
        with path.open("rb") as file:
            fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except FileNotFoundError:
        return False
    return False


# --------------------------------------------------------------------------------------------------
# reading


@dataclass(frozen=True)
class LoggedMessage:
    """One message of a log: its topic, when it was logged (ns since the epoch), its sequence number
    and its decoded JSON."""

    topic: str
    log_time: int
    sequence: int
    data: dict[str, Any]


@dataclass(frozen=True)
class PickLog:
    """A pick's log as :func:`read_log` found it; ``complete`` is False when it was cut off (killed)."""

    path: Path
    messages: tuple[LoggedMessage, ...]
    attachments: Mapping[str, bytes]
    metadata: Mapping[str, Mapping[str, str]]
    complete: bool

    def on(self, topic: str) -> list[LoggedMessage]:
        """The messages of one topic, in the order they were written."""
        return [m for m in self.messages if m.topic == topic]


def read_log(path: str | Path) -> PickLog:
    """Read a pick's log front to back, as far as it goes: a log cut by kill -9 (no footer, a last
    chunk half written) yields every message up to its last flush.

    Raises
    ------
    InputError
        The file is missing or not an MCAP file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: log file not found")
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[LoggedMessage] = []
    attachments: dict[str, bytes] = {}
    metadata: dict[str, dict[str, str]] = {}
    complete = False
    with path.open("rb") as stream:
        try:
            for record in StreamReader(stream, record_size_limit=None).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message) and record.channel_id in channels:
                    topic = channels[record.channel_id].topic
                    messages.append(LoggedMessage(topic, record.log_time, record.sequence, json.loads(record.data)))
                elif isinstance(record, Attachment):
                    attachments[record.name] = record.data
                elif isinstance(record, Metadata):
                    metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Footer):
                    complete = True
        except McapError as exc:
            if not messages and not metadata:
                raise InputError(f"{path}: not a readable MCAP log ({type(exc).__name__}: {exc})") from exc
    return PickLog(path, tuple(messages), attachments, metadata, complete)


def decode_frame(message: LoggedMessage) -> np.ndarray:
    """The pixels of a ``/camera/image`` message."""
    data = np.frombuffer(base64.b64decode(message.data["data"]), np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"frame {message.sequence}: the logged {message.data.get('format')} image does not decode")
    return image
