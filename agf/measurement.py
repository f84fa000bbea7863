"""What the vision hands to the rest of the controller: one pallet measurement.

A measurement exists only when it is trustworthy; an untrustworthy one is a
:class:`agf.errors.MeasurementError` with the reason, never a number.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from agf.geometry import Transform


@dataclass(frozen=True)
class PalletMeasurement:
    """The measured pose of a pallet's front face (frame P) and its uncertainty.

    Attributes
    ----------
    pallet_in_camera : Transform
        Frame P in camera frame C (m, rad).
    pallet_in_fork : Transform
        Frame P in fork frame F, through the commissioning calibration.
    loaded : bool
        Which hypothesis the pitch came from (paper section III).
    sigma_z : float
        Standard deviation of the height (fork z) estimate, m.
    sigma_pitch : float
        Standard deviation of the pitch estimate, rad.
    scores : mapping
        Hypothesis scores (``loaded``, ``unloaded``: Hough score / predicted length) and others.
    timing_ms : mapping
        Stage durations, ms (the ``timing_ms`` of DESIGN.md's ``agf measure`` contract).
    """

    pallet_in_camera: Transform
    pallet_in_fork: Transform
    loaded: bool
    sigma_z: float = 0.0
    sigma_pitch: float = 0.0
    scores: Mapping[str, float] = field(default_factory=dict)
    timing_ms: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.sigma_z) and self.sigma_z >= 0):
            raise ValueError(f"sigma_z must be a finite non-negative number, got {self.sigma_z!r}")
        if not (np.isfinite(self.sigma_pitch) and self.sigma_pitch >= 0):
            raise ValueError(f"sigma_pitch must be a finite non-negative number, got {self.sigma_pitch!r}")


def pose_json(T: Transform) -> dict[str, float]:
    """``{x_mm, y_mm, z_mm, pitch_deg, yaw_deg}`` of DESIGN.md's ``agf measure`` contract."""
    d = T.to_dict()
    return {key: d[key] for key in ("x_mm", "y_mm", "z_mm", "pitch_deg", "yaw_deg")}


def uncertainty_json(m: PalletMeasurement) -> dict[str, float]:
    """``{z_mm, pitch_deg}``: the measurement's uncertainty (1 sigma) in the units of DESIGN.md's JSON."""
    return {"z_mm": m.sigma_z * 1e3, "pitch_deg": float(np.degrees(m.sigma_pitch))}
