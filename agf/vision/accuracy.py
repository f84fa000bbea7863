"""Accuracy of measurements against ground truth: errors, detections, refusals and wrong accepts.

One tally for every accuracy figure of ``agf bench`` (the project's own renders, the foreign renders)
and the accuracy report, so that "within bounds" means the same everywhere: |x| <= 10 mm, |z| <= 5 mm,
|pitch| <= 0.1 deg (estimate minus truth, fork frame), and the loaded/unloaded hypothesis right. An
accepted measurement outside them is a wrong accept, the worst outcome there is.
"""

from __future__ import annotations

import statistics
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from agf.camera import CameraModel
from agf.config import ForkGeometry, SearchVolume
from agf.errors import MeasurementError, OverexposedError
from agf.geometry import Transform
from agf.pallets import PalletType

if TYPE_CHECKING:
    from agf.vision.measure import MeasureDetail

BOUNDS = {"x_mm": 10.0, "z_mm": 5.0, "pitch_deg": 0.1}
KEYS = ("x_mm", "y_mm", "z_mm", "pitch_deg", "yaw_deg")


def pose_errors(estimate: Transform, truth: Transform) -> dict[str, float]:
    """Estimate minus truth in mm and degrees (``x_mm`` ... ``yaw_deg``)."""
    est, gt = estimate.to_dict(), truth.to_dict()
    return {key: est[key] - gt[key] for key in KEYS}


def within_bounds(errors: dict[str, float]) -> bool:
    """Whether the errors are inside :data:`BOUNDS`."""
    return all(abs(errors[key]) <= bound for key, bound in BOUNDS.items())


def measured_with_shorter_exposures(
    image: Any,
    shorter: Iterable[Any],
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    volume: SearchVolume,
    forks: ForkGeometry,
) -> tuple[MeasureDetail, bool]:
    """One frame measured without a prior, and whether a shorter exposure was needed. ``shorter``: the same view with
    ever shorter exposures, taken one by one while the vision refuses a frame as overexposed, as the controller asks
    its camera for them (``ControllerConfig.exposures``).

    Raises
    ------
    MeasurementError
        The refusal of the last frame measured (overexposed where no shorter one is left).
    """
    from agf.vision.measure import measure_pallet

    retakes, shortened = iter(shorter), False
    while True:
        try:
            return measure_pallet(image, camera, camera_in_fork, pallet, volume, forks=forks), shortened
        except OverexposedError:
            image, shortened = next(retakes, None), True
            if image is None:
                raise


@dataclass
class AccuracyTally:
    """Measurements and refusals of a set of scenes, summarised by :meth:`summary`."""

    errors: dict[str, list[float]] = field(default_factory=lambda: {key: [] for key in KEYS})
    timing: dict[str, list[float]] = field(default_factory=dict)
    refused: list[str] = field(default_factory=list)
    wrong: list[str] = field(default_factory=list)
    measured: int = 0
    rows: list[tuple[str, dict[str, float] | None, str]] = field(default_factory=list)  # name, errors, verdict
    shortened: dict[str, bool] = field(default_factory=dict)  # measured after shorter exposures: within bounds?

    def measure(
        self,
        name: str,
        image: Any,
        camera: CameraModel,
        camera_in_fork: Transform,
        pallet: PalletType,
        volume: SearchVolume,
        forks: ForkGeometry,
        truth: Transform,
        truth_loaded: bool,
        shorter: Iterable[Any] = (),
    ) -> None:
        """Measure one frame without a prior and count it, measured or refused; ``shorter`` as for
        :func:`measured_with_shorter_exposures` (none by default)."""
        try:
            detail, shortened = measured_with_shorter_exposures(image, shorter, camera, camera_in_fork, pallet, volume,
                                                                forks)
        except MeasurementError as exc:
            self.add_refused(name, str(exc))
            return
        m = detail.measurement
        errors = self.add_measured(name, m.pallet_in_fork, truth, m.loaded == truth_loaded, m.timing_ms)
        if shortened:
            self.shortened[name] = within_bounds(errors) and m.loaded == truth_loaded

    def add_measured(
        self, name: str, estimate: Transform, truth: Transform, right_hypothesis: bool, timing_ms: dict[str, float]
    ) -> dict[str, float]:
        """Count one accepted measurement; returns its errors."""
        errors = pose_errors(estimate, truth)
        self.measured += 1
        for key, value in errors.items():
            self.errors[key].append(abs(value))
        for stage, ms in timing_ms.items():
            self.timing.setdefault(stage, []).append(ms)
        right = within_bounds(errors) and right_hypothesis
        if not right:
            self.wrong.append(name)
        self.rows.append((name, errors, "within bounds" if right else "WRONG ACCEPT"))
        return errors

    def add_refused(self, name: str, reason: str) -> None:
        """Count one refusal with its reason."""
        self.refused.append(f"{name}: {reason}")
        self.rows.append((name, None, f"refused: {reason}"))

    def summary(self) -> dict[str, Any]:
        """Scenes, measured within bounds, refused, wrong accepts, median and max absolute errors, timing."""
        total = self.measured + len(self.refused)
        return {
            "scenes": total,
            "within_bounds": self.measured - len(self.wrong),
            "detection_rate": self.measured / total if total else 0.0,
            "wrong_accepts": len(self.wrong),
            "wrong": list(self.wrong),
            "refused": list(self.refused),
            "median": {k: statistics.median(v) for k, v in self.errors.items() if v},
            "max": {k: max(v) for k, v in self.errors.items() if v},
            "timing_ms_median": {k: statistics.median(v) for k, v in self.timing.items()},
            # measured only after shorter exposures (the first frame refused as overexposed), and of those within
            # the bounds: within_bounds counts them, first_frames_within_bounds does not
            "after_shorter_exposure": sorted(self.shortened),
            "first_frames_within_bounds": self.measured - len(self.wrong) - sum(self.shortened.values()),
        }
