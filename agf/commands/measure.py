"""``agf measure``: one fisheye image in, DESIGN.md's JSON out, and the overlay picture (for a refusal
too: that is when a commissioning engineer needs it)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2

from agf.camera import load_camera
from agf.config import Config, load_calibration
from agf.errors import InputError, MeasurementError
from agf.geometry import Transform, transform_from_dict
from agf.insertion import InsertionConfig, tolerance_margins
from agf.measurement import PalletMeasurement, pose_json, uncertainty_json
from agf.pallets import PalletType, load_pallets, pallet_type
from agf.vision.measure import measure_pallet
from agf.viz import measurement_overlay, refusal_overlay


def measure_command(
    config: Config,
    image: Path,
    *,
    camera: str | None = None,
    calibration: str | None = None,
    pallet_type: str | None = None,
    prior_json: str | None = None,
    overlay: str | None = None,
) -> dict[str, Any]:
    """``agf measure``: DESIGN.md's JSON contract."""
    frame = cv2.imread(str(image), cv2.IMREAD_COLOR)  # colour: the pitch search reads edges beside clipping in it
    if frame is None:
        raise InputError(f"{image}: not an image OpenCV can read")
    model = load_camera(camera or config.vision.camera)
    camera_in_fork = load_calibration(calibration or config.vision.calibration)
    pallet = _pallet(config, pallet_type)
    prior = _prior(prior_json)
    try:
        detail = measure_pallet(
            frame, model, camera_in_fork, pallet, config.vision.search, forks=config.forks, prior=prior
        )
    except MeasurementError as exc:
        result: dict[str, Any] = {"ok": False, "error": str(exc)}
        if overlay:
            refusal_overlay(frame, model, pallet, exc.found, str(exc), Path(overlay))
            result["overlay"] = overlay
        return result
    m = detail.measurement
    result = {
        "ok": True,
        "loaded": m.loaded,
        "pallet_in_fork": pose_json(m.pallet_in_fork),
        "pallet_in_camera": pose_json(m.pallet_in_camera),
        "scores": {"loaded": m.scores["loaded"], "unloaded": m.scores["unloaded"]},
        "uncertainty": uncertainty_json(m),
        "insertion": _insertion_check(m, pallet, config),
        "timing_ms": dict(m.timing_ms),
    }
    if overlay:
        result["overlay"] = overlay
        measurement_overlay(frame, model, pallet, detail, Path(overlay), forks=config.forks)
    return result


def _insertion_check(m: PalletMeasurement, pallet: PalletType, config: Config) -> dict[str, Any]:
    """Paper V.A with this measurement's uncertainty (and the drives' residual error) taken off."""
    settings = InsertionConfig()
    error_z = settings.sigmas * m.sigma_z + settings.drive_error_z
    error_tilt = settings.sigmas * m.sigma_pitch + settings.drive_error_tilt
    margin, margin_tilt = tolerance_margins(error_z, error_tilt, pallet.pocket_height, config.forks)
    return {"safe": margin > 0 and margin_tilt > 0, "margin_mm": margin * 1e3, "margin_deg": math.degrees(margin_tilt)}


def _pallet(config: Config, name: str | None) -> PalletType:
    return pallet_type(load_pallets(config.vision.pallets), name or config.vision.pallet_type)


def _prior(path: str | None) -> Transform | None:
    if path is None:
        return None
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the prior JSON ({exc})") from exc
    pose = data.get("pallet_in_fork", data) if isinstance(data, dict) else data
    try:
        return transform_from_dict(pose, where=f"{path}: pallet_in_fork")
    except ValueError as exc:
        raise InputError(str(exc)) from exc
