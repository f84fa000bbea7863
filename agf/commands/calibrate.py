"""``agf calibrate`` / ``tools/calibrate``: the commissioning calibration, its YAML and its overlay."""

from __future__ import annotations

import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2

from agf.camera import load_camera
from agf.config import Config, load_calibration
from agf.errors import InputError, MeasurementError
from agf.vision.calibration import Calibration, Panel, calibrate
from agf.viz import calibration_overlay


def calibrate_command(
    config: Config,
    images: list[Path],
    *,
    panel_mm: tuple[float, float],
    camera: str | None,
    out: str | None,
    force: bool,
) -> dict[str, Any]:
    """``tools/calibrate`` / ``agf calibrate``: DESIGN.md's contract."""
    start = time.perf_counter()
    target = Path(out) if out else config.vision.calibration
    if target.exists() and not force and out is not None:
        raise InputError(f"{target}: exists; pass --force to overwrite the calibration")
    if out is None and not force:
        raise InputError(
            f"{target}: this is the calibration the config uses; pass --out FILE, or --force to replace it"
        )
    frames = []
    for path in images:
        frame = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if frame is None:
            raise InputError(f"{path}: not an image OpenCV can read")
        frames.append(frame)
    model = load_camera(camera or config.vision.camera)
    nominal = load_calibration(config.vision.calibration)
    panel = Panel(panel_mm[0] / 1e3, panel_mm[1] / 1e3)
    try:
        result = calibrate(frames, model, panel, config.forks, nominal)
    except MeasurementError as exc:
        return {"ok": False, "error": str(exc)}
    write_calibration(target, result, images)
    overlay = target.with_suffix(".png")
    calibration_overlay(frames[result.used[0]], model, result.fits[0], overlay)
    summary: dict[str, Any] = {
        "ok": True,
        "camera_in_fork": result.camera_in_fork.to_dict(),
        "residual_px": result.residual_px,
        "spread": result.spread,
        "images_used": [str(images[i]) for i in result.used],
        "images_rejected": {str(images[i]): reason for i, reason in result.rejected.items()},
        "calibration": str(target),
        "overlay": str(overlay),
        "timing_ms": {"total": (time.perf_counter() - start) * 1e3},
    }
    if result.without_shift is not None:
        summary["without_viewpoint_shift"] = result.without_shift.to_dict()
    return summary


def write_calibration(path: Path, result: Calibration, images: list[Path]) -> None:
    pose = {k: round(v, 4) for k, v in result.camera_in_fork.to_dict().items()}
    text = (
        "# Commissioning calibration written by tools/calibrate: the camera frame C in the fork frame F.\n"
        f"camera_in_fork: {{{', '.join(f'{k}: {v}' for k, v in pose.items())}}}\n"
        f"residual_px: {result.residual_px:.3f}\n"
        f"spread: {{{', '.join(f'{k}: {v:.4f}' for k, v in result.spread.items())}}}\n"
        f"images: [{', '.join(repr(str(images[i])) for i in result.used)}]\n"
        f"created: '{datetime.now(UTC).isoformat(timespec='seconds')}'\n"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
