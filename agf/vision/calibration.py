"""Camera-to-fork calibration from images of a rectangular panel lying on the forks (paper section IV).

The panel (width W across the forks, depth D along them, thickness T) lies on the forks with its front
edge centred on the fork origin and its edges parallel to the fork axes, so its top edges are known in
the fork frame F. The camera pose in F (six parameters) is found as the pose that projects those edges
onto the image's edges:

1. a grid over roll, pitch and yaw (mount errors of a few degrees) around the nominal mount, scored by
   the image gradient across the projected edges;
2. Gauss-Newton over all six parameters on sub-pixel edge offsets along the projected edge normals,
   through the exact camera model (viewpoint shift included), with robust weights and search radii
   shrinking to 2 px.

Several images combine by a median with outlier rejection. The same fit through the camera without
its viewpoint shift shows the bias a naive calibration would carry (paper Table 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from agf.camera import CameraModel
from agf.config import ForkGeometry
from agf.errors import MeasurementError
from agf.geometry import Transform
from agf.vision.edges import project_with_normals, search_edges
from agf.vision.grey import grey_from_bgr

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Panel:
    """The calibration panel: width across the forks (fork Y), depth along them (fork X), thickness (m)."""

    width: float
    depth: float
    thickness: float = 0.005

    def edge_points(self, forks: ForkGeometry, spacing: float = 0.005) -> tuple[Array, Array]:
        """Points (N, 3) on the panel's top edges in the fork frame, and outward unit normals (N, 3)."""
        top = forks.thickness / 2 + self.thickness
        y = np.arange(-self.width / 2 + 0.02, self.width / 2 - 0.02, spacing)
        x = np.arange(-self.depth + 0.02, -0.02, spacing)
        edges = [
            (np.c_[0 * y, y, 0 * y + top], (1.0, 0.0, 0.0)),  # front
            (np.c_[0 * y - self.depth, y, 0 * y + top], (-1.0, 0.0, 0.0)),  # back
            (np.c_[x, 0 * x + self.width / 2, 0 * x + top], (0.0, 1.0, 0.0)),  # left
            (np.c_[x, 0 * x - self.width / 2, 0 * x + top], (0.0, -1.0, 0.0)),  # right
        ]
        return np.concatenate([p for p, _ in edges]), np.concatenate([np.tile(n, (len(p), 1)) for p, n in edges])

    def corners(self, forks: ForkGeometry) -> Array:
        top = forks.thickness / 2 + self.thickness
        w = self.width / 2
        return np.array([[0, w, top], [0, -w, top], [-self.depth, -w, top], [-self.depth, w, top]])


@dataclass(frozen=True)
class CalibrationConfig:
    """Tuning of the panel fit (SI units)."""

    angle_range: float = math.radians(4.0)
    angle_step: float = math.radians(1.0)
    radii_px: tuple[float, ...] = (16.0, 10.0, 6.0, 4.0, 3.0, 2.0, 2.0, 2.0)
    max_residual_px: float = 0.8
    min_inliers: float = 0.9
    starts: int = 3
    outlier_mm: float = 3.0
    outlier_deg: float = 0.1


# The fit through the camera without its viewpoint shift is a report of what a naive calibration would
# find, not a calibration: its model is wrong by design, so it is accepted with looser limits.
WITHOUT_SHIFT = CalibrationConfig(angle_range=0.0, min_inliers=0.5, max_residual_px=3.0)


@dataclass(frozen=True)
class PanelFit:
    """The camera pose that one image gives, with its evidence."""

    camera_in_fork: Transform
    residual_px: float
    inliers: float
    points_px: Array
    offsets_px: Array


def fit_panel(
    image: NDArray,
    camera: CameraModel,
    panel: Panel,
    forks: ForkGeometry,
    nominal: Transform,
    config: CalibrationConfig = CalibrationConfig(),
) -> PanelFit:
    """``camera_in_fork`` from one image of the panel; :class:`MeasurementError` with the reason if refused."""
    gray = grey_from_bgr(image)
    if gray.shape != (camera.height, camera.width):
        raise MeasurementError(
            f"image is {gray.shape[1]} x {gray.shape[0]}, the camera {camera.width} x {camera.height}"
        )
    smooth = cv2.GaussianBlur(gray.astype(np.float32), (0, 0), 1.0)
    points, normals = panel.edge_points(forks)
    fits = []
    for start in _grid_starts(smooth, camera, points, normals, nominal, config):
        try:
            fits.append(_gauss_newton(smooth, camera, points, normals, start, config))
        except MeasurementError:
            continue
    if not fits:
        raise MeasurementError("panel not found: too few of its edges are in view")
    # The start that ends with the most edge points agreeing, then the smallest residual.
    pose, residual, inliers, p0, offsets = max(fits, key=lambda f: (round(f[2], 2), -f[1]))
    _, visible = camera.project(pose.inverse().apply(panel.corners(forks)))
    if not visible.all():
        raise MeasurementError("the panel is partly out of view: a corner is outside the image")
    if inliers < config.min_inliers:
        raise MeasurementError(f"panel not found: only {inliers:.0%} of its edges match image edges")
    if residual > config.max_residual_px:
        raise MeasurementError(f"panel edges fit poorly: residual {residual:.2f} px > {config.max_residual_px} px")
    return PanelFit(pose, residual, inliers, p0, offsets)


def _params(T: Transform) -> Array:
    yaw, pitch, roll = T.euler
    return np.r_[T.translation, roll, pitch, yaw]


def _transform(p: Array) -> Transform:
    return Transform.from_euler(p[0], p[1], p[2], p[3], p[4], p[5])


def _grid_starts(smooth, camera, points, normals, nominal: Transform, config: CalibrationConfig) -> list[Transform]:
    """The best few roll/pitch/yaw grid nodes, by the image gradient across the projected edges."""
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)
    angles = np.arange(-config.angle_range, config.angle_range + 1e-9, config.angle_step)
    base = _params(nominal)
    scored = []
    for droll in angles:
        for dpitch in angles:
            for dyaw in angles:
                pose = _transform(base + np.r_[0, 0, 0, droll, dpitch, dyaw])
                scored.append((_edge_score(gx, gy, camera, pose, points, normals), pose))
    scored.sort(key=lambda item: -item[0])
    return [pose for _, pose in scored[: config.starts]]


def _edge_score(gx, gy, camera, pose: Transform, points, normals) -> float:
    fork_in_camera = pose.inverse()
    p0, d, valid = project_with_normals(camera, fork_in_camera, points, normals)
    maps = (p0[:, 0:1].astype(np.float32), p0[:, 1:2].astype(np.float32))
    g = np.c_[cv2.remap(gx, *maps, cv2.INTER_LINEAR), cv2.remap(gy, *maps, cv2.INTER_LINEAR)]
    falling = -np.sum(g * d, axis=1)  # bright panel inside, darker outside
    return float(np.mean(np.where(valid, np.clip(falling, 0, None), 0.0)))


def _gauss_newton(smooth, camera, points, normals, start: Transform, config: CalibrationConfig):
    params = _params(start)
    steps = np.r_[1e-3, 1e-3, 1e-3, np.radians([0.02, 0.02, 0.02])]
    residual, inliers, p0, offsets = math.inf, 0.0, np.zeros((0, 2)), np.zeros(0)
    for radius in config.radii_px:
        fork_in_camera = _transform(params).inverse()
        p0, d, valid = project_with_normals(camera, fork_in_camera, points, normals)
        edges = search_edges(smooth, p0, d, radius)
        J = np.empty((len(points), 6))
        for k in range(6):
            moved = _transform(params + np.eye(6)[k] * steps[k]).inverse()
            pk, _ = camera.project(moved.apply(points))
            J[:, k] = np.sum((pk - p0) * d, axis=1) / steps[k]
        usable = valid & edges.valid
        if usable.sum() < 20:
            raise MeasurementError("panel not found: too few of its edges are in view")
        scale = max(1.4826 * float(np.median(np.abs(edges.offset[usable]))), radius / 4)
        c = 4.685 * scale
        w = np.where(usable & (np.abs(edges.offset) < c), (1 - (edges.offset / c) ** 2) ** 2, 0.0)
        sw = np.sqrt(w)
        delta = np.linalg.lstsq(J * sw[:, None], edges.offset * sw, rcond=None)[0]
        params = params + delta
        inl = w > 0
        offsets = edges.offset - J @ delta
        residual = float(np.sqrt(np.mean(offsets[inl] ** 2))) if inl.any() else math.inf
        inliers = float(np.mean(inl[valid])) if valid.any() else 0.0
    return _transform(params), residual, inliers, p0, offsets


@dataclass(frozen=True)
class Calibration:
    """The combined answer over several images."""

    camera_in_fork: Transform
    without_shift: Transform | None
    residual_px: float
    spread: dict[str, float]
    used: list[int]
    rejected: dict[int, str]
    fits: list[PanelFit]


def calibrate(
    images: list[NDArray],
    camera: CameraModel,
    panel: Panel,
    forks: ForkGeometry,
    nominal: Transform,
    config: CalibrationConfig = CalibrationConfig(),
) -> Calibration:
    """Fit every image, reject refused and outlying ones, combine the rest by their median."""
    fits: dict[int, PanelFit] = {}
    rejected: dict[int, str] = {}
    for i, image in enumerate(images):
        try:
            fits[i] = fit_panel(image, camera, panel, forks, nominal, config)
        except MeasurementError as exc:
            rejected[i] = str(exc)
    if not fits:
        raise MeasurementError(
            "no usable panel image: " + "; ".join(f"image {i + 1}: {r}" for i, r in rejected.items())
        )
    vectors = {i: _params(f.camera_in_fork) for i, f in fits.items()}
    median = np.median(np.array(list(vectors.values())), axis=0)
    tolerance = np.r_[np.full(3, config.outlier_mm / 1e3), np.full(3, math.radians(config.outlier_deg))]
    for i, v in list(vectors.items()):
        if np.any(np.abs(v - median) > tolerance) and len(vectors) > 2:
            rejected[i] = "outlier: disagrees with the other images beyond 3 mm / 0.1 deg"
            del vectors[i]
    stacked = np.array(list(vectors.values()))
    combined = _transform(np.mean(stacked, axis=0))
    spread = dict(
        zip(
            ("x_mm", "y_mm", "z_mm", "roll_deg", "pitch_deg", "yaw_deg"),
            np.r_[np.std(stacked[:, :3], axis=0) * 1e3, np.degrees(np.std(stacked[:, 3:], axis=0))],
            strict=True,
        )
    )
    without = None
    if camera.shift is not None:
        naive = [
            fit_panel(images[i], camera.without_viewpoint_shift(), panel, forks, fits[i].camera_in_fork, WITHOUT_SHIFT)
            for i in vectors
        ]
        without = _transform(np.mean([_params(f.camera_in_fork) for f in naive], axis=0))
    residual = float(np.sqrt(np.mean([fits[i].residual_px ** 2 for i in vectors])))
    return Calibration(
        combined,
        without,
        residual,
        {k: float(v) for k, v in spread.items()},
        sorted(vectors),
        rejected,
        [fits[i] for i in sorted(vectors)],
    )
