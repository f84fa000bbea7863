"""The unified (Mei) model with radial-tangential distortion (Kalibr's ``omni`` + ``radtan``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agf.camera.base import Array, CameraModel, normalised_from_pixels, pixels_from_normalised


@dataclass(frozen=True, eq=False)
class Unified(CameraModel):
    """Focal lengths, principal point (px), mirror parameter ``xi`` and ``radtan`` = (k1, k2, p1, p2)."""

    fx: float
    fy: float
    cx: float
    cy: float
    xi: float
    radtan: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.radtan) != 4 or not np.all(np.isfinite(self.radtan)):
            raise ValueError(f"unified: expected radtan (k1, k2, p1, p2), got {self.radtan}")
        if self.xi < 0:
            raise ValueError(f"unified: xi must be non-negative, got {self.xi}")

    def _distort(self, m: Array) -> tuple[Array, Array]:
        """Distorted normalised points (N, 2) and the Jacobian (N, 2, 2) of the distortion."""
        k1, k2, p1, p2 = self.radtan
        x, y = m[:, 0], m[:, 1]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        dradial = 2 * k1 + 4 * k2 * r2  # d radial / d x = dradial * x
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        jac = np.empty((m.shape[0], 2, 2))
        jac[:, 0, 0] = radial + x * dradial * x + 2 * p1 * y + 6 * p2 * x
        jac[:, 0, 1] = x * dradial * y + 2 * p1 * x + 2 * p2 * y
        jac[:, 1, 0] = y * dradial * x + 2 * p1 * x + 2 * p2 * y
        jac[:, 1, 1] = radial + y * dradial * y + 6 * p1 * y + 2 * p2 * x
        return np.stack([xd, yd], axis=1), jac

    def _limit(self) -> float:
        """Smallest z of a unit direction the model images uniquely."""
        return -1.0 / self.xi if self.xi > 1 else -self.xi

    def _project_optical(self, directions: Array) -> tuple[Array, np.ndarray]:
        unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
        denominator = unit[:, 2] + self.xi
        ok = (unit[:, 2] > self._limit()) & (denominator > 0)
        m = unit[:, :2] / np.where(ok, denominator, 1.0)[:, None]
        distorted, _ = self._distort(m)
        pixels = pixels_from_normalised(distorted[:, 0], distorted[:, 1], self.fx, self.fy, self.cx, self.cy)
        return pixels, ok

    def _unproject_optical(self, pixels: Array) -> tuple[Array, np.ndarray]:
        target = np.stack(normalised_from_pixels(pixels, self.fx, self.fy, self.cx, self.cy), axis=1)
        m = target.copy()
        for _ in range(30):
            distorted, jac = self._distort(m)
            m = m - np.linalg.solve(jac, (distorted - target)[:, :, None])[:, :, 0]
        distorted, _ = self._distort(m)
        ok = np.all(np.isfinite(m), axis=1) & (np.linalg.norm(distorted - target, axis=1) < 1e-10)
        r2 = np.sum(m * m, axis=1)
        radicand = 1 + (1 - self.xi**2) * r2
        ok &= radicand >= 0
        factor = (self.xi + np.sqrt(np.where(ok, radicand, 0.0))) / (1 + r2)
        optical = np.stack([factor * m[:, 0], factor * m[:, 1], factor - self.xi], axis=1)
        ok &= optical[:, 2] / np.maximum(np.linalg.norm(optical, axis=1), 1e-300) > self._limit()
        return optical, ok
