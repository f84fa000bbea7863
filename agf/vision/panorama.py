"""Equirectangular panoramas of the viewing sphere around any unit axis.

The paper's "pseudo-vertical" panorama: lines in 3D parallel to the panorama axis image as great
circles through the axis, which are vertical columns here. Longitude runs around the axis from a
reference direction (column 0 at ``lon_range[0]``, increasing to the right when the axis points
up), latitude from the equator (row 0 at ``lat_range[1]``, the top).

Frames: directions are unit vectors in the camera frame C. Pixels are (u, v) = (column, row).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from agf.camera.base import Array, CameraModel, as_pixels, as_points
from agf.camera.grid import STEPS, pixels_from_grid

# Lattice cells of at most 0.32 deg keep interpolated maps within 0.005 px of the projection on our lenses
# (tests/unit/test_camera_grid.py); coarser panoramas are projected on more of their pixels.
_MAX_CELL = math.radians(0.32)


@dataclass(frozen=True)
class Panorama:
    """An equirectangular grid around ``axis`` (unit, camera frame); build it with :meth:`around`."""

    axis: tuple[float, float, float]
    reference: tuple[float, float, float]
    width: int
    height: int
    lon_range: tuple[float, float] = (-math.pi, math.pi)
    lat_range: tuple[float, float] = (-math.pi / 2, math.pi / 2)

    @classmethod
    def around(
        cls,
        axis: ArrayLike,
        width: int,
        height: int,
        reference: ArrayLike | None = None,
        lon_range: tuple[float, float] = (-math.pi, math.pi),
        lat_range: tuple[float, float] = (-math.pi / 2, math.pi / 2),
    ) -> Panorama:
        """Panorama around ``axis`` with longitude 0 towards ``reference`` (made orthogonal to the axis).

        The default reference is camera X (forward), or camera Z when the axis is near X.
        """
        a = np.asarray(axis, dtype=float)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-9:
            raise ValueError(f"panorama axis: expected a non-zero 3-vector, got {axis}")
        a = a / np.linalg.norm(a)
        if reference is None:
            reference = (1.0, 0.0, 0.0) if abs(a[0]) < 0.9 else (0.0, 0.0, 1.0)
        r = np.asarray(reference, dtype=float)
        r = r - a * (r @ a)
        if np.linalg.norm(r) < 1e-6:
            raise ValueError(f"panorama reference {reference} is parallel to the axis {axis}")
        if width <= 0 or height <= 0:
            raise ValueError(f"panorama size must be positive, got {width} x {height}")
        if not (lon_range[0] < lon_range[1] and -math.pi / 2 <= lat_range[0] < lat_range[1] <= math.pi / 2):
            raise ValueError(f"panorama ranges invalid: lon {lon_range}, lat {lat_range} (rad)")
        r = r / np.linalg.norm(r)
        return cls(tuple(a), tuple(r), int(width), int(height), tuple(lon_range), tuple(lat_range))

    def basis(self) -> Array:
        """Rows e1 (longitude 0), e2 (longitude +90 deg), axis (3, 3, read-only): the panorama frame in camera
        coordinates."""
        return _basis(self.axis, self.reference)

    def angles_from_pixels(self, pixels: ArrayLike) -> tuple[Array, Array]:
        """Longitude and latitude (rad) at pixel centres (N, 2)."""
        pixels = as_pixels(pixels)
        (lon0, lon1), (lat0, lat1) = self.lon_range, self.lat_range
        lon = lon0 + (pixels[:, 0] + 0.5) * (lon1 - lon0) / self.width
        lat = lat1 - (pixels[:, 1] + 0.5) * (lat1 - lat0) / self.height
        return lon, lat

    def directions_from_pixels(self, pixels: ArrayLike) -> Array:
        """Unit directions (N, 3, camera frame) of panorama pixels (N, 2)."""
        lon, lat = self.angles_from_pixels(pixels)
        local = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=1)
        return local @ self.basis()

    def pixels_from_directions(self, directions: ArrayLike) -> Array:
        """Panorama pixels (N, 2) of camera-frame directions (N, 3); the inverse of the above."""
        local = as_points(directions, "directions") @ self.basis().T
        lon = np.arctan2(local[:, 1], local[:, 0])
        lat = np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1]))
        (lon0, lon1), (lat0, lat1) = self.lon_range, self.lat_range
        u = (lon - lon0) * self.width / (lon1 - lon0) - 0.5
        v = (lat1 - lat) * self.height / (lat1 - lat0) - 0.5
        return np.stack([u, v], axis=1)

    def pixel_size(self) -> float:
        """Angular size (rad) of one panorama pixel along the equator."""
        return (self.lon_range[1] - self.lon_range[0]) / self.width


@functools.lru_cache(maxsize=64)
def _basis(axis: tuple[float, float, float], reference: tuple[float, float, float]) -> Array:
    """:meth:`Panorama.basis`, cached: the pitch's Hough transform asks it of the same few panoramas 5,600 times
    over the bench's 34 frames, and its cross product cost 0.3 s of 18 profiled."""
    a, e1 = np.array(axis), np.array(reference)
    basis = np.stack([e1, np.cross(e1, a), a])
    basis.setflags(write=False)
    return basis


@functools.lru_cache(maxsize=32)
def panorama_maps(camera: CameraModel, panorama: Panorama) -> tuple[NDArray, NDArray, NDArray[np.bool_]]:
    """Fixed-point ``cv2.remap`` maps from ``panorama`` pixels into ``camera`` pixels, and validity.

    Cached per (camera, panorama): cameras hash by identity, panoramas by value. The camera is asked on
    a lattice of panorama pixels only (:func:`~agf.camera.grid.pixels_from_grid`).
    """
    per_pixel = max(panorama.pixel_size(), (panorama.lat_range[1] - panorama.lat_range[0]) / panorama.height)
    step = max((s for s in STEPS if s * per_pixel <= _MAX_CELL), default=1)
    pixels, valid = pixels_from_grid(camera, panorama.directions_from_pixels, panorama.width, panorama.height, step)
    fixed_xy, fixed_frac = cv2.convertMaps(pixels, None, cv2.CV_16SC2)
    return fixed_xy, fixed_frac, valid


def render_panorama(image: NDArray, camera: CameraModel, panorama: Panorama) -> tuple[NDArray, NDArray[np.bool_]]:
    """The panorama of a fisheye ``image`` (bilinear) and its validity mask (pixels outside the lens)."""
    if image.shape[:2] != (camera.height, camera.width):
        raise ValueError(
            f"image is {image.shape[1]} x {image.shape[0]} pixels "
            f"but the camera model is {camera.width} x {camera.height}"
        )
    fixed_xy, fixed_frac, valid = panorama_maps(camera, panorama)
    out = cv2.remap(image, fixed_xy, fixed_frac, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return out, valid
