"""The double sphere model (Usenko, Demmel and Cremers 2018; Kalibr's ``ds``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agf.camera.base import Array, CameraModel, normalised_from_pixels, pixels_from_normalised


@dataclass(frozen=True, eq=False)
class DoubleSphere(CameraModel):
    """Focal lengths, principal point (px), ``xi`` (sphere offset) and ``alpha`` in [0, 1]."""

    fx: float
    fy: float
    cx: float
    cy: float
    xi: float
    alpha: float

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 <= self.alpha <= 1:
            raise ValueError(f"double sphere: alpha must be in [0, 1], got {self.alpha}")

    def _project_optical(self, directions: Array) -> tuple[Array, np.ndarray]:
        x, y, z = directions.T
        d1 = np.linalg.norm(directions, axis=1)
        zeta = self.xi * d1 + z
        d2 = np.sqrt(x * x + y * y + zeta * zeta)
        denominator = self.alpha * d2 + (1 - self.alpha) * zeta
        w1 = self.alpha / (1 - self.alpha) if self.alpha <= 0.5 else (1 - self.alpha) / self.alpha
        w2 = (w1 + self.xi) / np.sqrt(2 * w1 * self.xi + self.xi**2 + 1)
        ok = (z > -w2 * d1) & (denominator > 0)
        safe = np.where(ok, denominator, 1.0)
        return pixels_from_normalised(x / safe, y / safe, self.fx, self.fy, self.cx, self.cy), ok

    def _unproject_optical(self, pixels: Array) -> tuple[Array, np.ndarray]:
        mx, my = normalised_from_pixels(pixels, self.fx, self.fy, self.cx, self.cy)
        r2 = mx * mx + my * my
        inner = 1 - (2 * self.alpha - 1) * r2
        ok = inner >= 0
        mz = (1 - self.alpha**2 * r2) / (self.alpha * np.sqrt(np.where(ok, inner, 0.0)) + 1 - self.alpha)
        radicand = mz * mz + (1 - self.xi**2) * r2
        ok &= radicand >= 0
        factor = (mz * self.xi + np.sqrt(np.where(ok, radicand, 0.0))) / (mz * mz + r2)
        return np.stack([factor * mx, factor * my, factor * mz - self.xi], axis=1), ok
