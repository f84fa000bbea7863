"""``agf replay LOG.mcap``: the measurement re-run on a pick's logged frames with today's code.

Everything the measurement needs comes from the log itself (:mod:`agf.recorder` writes the camera
model and the pallet catalogue as attachments, the calibration, pallet type, search volume and forks
as metadata), so a folder of logs from trucks is a regression test on real frames: a change to the
vision that moves a measurement shows here as a difference.

The pick measured without a prior (as the simulated world does), and so does the replay; a confirmation
(stage ``confirming``: a verifying frame's face where the plan expected it, at the pitch measured before) is
confirmed again from the ``expected`` pose it logged. Frames are
logged as the camera sent them (its JPEG, whose decoding is what the pick measured, or PNG), so with
unchanged code the replay reproduces the logged measurement to the last digit; :data:`TOLERANCE_MM` and
:data:`TOLERANCE_DEG` only absorb floating-point noise.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from agf.camera import load_camera
from agf.config import Config, ForkGeometry, SearchVolume
from agf.errors import InputError, MeasurementError
from agf.geometry import Transform, transform_from_dict
from agf.pallets import load_pallets, pallet_type
from agf.recorder import SETUP, LoggedMessage, MeasurementSetup, PickLog, decode_frame, read_log
from agf.vision.measure import MeasureDetail, confirm_pallet, measure_pallet

TOLERANCE_MM = 0.05  # replayed and logged positions agree within this (mm)
TOLERANCE_DEG = 0.005  # ... and angles within this (deg)
_POSITIONS = ("x_mm", "y_mm", "z_mm")
_ANGLES = ("roll_deg", "pitch_deg", "yaw_deg")


def setup_from_log(log: PickLog, folder: Path) -> MeasurementSetup:
    """The measurement setup a log records; its camera and catalogue files are written to ``folder``."""
    meta = log.metadata.get(SETUP)
    if meta is None:
        raise InputError(f"{log.path}: no '{SETUP}' metadata record; the log cannot be replayed on its own")
    try:
        files = {}
        for key, group in (("camera_file", "camera"), ("pallets_file", "pallets")):
            name = Path(meta[key]).name
            files[key] = folder / name
            files[key].write_bytes(log.attachments[f"{group}/{name}"])
        return MeasurementSetup(
            camera_file=files["camera_file"],
            camera_in_fork=Transform.from_matrix(json.loads(meta["camera_in_fork_matrix"])),
            pallets_file=files["pallets_file"],
            pallet_type=meta["pallet_type"],
            search=SearchVolume(**json.loads(meta["search"])),
            forks=ForkGeometry(**json.loads(meta["forks"])),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{log.path}: the '{SETUP}' record or its attachments are incomplete ({exc})") from exc


class _Measurer:
    """Today's measurement with a log's setup."""

    def __init__(self, setup: MeasurementSetup) -> None:
        self.setup = setup
        self.camera = load_camera(setup.camera_file)
        self.pallet = pallet_type(load_pallets(setup.pallets_file), setup.pallet_type)

    def __call__(self, image: np.ndarray, logged: dict[str, Any] | None = None) -> MeasureDetail:
        """The frame measured from scratch, or, for a logged confirmation (stage ``confirming``), its face confirmed
        where the log says the plan expected it, with the logged hypothesis and pitch sigma."""
        s = self.setup
        if logged is None or logged["stage"] != "confirming":
            return measure_pallet(image, self.camera, s.camera_in_fork, self.pallet, s.search, forks=s.forks)
        expected = transform_from_dict(logged["expected"], where=f"frame {logged['frame']}: expected")
        sigma = math.radians(logged["uncertainty"]["pitch_deg"]) if logged["ok"] else 0.0
        return confirm_pallet(image, self.camera, s.camera_in_fork, self.pallet, s.search, expected,
                              loaded=bool(logged.get("loaded", False)), sigma_pitch=sigma, forks=s.forks)


def compare(logged: dict[str, Any], replayed: MeasureDetail | None, refusal: str | None) -> dict[str, Any]:
    """One logged measurement against its replay: the differences (replayed - logged, mm and deg)."""
    row: dict[str, Any] = {
        "stage": logged["stage"],
        "frame": logged["frame"],
        "logged": _summary(logged.get("pallet_in_fork"), logged.get("loaded"), logged.get("refusal")),
    }
    if replayed is None:
        row["replayed"] = _summary(None, None, refusal)
        row["same"] = not logged["ok"]
        return row
    m = replayed.measurement
    pose = m.pallet_in_fork.to_dict()
    row["replayed"] = _summary(pose, m.loaded, None)
    if not logged["ok"]:
        row["same"] = False
        return row
    difference = {key: pose[key] - logged["pallet_in_fork"][key] for key in _POSITIONS + _ANGLES}
    row["difference"] = difference
    row["same"] = (
        m.loaded == logged["loaded"]
        and all(abs(difference[k]) <= TOLERANCE_MM for k in _POSITIONS)
        and all(abs(difference[k]) <= TOLERANCE_DEG for k in _ANGLES)
    )
    return row


def _summary(pose: dict[str, float] | None, loaded: bool | None, refusal: str | None) -> dict[str, Any]:
    if pose is None:
        return {"ok": False, "refusal": refusal}
    return {"ok": True, "pallet_in_fork": {k: pose[k] for k in _POSITIONS + _ANGLES}, "loaded": loaded}


def replay_log(log: PickLog, plots: Path | None = None) -> dict[str, Any]:
    """Re-measure every logged measurement's frame; ``ok`` when each agrees with the log.

    With ``plots`` the pick is drawn from the log alone: the axes' setpoints and feedback over time,
    and each frame with its replayed measurement.
    """
    frames = {m.sequence: m for m in log.on("/camera/image")}
    logged = log.on("/measurement")
    if not logged:
        raise InputError(f"{log.path}: the log holds no measurement to replay (the pick ended before measuring)")
    with tempfile.TemporaryDirectory() as folder:
        measure = _Measurer(setup_from_log(log, Path(folder)))
    rows, details = [], []
    for message in logged:
        frame = frames.get(message.data["frame"])
        if frame is None:
            raise InputError(f"{log.path}: measurement of frame {message.data['frame']} but no such frame logged")
        detail, refusal = _measure(measure, frame, message.data)
        rows.append(compare(message.data, detail, refusal))
        details.append((frame, detail))
    result: dict[str, Any] = {
        "ok": all(row["same"] for row in rows),
        "log": str(log.path),
        "complete": log.complete,
        "frames": len(frames),
        "measurements": rows,
        "max_difference": _largest(rows),
        "tolerance": {"position_mm": TOLERANCE_MM, "angle_deg": TOLERANCE_DEG},
    }
    if plots is not None:
        result["plots"] = draw_pick(log, details, measure, plots)
    return result


def _measure(measure: _Measurer, frame: LoggedMessage,
             logged: dict[str, Any] | None = None) -> tuple[MeasureDetail | None, str | None]:
    image = decode_frame(frame)
    camera = measure.camera
    if image.shape[:2] != (camera.height, camera.width):
        raise InputError(f"frame {frame.sequence} is {image.shape[1]} x {image.shape[0]}, the logged camera model's "
                         f"frames are {camera.width} x {camera.height}")
    try:
        return measure(image, logged), None
    except MeasurementError as exc:
        return None, str(exc)


def _largest(rows: list[dict[str, Any]]) -> dict[str, float]:
    diffs = [row["difference"] for row in rows if "difference" in row]
    return {
        "position_mm": max((abs(d[k]) for d in diffs for k in _POSITIONS), default=0.0),
        "angle_deg": max((abs(d[k]) for d in diffs for k in _ANGLES), default=0.0),
    }


def axis_log(log: PickLog) -> list[dict[str, Any]]:
    """The controller's per-cycle rows (``t`` s, ``state``, ``setpoint``, ``actual``) rebuilt from ``/axes``."""
    return [
        {"t": m.log_time * 1e-9, "state": m.data["state"], "setpoint": m.data["setpoint"],
         "actual": {name: f["position"] for name, f in m.data["feedback"].items()}}
        for m in log.on("/axes")
    ]


def draw_pick(log: PickLog, details: list[tuple[LoggedMessage, MeasureDetail | None]], measure: _Measurer,
              folder: Path) -> list[str]:
    """The pick's plots from its log: axis trajectories and each measured frame with its overlay."""
    from agf.viz import measurement_overlay, pick_plots

    folder.mkdir(parents=True, exist_ok=True)
    written = pick_plots(SimpleNamespace(log=axis_log(log)), folder)
    for k, (frame, detail) in enumerate(details):
        if detail is None:
            continue
        out = folder / f"measurement-{k + 1}-frame-{frame.sequence}.png"
        measurement_overlay(decode_frame(frame), measure.camera, measure.pallet, detail, out, forks=measure.setup.forks)
        written.append(str(out))
    return written


def replay_command(config: Config, log_path: Path, *, plots: str | None = None) -> dict[str, Any]:
    """``agf replay``: DESIGN.md's command; the configuration is not used, the log carries its setup."""
    return replay_log(read_log(log_path), Path(plots) if plots else None)
