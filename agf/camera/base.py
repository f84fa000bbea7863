"""The camera-model protocol shared by every lens model.

A model is composed of two pieces, as in kornia's camera models:

* a central projection (the lens polynomial or sphere model) between ray directions and pixels,
  written by each model in its own optical frame (x right, y down, z forward) as the pair
  ``_project_optical`` / ``_unproject_optical``;
* an optional :class:`~agf.camera.viewpoint_shift.ViewpointShift`: the ray of a pixel at incidence
  angle theta starts at ``(offset(theta), 0, 0)`` in the camera frame instead of at the origin.

The public methods work in the camera frame C of DESIGN.md (X optical axis, Y left, Z up) and
the image convention u right (column), v down (row). They check shapes once for every model.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agf.camera.viewpoint_shift import ViewpointShift

Array = NDArray[np.float64]

# Rows map camera-frame vectors (X fwd, Y left, Z up) to optical-frame ones (x right, y down, z fwd).
OPTICAL_FROM_CAMERA = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def as_points(points: ArrayLike, name: str = "points") -> Array:
    """Validate an (N, 3) array of finite points or directions."""
    array = np.asarray(points, dtype=float)
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {array.shape}")
    return array


def as_pixels(pixels: ArrayLike) -> Array:
    """Validate an (N, 2) array of (u, v) pixel coordinates."""
    array = np.asarray(pixels, dtype=float)
    if array.ndim != 2 or array.shape[1] != 2:
        raise ValueError(f"pixels: expected shape (N, 2) of (u, v), got {array.shape}")
    return array


def pixels_from_normalised(mx: Array, my: Array, fx: float, fy: float, cx: float, cy: float) -> Array:
    """Pixels (N, 2) of normalised image coordinates through focal lengths and principal point (px)."""
    return np.stack([fx * mx + cx, fy * my + cy], axis=1)


def normalised_from_pixels(pixels: Array, fx: float, fy: float, cx: float, cy: float) -> tuple[Array, Array]:
    """The inverse of :func:`pixels_from_normalised`."""
    return (pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy


def incidence_angle(directions: Array) -> Array:
    """Angle (rad) between camera-frame directions (N, 3) and the optical axis X."""
    return np.arctan2(np.hypot(directions[:, 1], directions[:, 2]), directions[:, 0])


@dataclass(frozen=True, eq=False)
class CameraModel(ABC):
    """Base of every camera model; instances hash by identity so derived maps can be cached.

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    max_incidence : float
        Largest incidence angle (rad) the lens images; rays beyond it are invalid.
    shift : ViewpointShift or None
        The entrance pupil's travel along the optical axis; None for a single viewpoint.
    """

    width: int
    height: int
    max_incidence: float
    shift: ViewpointShift | None

    def __post_init__(self) -> None:
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"image size must be positive, got {self.width} x {self.height}")
        if not 0 < self.max_incidence <= np.pi:
            raise ValueError(f"max_incidence must be in (0, pi] rad, got {self.max_incidence}")

    # -- the protocol -----------------------------------------------------------------------------
    def project(self, points: ArrayLike) -> tuple[Array, NDArray[np.bool_]]:
        """Pixels (N, 2) of camera-frame points (N, 3, m) and a validity mask (N,).

        With a viewpoint shift, each point is imaged by the ray whose shifted origin lies on its
        line of sight; its incidence angle is solved for (Newton, below 1e-10 rad).
        """
        points = as_points(points)
        directions = points if self.shift is None else self._shifted_directions(points)
        return self.project_directions(directions)

    def unproject(self, pixels: ArrayLike) -> tuple[Array, Array]:
        """Ray origins (N, 3, m) and unit directions (N, 3) in the camera frame for pixels (N, 2).

        Pixels the model cannot lift get NaN directions; :meth:`valid_pixels` is the mask.
        """
        pixels = as_pixels(pixels)
        optical, ok = self._unproject_optical(pixels)
        directions = optical @ OPTICAL_FROM_CAMERA  # inverse of an orthonormal matrix is its transpose
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        directions[~ok] = np.nan
        return self.origins(directions), directions

    def project_directions(self, directions: ArrayLike) -> tuple[Array, NDArray[np.bool_]]:
        """Pixels (N, 2) at which rays of camera-frame directions (N, 3) are imaged, and validity."""
        directions = as_points(directions, "directions")
        pixels, ok = self._project_optical(directions @ OPTICAL_FROM_CAMERA.T)
        valid = ok & (incidence_angle(directions) <= self.max_incidence) & self._inside(pixels)
        return pixels, valid

    def origins(self, directions: Array) -> Array:
        """Ray origins (N, 3) for unit directions (N, 3): the shifted entrance pupil."""
        origins = np.zeros_like(directions)
        if self.shift is not None:
            origins[:, 0] = self.shift.offset(incidence_angle(directions))
        return origins

    def valid_pixels(self, pixels: ArrayLike) -> NDArray[np.bool_]:
        """Mask (N,) of pixels inside the image whose ray lies inside the field of view."""
        pixels = as_pixels(pixels)
        optical, ok = self._unproject_optical(pixels)
        directions = optical @ OPTICAL_FROM_CAMERA
        with np.errstate(invalid="ignore"):
            inside_fov = incidence_angle(directions) <= self.max_incidence
        return ok & inside_fov & self._inside(pixels)

    def without_viewpoint_shift(self) -> CameraModel:
        """The same lens treated as a single-viewpoint camera (what a naive calibration assumes)."""
        return dataclasses.replace(self, shift=None)

    # -- for models -------------------------------------------------------------------------------
    @abstractmethod
    def _project_optical(self, directions: Array) -> tuple[Array, NDArray[np.bool_]]:
        """Pixels (N, 2) of optical-frame directions (N, 3, any norm) and where the model holds."""

    @abstractmethod
    def _unproject_optical(self, pixels: Array) -> tuple[Array, NDArray[np.bool_]]:
        """Optical-frame directions (N, 3, any norm) of pixels (N, 2) and where the model holds."""

    # -- internals --------------------------------------------------------------------------------
    def _inside(self, pixels: Array) -> NDArray[np.bool_]:
        u, v = pixels[:, 0], pixels[:, 1]
        with np.errstate(invalid="ignore"):
            return (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)

    def _shifted_directions(self, points: Array) -> Array:
        """Directions from each point's own shifted pupil: solve theta = atan2(rho, x - s(theta))."""
        rho = np.hypot(points[:, 1], points[:, 2])
        rho2 = rho**2  # out of the loop: the solve runs 1,100 times over the bench's 34 frames
        x = points[:, 0]
        theta = np.arctan2(rho, x)
        for _ in range(30):
            s, ds = self.shift.offset_and_derivative(theta)
            dx = x - s
            f = theta - np.arctan2(rho, dx)
            df = 1.0 - rho * ds / (rho2 + dx**2)
            step = f / df
            theta = theta - step
            if np.all(np.abs(step) < 1e-10):  # 1e-10 rad is below 1e-7 px on any lens here
                break
        directions = points.copy()
        directions[:, 0] = x - self.shift.offset(theta)
        return directions
