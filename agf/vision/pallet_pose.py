"""Pallet detection and pose (position and yaw, at a given pitch) from one fisheye image.

The method of the paper's references [1][2]: project the fisheye image onto a virtual plane at a
hypothesised pose of the pallet's front face and compare it with the face model; keep the pose of
maximum similarity. Done in three steps:

1. Coarse: for each yaw hypothesis, a virtual pinhole view looking along the pallet's X axis (the
   face is fronto-parallel there, so a depth is a scale and y, z are a shift) from a low pyramid
   level; normalised cross-correlation with the face raster at every scale (``cv2.matchTemplate``).
2. Fine: from the best distinct candidates, a Gauss-Newton fit of x, y, z, yaw to sub-pixel edges
   found along the projected normals of the pocket boundaries, through the exact camera model
   (viewpoint shift included).
3. Verdict: the normalised cross-correlation of the face projected at the fitted pose, its margin
   over the best distinct runner-up, the edge residual, and whether the face is in view and not
   hidden by the forks. Anything unconvincing is a :class:`MeasurementError` with the reason.

The pose is parametrised in the fork frame F (x, y, z, yaw; pitch given) and mapped to the camera
with the commissioning calibration ``camera_in_fork``.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from agf.camera.base import CameraModel
from agf.config import ForkGeometry, SearchVolume
from agf.errors import MeasurementError
from agf.geometry import Transform, matrix_from_euler
from agf.vision.edges import project_with_normals, search_edges
from agf.vision.face_model import FaceModel

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PoseSearchConfig:
    """Tuning of the pose search (SI units)."""

    coarse_pixel: float = 0.02  # m per virtual pixel at the middle search depth
    pyramid_level: int = 3
    fine_pixel: float = 0.005  # second scan, around each coarse candidate
    fine_level: int = 1
    fine_window: tuple[float, float, float] = (0.12, 0.04, 0.12)  # m around a coarse candidate (x, y, z)
    fine_scale_step_px: float = 3.0  # template width change between scales of the fine scan
    min_group_inliers: float = 0.6  # fraction of each edge group (top, bottom, sides) that must fit
    yaw_step: float = math.radians(4.0)
    prior_window: float = 0.3  # m around a prior in x, y, z
    prior_yaw_window: float = math.radians(10.0)
    candidates: int = 3
    min_score: float = 0.5
    min_margin: float = 0.1
    max_residual_px: float = 1.5
    max_occluded: float = 0.25
    edge_spacing: float = 0.006
    radii_px: tuple[float, ...] = (4.0, 3.0, 2.0, 2.0, 2.0)


@dataclass(frozen=True)
class PoseEstimate:
    """A pallet pose found in the image, with the evidence for it."""

    pallet_in_camera: Transform
    pallet_in_fork: Transform
    score: float
    margin: float
    residual_px: float
    edges_used: int
    occluded: float
    group_inliers: float
    sigma: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # x, y, z (m), yaw (rad), from the fit
    timing_ms: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class _Params:
    """Pose parameters in the fork frame: position (m), yaw (rad), fixed pitch (rad)."""

    x: float
    y: float
    z: float
    yaw: float
    pitch: float

    def transform(self) -> Transform:
        return Transform.from_euler(self.x, self.y, self.z, 0.0, self.pitch, self.yaw)

    def moved(self, delta: Array) -> _Params:
        return _Params(self.x + delta[0], self.y + delta[1], self.z + delta[2], self.yaw + delta[3], self.pitch)


def estimate_pallet_pose(
    image: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    face: FaceModel,
    volume: SearchVolume,
    *,
    prior: Transform | None = None,
    pitch: float | None = None,
    forks: ForkGeometry | None = None,
    config: PoseSearchConfig = PoseSearchConfig(),
    check: bool = True,
) -> PoseEstimate:
    """Find the pallet's front face; see the module docstring.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 array
        The fisheye frame, of the camera's size.
    camera_in_fork : Transform
        Commissioning calibration.
    face : FaceModel
        Front face of the expected pallet type.
    volume : SearchVolume
        Where to look (fork frame) when there is no prior.
    prior : Transform, optional
        ``pallet_in_fork`` known to about +-0.3 m and +-10 deg (approach phase); narrows the search.
    pitch : float, optional
        Pallet pitch (rad) to assume; default the prior's, else 0.
    check : bool
        Apply :func:`check_pose_estimate`; a caller iterating pose and pitch checks only its final pose.

    Raises
    ------
    MeasurementError
        When no convincing face is found, it is ambiguous, partly out of view or hidden by the forks.
    """
    timing: dict[str, float] = {}
    start = time.perf_counter()
    gray = _gray(image, camera)
    if pitch is None:
        pitch = prior.euler[1] if prior is not None else 0.0
    box = _search_box(volume, prior, pitch, config)
    coarse = _scan(
        _pyramid(gray, config.pyramid_level),
        config.pyramid_level,
        config.coarse_pixel,
        1.0,
        camera,
        camera_in_fork,
        face,
        box,
    )
    fine_image = _pyramid(gray, config.fine_level)
    candidates = [
        _rescan(fine_image, camera, camera_in_fork, face, params, config) for _, params in coarse[: config.candidates]
    ]
    candidates = sorted([c for c in candidates if c is not None], key=lambda c: -c[0]) + coarse[config.candidates :]
    timing["coarse"] = (time.perf_counter() - start) * 1e3
    if not candidates:
        raise MeasurementError("no pallet front face found in the search volume")

    t = time.perf_counter()
    smooth = cv2.GaussianBlur(gray, (0, 0), 1.0)
    points, normals, groups = face.edge_points(config.edge_spacing)
    fitted = []
    for _, params in candidates[: config.candidates]:
        fit = _refine(smooth, camera, camera_in_fork, params, points, normals, groups, forks, config)
        if fit is not None:
            fitted.append((_face_similarity(gray, camera, camera_in_fork, face, fit[0]), *fit))
    timing["refine"] = (time.perf_counter() - t) * 1e3
    if not fitted:
        raise MeasurementError("the pallet front face could not be fitted to image edges")
    fitted.sort(key=lambda f: -f[0])
    score, params, residual, used, occluded, worst_group, sigma = fitted[0]
    margin = _margin(score, params, fitted[1:], candidates, face, camera_in_fork.translation)
    timing["total"] = (time.perf_counter() - start) * 1e3
    pallet_in_fork = params.transform()
    estimate = PoseEstimate(
        camera_in_fork.inverse() @ pallet_in_fork,
        pallet_in_fork,
        score,
        margin,
        residual,
        used,
        occluded,
        worst_group,
        sigma,
        timing,
    )
    if check:
        check_pose_estimate(estimate, camera, face, config)
    return estimate


# -- search space ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Box:
    low: Array  # x, y, z (m)
    high: Array
    yaws: tuple[float, ...]
    pitch: float


def _search_box(volume: SearchVolume, prior: Transform | None, pitch: float, config: PoseSearchConfig) -> _Box:
    if prior is None:
        low = np.array([volume.x_min, volume.y_min, volume.z_min])
        high = np.array([volume.x_max, volume.y_max, volume.z_max])
        yaw_low, yaw_high = -volume.yaw_max, volume.yaw_max
    else:
        centre = prior.translation
        low, high = centre - config.prior_window, centre + config.prior_window
        yaw = prior.euler[0]
        yaw_low, yaw_high = yaw - config.prior_yaw_window, yaw + config.prior_yaw_window
    n = max(int(math.ceil((yaw_high - yaw_low) / config.yaw_step)) + 1, 1)
    return _Box(low, high, tuple(np.linspace(yaw_low, yaw_high, n)), pitch)


# -- coarse stage ---------------------------------------------------------------------------------


def _scan(
    level_image: NDArray[np.float32],
    level: int,
    pixel: float,
    scale_step_px: float,
    camera: CameraModel,
    camera_in_fork: Transform,
    face: FaceModel,
    box: _Box,
) -> list[tuple[float, _Params]]:
    """(score, params) of the best normalised-correlation peaks over ``box``, best first, one per place."""
    fork_in_camera = camera_in_fork.inverse()
    corners = np.array(
        [
            [x, y, z]
            for x in (box.low[0], box.high[0])
            for y in (box.low[1], box.high[1])
            for z in (box.low[2], box.high[2])
        ]
    )
    found: list[tuple[float, _Params]] = []
    for yaw in box.yaws:
        R_cv = fork_in_camera.rotation @ matrix_from_euler(yaw, box.pitch, 0.0)
        origins_v = fork_in_camera.apply(corners) @ R_cv  # pallet origins in the view frame
        f = float(np.mean(origins_v[:, 0])) / pixel
        window = _window(origins_v, face, f)
        view = _view(level_image, camera, _key(R_cv), window, f, level)
        step = scale_step_px / face.width
        for scale in np.arange(f / np.max(origins_v[:, 0]), f / np.min(origins_v[:, 0]) + step / 2, step):
            found += _peaks(view, face, scale, f, window, R_cv, camera_in_fork, yaw, box)
    found.sort(key=lambda c: -c[0])
    return _distinct(found, face, camera_in_fork.translation)


def _rescan(fine_image, camera, camera_in_fork, face, params: _Params, config: PoseSearchConfig):
    """The best (score, params) of a finer scan around one coarse candidate, or None."""
    window = np.array(config.fine_window)
    centre = np.array([params.x, params.y, params.z])
    yaws = (params.yaw - config.yaw_step / 2, params.yaw, params.yaw + config.yaw_step / 2)
    box = _Box(centre - window, centre + window, yaws, params.pitch)
    found = _scan(
        fine_image, config.fine_level, config.fine_pixel, config.fine_scale_step_px, camera, camera_in_fork, face, box
    )
    return found[0] if found else None


def _window(origins_v: Array, face: FaceModel, f: float) -> tuple[int, int, int, int]:
    """Virtual-image rectangle (col0, row0, width, height) covering every face in the search box."""
    offsets = np.array([[0.0, y, z] for y in (-face.width / 2, face.width / 2) for z in (face.z_bottom, face.z_top)])
    points = (origins_v[:, None, :] + offsets[None]).reshape(-1, 3)
    cols = -f * points[:, 1] / points[:, 0]
    rows = -f * points[:, 2] / points[:, 0]
    col0, row0 = int(np.floor(cols.min())) - 3, int(np.floor(rows.min())) - 3
    return col0, row0, int(np.ceil(cols.max())) - col0 + 4, int(np.ceil(rows.max())) - row0 + 4


def _key(R: Array) -> tuple[float, ...]:
    return tuple(np.round(R, 9).ravel().tolist())


def _view(level: NDArray[np.float32], camera: CameraModel, R_key: tuple, window: tuple, f: float, lvl: int):
    map_u, map_v = _view_maps(camera, R_key, window, round(f, 6), lvl)
    return cv2.remap(level, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


@functools.lru_cache(maxsize=256)
def _view_maps(camera: CameraModel, R_key: tuple, window: tuple, f: float, lvl: int) -> tuple[NDArray, NDArray]:
    """Maps of a virtual pinhole view (frame V rotated by R_key from the camera) into pyramid level ``lvl``."""
    col0, row0, width, height = window
    rows, cols = np.mgrid[row0 : row0 + height, col0 : col0 + width].astype(float)
    directions_v = np.stack([np.ones_like(cols), -cols / f, -rows / f], axis=-1).reshape(-1, 3)
    R_cv = np.array(R_key).reshape(3, 3)
    pixels, _ = camera.project_directions(directions_v @ R_cv.T)
    scale = 2.0**lvl
    pixels = (pixels + 0.5) / scale - 0.5
    shape = (height, width)
    return pixels[:, 0].reshape(shape).astype(np.float32), pixels[:, 1].reshape(shape).astype(np.float32)


def _peaks(view, face, scale, f, window, R_cv, camera_in_fork, yaw, box) -> list[tuple[float, _Params]]:
    pixel = 1.0 / scale
    template, ys, zs = face.raster(pixel)
    if template.shape[0] < 3 or template.shape[0] >= view.shape[0] or template.shape[1] >= view.shape[1]:
        return []
    response = cv2.matchTemplate(view, template, cv2.TM_CCOEFF_NORMED)
    local_max = response >= cv2.dilate(response, np.ones((5, 5), np.uint8))
    rows, cols = np.nonzero(local_max & (response > 0.2))
    if rows.size == 0:
        return []
    order = np.argsort(-response[rows, cols])[:4]
    depth = f / scale
    out = []
    y_mid, z_mid = (ys[0] + ys[-1]) / 2, (zs[0] + zs[-1]) / 2
    for r, c in zip(rows[order], cols[order], strict=True):
        col_c = c + (template.shape[1] - 1) / 2 + window[0]
        row_c = r + (template.shape[0] - 1) / 2 + window[1]
        origin_v = np.array([depth, -col_c * depth / f - y_mid, -row_c * depth / f - z_mid])
        x, y, z = camera_in_fork.apply(R_cv @ origin_v)
        if np.all((np.array([x, y, z]) >= box.low - 0.05) & (np.array([x, y, z]) <= box.high + 0.05)):
            out.append((float(response[r, c]), _Params(x, y, z, yaw, box.pitch)))
    return out


def _distinct(found: list[tuple[float, _Params]], face: FaceModel, eye: Array) -> list[tuple[float, _Params]]:
    """Keep the best candidate of each place in the image (along one line of sight, depth is a scale)."""
    kept: list[tuple[float, _Params]] = []
    for score, p in found:
        if all(not _same_place(p, q, face, eye) for _, q in kept):
            kept.append((score, p))
    return kept


def _same_place(p: _Params, q: _Params, face: FaceModel, eye: Array) -> bool:
    """Whether two hypotheses put the face centre within a sixth of the face's width in the image."""
    a = np.array([p.x, p.y, p.z]) - eye
    b = np.array([q.x, q.y, q.z]) - eye
    angle = math.acos(float(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0)))
    return angle < face.width / 6 / max(np.linalg.norm(a), np.linalg.norm(b))


# -- fine stage -----------------------------------------------------------------------------------


def _refine(smooth, camera, camera_in_fork, params, points, normals, groups, forks, config):
    """Gauss-Newton on pocket-edge offsets.

    Returns (params, residual_px, edges_used, occluded, worst group inlier fraction, sigma) or None. Each edge
    group (pocket tops, bottoms, sides) weighs the same in total, so the many horizontal edge points
    cannot outvote the few vertical ones that fix the scale, hence the depth.
    """
    fork_in_camera = camera_in_fork.inverse()
    steps = np.array([1e-3, 1e-3, 1e-3, math.radians(0.05)])
    residual, used, occluded, worst = math.inf, 0, 0.0, 0.0
    for radius in config.radii_px:
        T = fork_in_camera @ params.transform()
        p0, direction, valid = project_with_normals(camera, T, points, normals)
        edges = search_edges(smooth, p0, direction, radius)
        J = np.empty((len(points), 4))
        for k in range(4):
            moved = fork_in_camera @ params.moved(np.eye(4)[k] * steps[k]).transform()
            pk, _ = camera.project(moved.apply(points))
            J[:, k] = np.sum((pk - p0) * direction, axis=1) / steps[k]
        hidden = _occluded(params.transform().apply(points), camera_in_fork.translation, forks)
        occluded = float(np.mean(hidden))
        usable = valid & edges.valid & ~hidden
        if usable.sum() < 12:
            return None
        weights = _tukey(edges.offset, usable, edges.strength, floor=radius / 4)
        inliers = weights > 0
        seen = valid & ~hidden
        fractions = [float(np.mean(inliers[seen & (groups == g)])) for g in np.unique(groups[seen])]
        robust = weights.copy()
        for g in np.unique(groups):
            total = weights[groups == g].sum()
            weights[groups == g] *= 1.0 / total if total > 0 else 0.0
        sw = np.sqrt(weights)
        delta = np.linalg.lstsq(J * sw[:, None], edges.offset * sw, rcond=None)[0]
        params = params.moved(delta)
        residual = float(np.sqrt(np.mean((edges.offset - J @ delta)[inliers] ** 2))) if inliers.any() else math.inf
        used, worst = int(inliers.sum()), min(fractions)
    # Covariance of the last step with the unnormalised robust weights: residual^2 (J^T W J)^-1.
    information = (J * robust[:, None]).T @ J
    sigma = tuple(np.sqrt(np.abs(np.diag(np.linalg.pinv(information))) * residual**2).tolist())
    return params, residual, used, occluded, worst, sigma


def _tukey(offset: Array, usable: NDArray[np.bool_], strength: Array, floor: float) -> Array:
    """Tukey biweights with a scale from the median absolute offset (at least ``floor`` px); weak edges
    weigh less."""
    scale = max(1.4826 * float(np.median(np.abs(offset[usable]))), floor)
    c = 4.685 * scale
    w = np.where(usable & (np.abs(offset) < c), (1 - (offset / c) ** 2) ** 2, 0.0)
    strong = np.median(strength[usable])
    return w * np.clip(strength / max(strong, 1e-9), 0.0, 1.0)


def _occluded(points_f: Array, camera_f: Array, forks: ForkGeometry | None) -> NDArray[np.bool_]:
    """Which points (fork frame) the fork tines hide from the camera (segment against box slabs)."""
    if forks is None:
        return np.zeros(len(points_f), bool)
    hidden = np.zeros(len(points_f), bool)
    d = points_f - camera_f
    for side in (-1.0, 1.0):
        y = side * forks.spacing / 2
        low = np.array([-forks.length, y - forks.width / 2, -forks.thickness / 2])
        high = np.array([0.0, y + forks.width / 2, forks.thickness / 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (low - camera_f) / d, (high - camera_f) / d
        t_near = np.nanmax(np.minimum(t0, t1), axis=1)
        t_far = np.nanmin(np.maximum(t0, t1), axis=1)
        hidden |= (t_near < t_far) & (t_far > 0) & (t_near < 1)
    return hidden


# -- verdict --------------------------------------------------------------------------------------


def _face_similarity(gray, camera, camera_in_fork, face: FaceModel, params: _Params, pixel: float = 0.005) -> float:
    """Normalised cross-correlation of the face model with the image projected at ``params``."""
    template, ys, zs = face.raster(pixel)
    yy, zz = np.meshgrid(ys, zs)
    points = np.stack([np.zeros(yy.size), yy.ravel(), zz.ravel()], axis=1)
    T = camera_in_fork.inverse() @ params.transform()
    pixels, valid = camera.project(T.apply(points))
    if not valid.all():
        return -1.0
    samples = cv2.remap(gray, pixels[:, 0:1].astype(np.float32), pixels[:, 1:2].astype(np.float32), cv2.INTER_LINEAR)
    a = samples.ravel().astype(np.float64) - samples.mean()
    b = template.ravel().astype(np.float64) - template.mean()
    return float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12))


def _margin(score, params, others, candidates, face, eye) -> float:
    """Similarity lead over the best candidate elsewhere, fine against fine and coarse against coarse."""
    margins = []
    fine_rivals = [s for s, p, *_ in others if not _same_place(p, params, face, eye)]
    if fine_rivals:
        margins.append(score - max(fine_rivals))
    own = [s for s, p in candidates if _same_place(p, params, face, eye)]
    rivals = [s for s, p in candidates if not _same_place(p, params, face, eye)]
    if own and rivals:
        margins.append(max(own) - max(rivals))
    return min(margins) if margins else score


def check_pose_estimate(
    estimate: PoseEstimate, camera: CameraModel, face: FaceModel, config: PoseSearchConfig = PoseSearchConfig()
) -> None:
    """Raise :class:`MeasurementError` with the reason unless the estimate is convincing: face in view,
    not hidden by the forks, similar enough, clearly better than any rival, edges fitting."""
    score, margin, residual = estimate.score, estimate.margin, estimate.residual_px
    occluded, worst_group = estimate.occluded, estimate.group_inliers
    _, valid = camera.project(estimate.pallet_in_camera.apply(face.corners()))
    if not valid.all():
        raise MeasurementError("the pallet is partly out of view: a corner of its front face is outside the image")
    if occluded > config.max_occluded:
        raise MeasurementError(f"the forks hide {occluded:.0%} of the pallet's pocket edges from the camera")
    if score < config.min_score:
        raise MeasurementError(f"no convincing pallet front face: similarity {score:.2f} < {config.min_score:.2f}")
    if margin < config.min_margin:
        raise MeasurementError(
            f"ambiguous pallet: the runner-up is within {margin:.2f} of the best similarity {score:.2f} "
            f"(need {config.min_margin:.2f})"
        )
    if worst_group < config.min_group_inliers:
        raise MeasurementError(
            f"pocket edges fit poorly: only {worst_group:.0%} of one edge group agrees with the fitted pose "
            f"(need {config.min_group_inliers:.0%})"
        )
    if residual > config.max_residual_px:
        raise MeasurementError(f"pocket edges fit poorly: residual {residual:.2f} px > {config.max_residual_px} px")


# -- image ----------------------------------------------------------------------------------------


def _gray(image: NDArray, camera: CameraModel) -> NDArray[np.float32]:
    if image.shape[:2] != (camera.height, camera.width):
        raise MeasurementError(
            f"image is {image.shape[1]} x {image.shape[0]} pixels but the camera model expects "
            f"{camera.width} x {camera.height}"
        )
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    return gray.astype(np.float32)


def _pyramid(gray: NDArray[np.float32], levels: int) -> NDArray[np.float32]:
    for _ in range(levels):
        gray = cv2.pyrDown(gray)
    return gray
