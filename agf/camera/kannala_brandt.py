"""The Kannala-Brandt model (OpenCV's ``cv2.fisheye``; Kalibr's pinhole-equidistant).

``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` with the incidence
angle taken by ``atan2`` so the model holds beyond 90 deg, where OpenCV's ``atan(r)`` cannot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agf.camera.base import Array, CameraModel, normalised_from_pixels, pixels_from_normalised


@dataclass(frozen=True, eq=False)
class KannalaBrandt(CameraModel):
    """Focal lengths and principal point in px; ``k`` = (k1, k2, k3, k4)."""

    fx: float
    fy: float
    cx: float
    cy: float
    k: tuple[float, float, float, float]

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.k) != 4 or not np.all(np.isfinite(self.k)):
            raise ValueError(f"Kannala-Brandt: expected 4 finite coefficients k1..k4, got {self.k}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"Kannala-Brandt: focal lengths must be positive, got {self.fx}, {self.fy}")

    def _distort(self, theta: Array) -> tuple[Array, Array]:
        """theta_d and its derivative d theta_d / d theta."""
        k1, k2, k3, k4 = self.k
        t2 = theta * theta
        value = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        return value, slope

    def _project_optical(self, directions: Array) -> tuple[Array, np.ndarray]:
        x, y, z = directions.T
        rho = np.hypot(x, y)
        theta = np.arctan2(rho, z)
        theta_d, slope = self._distort(theta)
        scale = np.where(rho > 0, theta_d / np.where(rho > 0, rho, 1.0), 0.0)
        pixels = pixels_from_normalised(x * scale, y * scale, self.fx, self.fy, self.cx, self.cy)
        return pixels, slope > 0

    def _unproject_optical(self, pixels: Array) -> tuple[Array, np.ndarray]:
        mx, my = normalised_from_pixels(pixels, self.fx, self.fy, self.cx, self.cy)
        theta_d = np.hypot(mx, my)
        theta = theta_d.copy()
        for _ in range(20):
            value, slope = self._distort(theta)
            theta = theta - (value - theta_d) / slope
        value, slope = self._distort(theta)
        ok = np.isfinite(theta) & (slope > 0) & (np.abs(value - theta_d) < 1e-10) & (theta >= 0)
        scale = np.where(theta_d > 0, np.sin(theta) / np.where(theta_d > 0, theta_d, 1.0), 1.0)
        return np.stack([mx * scale, my * scale, np.cos(theta)], axis=1), ok
