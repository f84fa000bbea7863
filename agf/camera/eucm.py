"""The extended unified camera model (Khomutenko, Garcia and Martinet 2016; Kalibr's ``eucm``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agf.camera.base import Array, CameraModel, normalised_from_pixels, pixels_from_normalised


@dataclass(frozen=True, eq=False)
class ExtendedUnified(CameraModel):
    """Focal lengths, principal point (px), ``alpha`` in [0, 1] and ``beta`` > 0."""

    fx: float
    fy: float
    cx: float
    cy: float
    alpha: float
    beta: float

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 <= self.alpha <= 1 or self.beta <= 0:
            raise ValueError(f"EUCM: need alpha in [0, 1] and beta > 0, got {self.alpha}, {self.beta}")

    def _project_optical(self, directions: Array) -> tuple[Array, np.ndarray]:
        x, y, z = directions.T
        rho = np.sqrt(self.beta * (x * x + y * y) + z * z)
        denominator = self.alpha * rho + (1 - self.alpha) * z
        w = (1 - self.alpha) / self.alpha if self.alpha > 0.5 else self.alpha / (1 - self.alpha)
        ok = (z > -w * rho) & (denominator > 0)
        safe = np.where(ok, denominator, 1.0)
        return pixels_from_normalised(x / safe, y / safe, self.fx, self.fy, self.cx, self.cy), ok

    def _unproject_optical(self, pixels: Array) -> tuple[Array, np.ndarray]:
        mx, my = normalised_from_pixels(pixels, self.fx, self.fy, self.cx, self.cy)
        r2 = mx * mx + my * my
        gamma = 1 - self.alpha
        inner = 1 - (self.alpha - gamma) * self.beta * r2
        ok = inner >= 0
        mz = (1 - self.alpha**2 * self.beta * r2) / (self.alpha * np.sqrt(np.where(ok, inner, 0.0)) + gamma)
        return np.stack([mx, my, mz], axis=1), ok
