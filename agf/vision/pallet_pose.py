"""Pallet detection and pose (position and yaw, at a given pitch) from one fisheye image.

The method of the paper's references [1][2]: project the fisheye image onto a virtual plane at a
hypothesised pose of the pallet's front face and compare it with the face model; keep the pose of
maximum similarity. Done in three steps:

1. Coarse: for each yaw hypothesis, a virtual pinhole view looking along the pallet's X axis (the
   face is fronto-parallel there, so a depth is a scale and y, z are a shift) from a low pyramid
   level; normalised cross-correlation with the face raster at every scale (``cv2.matchTemplate``'s
   measure, from integral images: the raster is a few constant rectangles), where the face can be in
   the search volume; then a finer scan around the best distinct candidates.
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

import dataclasses
import functools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from agf.camera.base import CameraModel
from agf.camera.grid import pixels_from_grid
from agf.config import ForkGeometry, SearchVolume
from agf.errors import FaceSimilarityError, MeasurementError, PalletHiddenError
from agf.geometry import Transform, matrix_from_euler
from agf.vision.edges import EdgeSearch, search_edges
from agf.vision.face_model import ENDS, FaceModel
from agf.vision.face_scores import correlation_scores, region_scores
from agf.vision.grey import grey_from_bgr

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PoseSearchConfig:
    """Tuning of the pose search (SI units)."""

    coarse_pixel: float = 0.02  # m per virtual pixel at the middle search depth, at ``pyramid_level``
    pyramid_level: int = 3
    # Seen steeply from above, the face is a thin band: 28 px tall through a 190 deg lens 1.3 m above it (foreign
    # render unloaded-below-forks), 3.5 px at level 3, where its pockets did not resolve and the best peak within
    # 80 mm of it ranked 580th. With ``finer_where_thin``, each slab of the search box (in height) where the face
    # would be less than ``min_face_px`` tall at the coarse level is scanned at a finer level, down to
    # ``fine_level``. Off by default: in every search it reshuffled the candidates of frames that measured at the
    # coarse level, and moved pitches measured 0.03-0.07 deg from the truth beyond the bounds (campaign seed 7,
    # picks 120, 174, 182; see MeasureConfig.steep_similarity).
    finer_where_thin: bool = False
    min_face_px: float = 4.0
    slab_step: float = 0.05  # m: the heights at which the face's image height is worked out
    fine_pixel: float = 0.005  # second scan, around each coarse candidate
    fine_level: int = 1
    fine_window: tuple[float, float, float] = (0.12, 0.04, 0.12)  # m around a coarse candidate (x, y, z)
    fine_scale_step_px: float = 3.0  # template width change between scales of the fine scan
    min_group_inliers: float = 0.6  # fraction of each edge group (top, bottom, sides) that must fit
    yaw_step: float = math.radians(4.0)
    prior_window: float = 0.3  # m around a prior in x, y, z
    prior_yaw_window: float = math.radians(10.0)
    candidates: int = 3
    # What the face is matched by: "correlation" with a raster of dark pockets in lit wood (the paper's
    # measure), or "regions", which asks only that the wood is one surface and each of the pocket's
    # ``pocket_bands`` horizontal bands differs from it (the pocket's shadowed ceiling, the bottom deck
    # seen from above and the floor behind differ by viewpoint and light).
    similarity: Literal["correlation", "regions"] = "correlation"
    pocket_bands: int = 3
    min_score: float = 0.5
    min_margin: float = 0.1
    max_residual_px: float = 1.5
    max_occluded: float = 0.25
    edge_spacing: float = 0.006
    radii_px: tuple[float, ...] = (4.0, 3.0, 2.0, 2.0, 2.0)
    # The face's two ends join the converged pocket-edge fit for ``end_steps`` more steps (at the last
    # radius) and are kept when they move it at most ``ends_agreement`` (m): they fix the scale, hence
    # the depth, which the pocket edges alone left 2.7 mm too far where a lit pocket entrance shows
    # beyond a pocket edge; joined from the start they pulled a steeply seen face to 0.83 of its scale,
    # and a loaded pallet beside two neighbours moved 26 mm with them (random pick 29 of
    # `agf simulate --random 100 --seed 7`).
    end_steps: int = 2
    ends_agreement: float = 0.01
    # Along one line of sight a depth is a scale, and seen steeply from above the face's similarity can be
    # flat over 20 % of depth (the face plus a deck board matches as well as the face alone: campaign seed 7,
    # pick 3, 0.68 from 1.32 m to 1.62 m). Coarse peaks at the best's place but at depths this far from it
    # (relative), scoring within ``depth_window`` of it, are fitted too, at most ``depths`` of them, and
    # returned as :attr:`PoseEstimate.depths` for the caller to decide between by other evidence.
    depth_gap: float = 0.08
    depth_window: float = 0.1
    depths: int = 2

    def __post_init__(self) -> None:
        if self.similarity not in ("correlation", "regions"):
            raise ValueError(f"similarity must be 'correlation' or 'regions', got {self.similarity!r}")
        if self.pocket_bands < 1:
            raise ValueError(f"pocket_bands must be at least 1, got {self.pocket_bands}")
        if self.depths < 0:
            raise ValueError(f"depths must be 0 or more, got {self.depths}")
        if not self.min_face_px > 0 or not self.slab_step > 0:
            raise ValueError(f"min_face_px and slab_step must be positive, got {self.min_face_px} and {self.slab_step}")
        if not 0 <= self.fine_level <= self.pyramid_level:
            raise ValueError(f"fine_level must be 0 to pyramid_level ({self.pyramid_level}), got {self.fine_level}")


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
    # Fits at the same place in the image but another depth (PoseSearchConfig.depth_gap), best first, with
    # this estimate's margin: the similarity does not choose between them (see PoseSearchConfig.depths).
    depths: tuple[PoseEstimate, ...] = ()


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
    pyramid = _pyramid(gray, max(config.pyramid_level, config.fine_level))
    matcher = _matcher(face, config)
    slabs = [
        _scan(
            pyramid[level], level, config.coarse_pixel * 2.0 ** (level - config.pyramid_level),
            2.0 ** (config.pyramid_level - level), camera, camera_in_fork, face, slab, matcher,
        )
        for slab, level in _slabs(box, camera, camera_in_fork, face, config)
    ]
    found = sorted((peak for peaks in slabs for peak in peaks), key=lambda c: -c[0])
    coarse = _distinct(found, face, camera_in_fork.translation)
    chosen = _leaders(coarse[: config.candidates], slabs, face, camera_in_fork.translation)
    fine_image = pyramid[config.fine_level]
    candidates = [_rescan(fine_image, camera, camera_in_fork, face, params, config, matcher) for _, params in chosen]
    left = [c for c in coarse[config.candidates :] if all(c is not other for other in chosen)]
    candidates = sorted([c for c in candidates if c is not None], key=lambda c: -c[0]) + left
    timing["coarse"] = (time.perf_counter() - start) * 1e3
    if not candidates:
        raise MeasurementError("no pallet front face found in the search volume")

    t = time.perf_counter()
    starts = [params for _, params in candidates[: config.candidates]]
    fitted = _fine(gray, camera, camera_in_fork, face, starts, forks, config)
    timing["refine"] = (time.perf_counter() - t) * 1e3
    score, params, *_ = fitted[0]
    margin = _margin(score, params, fitted[1:], candidates, face, camera_in_fork.translation)
    depths = _depths(gray, fine_image, camera, camera_in_fork, face, found, fitted, forks, config, matcher)
    timing["total"] = (time.perf_counter() - start) * 1e3
    estimate = _estimate(fitted[0], margin, camera_in_fork, timing, depths)
    if check:
        check_pose_estimate(estimate, camera, face, config)
    return estimate


def refine_pallet_pose(
    image: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    face: FaceModel,
    start: Transform,
    *,
    pitch: float | None = None,
    forks: ForkGeometry | None = None,
    config: PoseSearchConfig = PoseSearchConfig(),
) -> PoseEstimate:
    """The fine stage of :func:`estimate_pallet_pose` alone, from ``start`` (``pallet_in_fork`` known to a
    few millimetres, as this frame's own pose searched at another pitch), at ``pitch`` (default the start's).

    It sees no rivals, so the estimate's margin is its score, and it is not checked: the caller has both
    from the search that gave ``start``.

    Raises
    ------
    MeasurementError
        When the pocket edges cannot be fitted from ``start``.
    """
    start_time = time.perf_counter()
    yaw, start_pitch, _ = start.euler
    params = _Params(*start.translation, yaw, start_pitch if pitch is None else pitch)
    fitted = _fine(_gray(image, camera), camera, camera_in_fork, face, [params], forks, config)
    return _estimate(fitted[0], fitted[0][0], camera_in_fork, {"total": (time.perf_counter() - start_time) * 1e3})


def _fine(gray, camera, camera_in_fork, face: FaceModel, starts: list[_Params], forks, config) -> list[tuple]:
    """The fits from ``starts`` (score, params, residual, edges used, occluded, worst group, sigma), most
    similar first; :class:`MeasurementError` when none fits."""
    smooth = _smooth_near(gray, camera, camera_in_fork, face, starts)
    points, normals, groups = face.fit_points(config.edge_spacing)
    fits = _refine(smooth, camera, camera_in_fork, starts, points, normals, groups, forks, config)
    fits = [fit for fit in fits if fit is not None]
    if not fits:
        raise MeasurementError("the pallet front face could not be fitted to image edges")
    scores = _face_similarities(gray, camera, camera_in_fork, face, [fit[0] for fit in fits], config)
    return sorted([(score, *fit) for score, fit in zip(scores, fits, strict=True)], key=lambda f: -f[0])


def _estimate(
    fit: tuple, margin: float, camera_in_fork: Transform, timing: dict[str, float], depths: Sequence[tuple] = ()
) -> PoseEstimate:
    score, params, residual, used, occluded, worst_group, sigma = fit
    pallet_in_fork = params.transform()
    return PoseEstimate(
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
        # another depth's lead over the rivals elsewhere: the best's, less what it scores below the best
        tuple(_estimate(other, margin - (score - other[0]), camera_in_fork, {}) for other in depths),
    )


def _depths(gray, fine_image, camera, camera_in_fork, face, found, fitted, forks, config, matcher) -> list[tuple]:
    """The fits at the place of the best fit ``fitted[0]`` but another depth: those among ``fitted`` and
    those from the coarse peaks ``found`` at the best peak's place and within ``config.depth_window`` of its
    score, each at least ``config.depth_gap`` (relative) from the best and from each other, at most
    ``config.depths`` (none when that is 0), by similarity. The coarse peaks are scanned again in a narrow
    window only: in the usual one they slid back to the best's depth, the similarity being flat along the line
    of sight."""
    if config.depths == 0:
        return []
    eye = camera_in_fork.translation
    near = [p for s, p in found if s >= found[0][0] - config.depth_window]
    here = _same_places(_positions(near[:1])[0], _positions(near), face, eye)
    peaks = [p for p, same in zip(near, here, strict=True) if same]
    narrow = dataclasses.replace(config, fine_window=(config.coarse_pixel * 2,) * 3)
    best = fitted[0][1]
    kept = [best]  # the best, then the starts at other depths
    for params in peaks:
        if len(kept) <= config.depths and _new_depth(params, kept, eye, config.depth_gap):
            rescanned = _rescan(fine_image, camera, camera_in_fork, face, params, narrow, matcher)
            if rescanned is not None and _new_depth(rescanned[1], kept, eye, config.depth_gap):
                kept.append(rescanned[1])
    fits = list(fitted[1:])
    if len(kept) > 1:
        try:
            fits += _fine(gray, camera, camera_in_fork, face, kept[1:], forks, config)
        except MeasurementError:
            pass
    chosen: list[tuple] = []
    for fit in sorted(fits, key=lambda f: -f[0]):
        placed = [best] + [f[1] for f in chosen]
        if len(chosen) < config.depths and _same_place(fit[1], best, face, eye) and _new_depth(
            fit[1], placed, eye, config.depth_gap
        ):
            chosen.append(fit)
    return chosen


def _new_depth(params: _Params, kept: list[_Params], eye: Array, gap: float) -> bool:
    """Whether ``params`` lies at least ``gap`` (relative) nearer or further from ``eye`` than each of ``kept``."""
    distance = np.linalg.norm(_positions([params])[0] - eye)
    return bool(np.all(np.abs(np.linalg.norm(_positions(kept) - eye, axis=1) / distance - 1.0) >= gap))


# -- search space ---------------------------------------------------------------------------------


_BOX_SLACK = 0.05  # m: scan peaks this far outside the search box still count
_NEIGHBOURS = np.ones((5, 5), np.uint8)  # a scan peak is the maximum of its 5 x 5 neighbourhood


@dataclass(frozen=True)
class _Box:
    low: Array  # x, y, z (m)
    high: Array
    yaws: tuple[float, ...]
    pitch: float


def _search_box(volume: SearchVolume, prior: Transform | None, pitch: float, config: PoseSearchConfig) -> _Box:
    if prior is None:
        low, high = volume.low, volume.high
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
    matcher: _Matcher,
) -> list[tuple[float, _Params]]:
    """(score, params) of the peaks of ``matcher``'s score over ``box``, best first (:func:`_distinct` keeps
    the best of each place)."""
    fork_in_camera = camera_in_fork.inverse()
    corners = _corners(box.low, box.high)
    slack = _corners(box.low - _BOX_SLACK, box.high + _BOX_SLACK)
    found: list[tuple[float, _Params]] = []
    for yaw in box.yaws:
        R_cv = fork_in_camera.rotation @ matrix_from_euler(yaw, box.pitch, 0.0)
        origins_v = fork_in_camera.apply(corners) @ R_cv  # pallet origins in the view frame
        f = float(np.mean(origins_v[:, 0])) / pixel
        window = _window(origins_v, face, f)
        view = _view(level_image, camera, _key(R_cv), window, f, level)
        integrals = cv2.integral2(view, sdepth=cv2.CV_64F, sqdepth=cv2.CV_64F)  # sums and squares, for every scale
        reach_v = fork_in_camera.apply(slack) @ R_cv
        bounds_v = (*reach_v[:, 1:].min(axis=0).tolist(), *reach_v[:, 1:].max(axis=0).tolist())
        step = scale_step_px / face.width
        scales = np.arange(f / np.max(origins_v[:, 0]), f / np.min(origins_v[:, 0]) + step / 2, step)
        peaks = _peaks(integrals, _templates(face, matcher.edges, 1.0 / scales), matcher, scales, f, window, bounds_v)
        found += _in_box(peaks, R_cv, camera_in_fork, yaw, box)
    found.sort(key=lambda c: -c[0])
    return found


def _slabs(
    box: _Box, camera: CameraModel, camera_in_fork: Transform, face: FaceModel, config: PoseSearchConfig
) -> list[tuple[_Box, int]]:
    """``box`` cut in height into slabs, each with the coarsest pyramid level (from ``config.pyramid_level`` down
    to ``config.fine_level``) at which the face, anywhere in the slab, is ``config.min_face_px`` tall or more; the
    whole box at ``config.pyramid_level`` unless ``config.finer_where_thin``."""
    if not config.finer_where_thin:
        return [(box, config.pyramid_level)]
    heights = np.arange(box.low[2], box.high[2] + config.slab_step / 2, config.slab_step)
    tall = _face_heights_px(heights, box, camera, camera_in_fork, face)
    fits = np.floor(np.log2(np.maximum(tall, 1e-9) / config.min_face_px))  # the floor keeps log2 finite
    levels = np.clip(fits, config.fine_level, config.pyramid_level).astype(int)
    slabs = []
    for start in np.flatnonzero(np.r_[True, levels[1:] != levels[:-1]]):
        stop = start + int(np.argmax(np.r_[levels[start:] != levels[start], True]))
        low, high = box.low.copy(), box.high.copy()
        low[2], high[2] = heights[start], min(heights[stop - 1] + config.slab_step, box.high[2])
        slabs.append((_Box(low, high, box.yaws, box.pitch), int(levels[start])))
    return slabs


def _leaders(best: list[tuple[float, _Params]], slabs: list[list[tuple[float, _Params]]], face: FaceModel,
             eye: Array) -> list[tuple[float, _Params]]:
    """The ``best`` coarse candidates and each slab's best peak at another place: a slab scanned a level finer
    scores its peaks sharper (random look 2 of paper scene unloaded-high-flat: 0.71 at level 2 where level 3's best
    scored 0.65), so the best three overall may all come from one slab and leave another's face unfitted."""
    chosen = list(best)
    for peaks in slabs:
        if peaks and not any(_same_place(peaks[0][1], params, face, eye) for _, params in chosen):
            chosen.append(peaks[0])
    return chosen


def _face_heights_px(
    heights: Array, box: _Box, camera: CameraModel, camera_in_fork: Transform, face: FaceModel
) -> Array:
    """The face's smallest image height (px) at each of ``heights`` (m, fork frame), over the box's near and far
    ends and its middle in y; infinite where it does not project."""
    rotation = matrix_from_euler(0.0, box.pitch, 0.0)
    ends = rotation @ np.array([[0.0, 0.0, face.z_top], [0.0, 0.0, face.z_bottom]]).T
    origins = np.array([[x, (box.low[1] + box.high[1]) / 2, z] for z in heights for x in (box.low[0], box.high[0])])
    points = (origins[:, None, :] + ends.T[None]).reshape(-1, 3)
    pixels, valid = camera.project(camera_in_fork.inverse().apply(points))
    tall = np.linalg.norm(pixels[0::2] - pixels[1::2], axis=1)
    tall[~(valid[0::2] & valid[1::2])] = np.inf
    return tall.reshape(len(heights), 2).min(axis=1)


def _corners(low: Array, high: Array) -> Array:
    """The 8 corners (8, 3) of an axis-aligned box."""
    return np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])])


def _rescan(fine_image, camera, camera_in_fork, face, params: _Params, config: PoseSearchConfig, matcher: _Matcher):
    """The best (score, params) of a finer scan around one coarse candidate, or None."""
    window = np.array(config.fine_window)
    centre = np.array([params.x, params.y, params.z])
    yaws = (params.yaw - config.yaw_step / 2, params.yaw, params.yaw + config.yaw_step / 2)
    box = _Box(centre - window, centre + window, yaws, params.pitch)
    found = _scan(
        fine_image, config.fine_level, config.fine_pixel, config.fine_scale_step_px, camera, camera_in_fork, face, box,
        matcher,
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
    pixels = _view_map(camera, R_key, window, round(f, 6), lvl)
    return cv2.remap(level, pixels, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


@functools.lru_cache(maxsize=256)
def _view_map(camera: CameraModel, R_key: tuple, window: tuple, f: float, lvl: int) -> NDArray[np.float32]:
    """Map (H, W, 2) of a virtual pinhole view (frame V rotated by R_key from the camera) into pyramid
    level ``lvl``."""
    col0, row0, width, height = window
    R_cv = np.array(R_key).reshape(3, 3)

    def directions(nodes: Array) -> Array:
        cols, rows = nodes[:, 0] + col0, nodes[:, 1] + row0
        return np.stack([np.ones_like(cols), -cols / f, -rows / f], axis=-1) @ R_cv.T

    pixels, valid = pixels_from_grid(camera, directions, width, height)
    pixels = (pixels + 0.5) / 2.0**lvl - 0.5
    pixels[~valid] = -1.0
    return pixels


@dataclass(frozen=True)
class _Template:
    """The face's cells (:meth:`FaceModel.regions`) at one scale, laid out as :meth:`FaceModel.raster`."""

    rows: NDArray[np.int_]  # cell boundaries (R + 1,) in pixels, from 0 to the raster's height
    cols: NDArray[np.int_]  # (C + 1,), from 0 to its width
    height: int
    width: int
    y_mid: float  # face y and z (m) at the raster's centre
    z_mid: float


def _templates(face: FaceModel, edges: tuple[Array, Array], pixels: Array) -> list[_Template]:
    """The face's cells (z and y ``edges``, m) at each of ``pixels`` (m), laid out as
    :meth:`FaceModel.raster` lays it out (pixel centres from half a pixel inside the top-left corner; a
    centre exactly on an edge may fall on the other side), for all sizes at once."""
    z_edges, y_edges = edges
    p = pixels[:, None]
    y0, z0 = face.width / 2 - p / 2, face.z_top - p / 2  # the first pixel centres
    width = np.ceil((-face.width / 2 - y0) / -p)
    height = np.ceil((face.z_bottom - z0) / -p)
    cols = np.clip(np.ceil((y0 - y_edges) / p), 0, width).astype(int)  # pixels beyond each edge
    rows = np.clip(np.ceil((z0 - z_edges) / p), 0, height).astype(int)
    y_mid, z_mid = y0[:, 0] - (width[:, 0] - 1) * pixels / 2, z0[:, 0] - (height[:, 0] - 1) * pixels / 2
    sizes = height[:, 0].astype(int).tolist(), width[:, 0].astype(int).tolist()
    fields = rows, cols, *sizes, y_mid.tolist(), z_mid.tolist()
    return [_Template(*t) for t in zip(*fields, strict=True)]


@dataclass(frozen=True)
class _Span:
    """Where one scale's correlation is computed: from offset (top, left), ``shape`` offsets, of which the
    ``inner`` rectangle (relative rows and columns, [start, stop)) may put the face in the box."""

    top: int
    left: int
    shape: tuple[int, int]
    inner: tuple[int, int, int, int]


def _span(integrals: tuple[NDArray, NDArray], template: _Template, scale: float, window, bounds_v) -> _Span | None:
    """The offsets of one scale whose face origin lies within ``bounds_v`` (the box's view-frame extent
    in y and z: low y, low z, high y, high z), and 2 px around them for the local maximum test; None
    when there are none."""
    height, width = template.height, template.width
    out_rows, out_cols = integrals[0].shape[0] - height, integrals[0].shape[1] - width
    if height < 3 or out_rows < 2 or out_cols < 2:
        return None
    y_low, z_low, y_high, z_high = bounds_v
    row_c, col_c = (height - 1) / 2 + window[1], (width - 1) / 2 + window[0]  # raster centre at offset 0
    r0, r1 = _offsets(-(z_high + template.z_mid) * scale - row_c, -(z_low + template.z_mid) * scale - row_c, out_rows)
    c0, c1 = _offsets(-(y_high + template.y_mid) * scale - col_c, -(y_low + template.y_mid) * scale - col_c, out_cols)
    if r0 >= r1 or c0 >= c1:
        return None
    top, left = max(r0 - 2, 0), max(c0 - 2, 0)
    shape = (min(r1 + 2, out_rows) - top, min(c1 + 2, out_cols) - left)
    return _Span(top, left, shape, (r0 - top, r1 - top, c0 - left, c1 - left))


def _peaks(
    integrals, templates: list[_Template], matcher: _Matcher, scales: Array, f: float, window, bounds_v
) -> Array:
    """The (up to 4) best local maxima of the match at each scale that may put the face in the box:
    (K, 4) rows of score and face origin (view frame, m), scale by scale, best first within each.

    The match is computed only where :func:`_span` says (at one depth the box covers a fraction of
    the view).
    """
    spans = [_span(integrals, t, scale, window, bounds_v) for t, scale in zip(templates, scales, strict=True)]
    live = [k for k, span in enumerate(spans) if span is not None]
    if not live:
        return np.zeros((0, 4))
    stack, inner = _responses(integrals, [templates[k] for k in live], matcher, [spans[k] for k in live])
    n, r, c, score = _best_maxima(stack, inner, 4)
    table = np.array([[scales[k], spans[k].top, spans[k].left, *_layout(templates[k])] for k in live])
    scale, top, left, height, width, y_mid, z_mid = table[n].T
    metres = 1.0 / scale  # per view pixel at the face
    row_c, col_c = (height - 1) / 2 + window[1], (width - 1) / 2 + window[0]  # raster centre at offset 0
    return np.stack(
        [score, f * metres, -(c + left + col_c) * metres - y_mid, -(r + top + row_c) * metres - z_mid], axis=1
    )


def _layout(template: _Template) -> tuple[int, int, float, float]:
    return template.height, template.width, template.y_mid, template.z_mid


def _responses(integrals, templates: list[_Template], matcher: _Matcher, spans: list[_Span]) -> tuple[NDArray, NDArray]:
    """The scales' matches (S, R, C), each from the top left of its slice and below any score (-2)
    beyond its span, and where each slice's inner rectangle is. The last two rows of every slice are
    padding, so that a 5 x 5 neighbourhood never reaches into the next."""
    rows = max(span.shape[0] for span in spans) + 2
    cols = max(span.shape[1] for span in spans)
    stack = np.full((len(spans), rows, cols), -2.0, np.float32)
    inner = np.zeros(stack.shape, bool)
    matcher.scores(integrals, templates, np.array([[span.top, span.left, *span.shape] for span in spans]), stack)
    for n, span in enumerate(spans):
        r0, r1, c0, c1 = span.inner
        inner[n, r0:r1, c0:c1] = True
    return stack, inner


def _best_maxima(stack: NDArray, inner: NDArray[np.bool_], count: int) -> tuple[NDArray, ...]:
    """Slice, row, column and score of the ``count`` best local maxima above 0.2 in each slice's inner
    rectangle, slice by slice, best first: one dilation and one threshold for all slices, as per slice the
    calls cost more than the arithmetic."""
    flat = stack.reshape(-1, stack.shape[2])
    local_max = (flat >= cv2.dilate(flat, _NEIGHBOURS)).reshape(stack.shape)
    n, r, c = np.nonzero(local_max & inner & (stack > 0.2))
    score = stack[n, r, c]
    order = np.lexsort((-score, n))
    n, r, c, score = n[order], r[order], c[order], score[order]
    best = np.arange(len(n)) - np.searchsorted(n, n) < count  # rank within the slice
    return n[best], r[best], c[best], score[best]


def _in_box(peaks: Array, R_cv: Array, camera_in_fork: Transform, yaw: float, box: _Box) -> list[tuple[float, _Params]]:
    """(score, params) of the scan peaks (rows of score and view-frame face origin) in the box."""
    origins = camera_in_fork.apply(peaks[:, 1:] @ R_cv.T).reshape(-1, 3)
    inside = np.all((origins >= box.low - _BOX_SLACK) & (origins <= box.high + _BOX_SLACK), axis=1)
    return [
        (score, _Params(*o, yaw, box.pitch))
        for score, o in zip(peaks[inside, 0].tolist(), origins[inside].tolist(), strict=True)
    ]


def _offsets(first: float, last: float, count: int) -> tuple[int, int]:
    """The integer offsets [start, stop) from ``first`` to ``last`` (fractional, either order), within [0, count)."""
    low, high = min(first, last), max(first, last)
    return max(math.floor(low), 0), min(math.ceil(high) + 1, count)


class _Matcher(Protocol):
    """A score of the face at every offset of a virtual view, from the view's integral images."""

    edges: tuple[Array, Array]  # the face's cell edges, z from the top and y from the left (m)

    def scores(
        self, integrals: tuple[NDArray, NDArray], templates: Sequence[_Template], spans: NDArray, out: NDArray
    ) -> None:
        """Each template's scores into ``out`` (S, R, C): from the view's integral images of sums and squares
        (each (H + 1, W + 1), as ``cv2.integral2`` gives them), at the offsets ``spans`` (S, 4) gives (first row,
        first column, rows, columns)."""


def _matcher(face: FaceModel, config: PoseSearchConfig) -> _Matcher:
    if config.similarity == "correlation":
        return _Correlation.of(face)
    return _RegionMatch.of(face, config.pocket_bands)


def _cells(templates: Sequence[_Template]) -> tuple[NDArray[np.int_], NDArray[np.int_], NDArray[np.int_]]:
    """The templates' cell boundaries (S, R + 1) and (S, C + 1) and sizes (S, 2): height, width (px)."""
    rows = np.stack([t.rows for t in templates])
    cols = np.stack([t.cols for t in templates])
    return rows, cols, np.array([[t.height, t.width] for t in templates])


@dataclass(frozen=True)
class _Correlation:
    """``cv2.matchTemplate(view, raster, cv2.TM_CCOEFF_NORMED)`` with the face raster (wood 1, pocket
    0): the paper's measure, strong where pockets are dark openings in lit wood.

    The raster is a few constant cells, so its correlation at every offset is a few integral-image
    lookups at the cell corners (where the raster's mixed second difference is nonzero) instead of a
    DFT of the view: several times faster, and equal to 1e-4. The window's own corners give the window
    sum times the corner cell's value, which the normalisation needs anyway.
    """

    edges: tuple[Array, Array]
    values: Array  # (R, C): 1 wood, 0 pocket
    corners: tuple[NDArray[np.int_], NDArray[np.int_], Array]  # rows, columns, weights of the nonzero corners
    corner: float  # the corner cell's value
    # the raster's mean and norm by its cell boundaries (rows, columns as bytes): a scan's scales repeat a few
    # boundaries (161 distinct among 2,572 templates of 8 bench frames), and computing them cost 18 us a match
    moments: dict[tuple[bytes, bytes], tuple[float, float]] = field(default_factory=dict, init=False, repr=False,
                                                                     compare=False)

    @classmethod
    def of(cls, face: FaceModel) -> _Correlation:
        z, y, regions = face.regions(1)
        values = (regions == 0).astype(float)
        weights = np.diff(np.diff(np.pad(values, 1), axis=0), axis=1)  # mixed second difference
        corner = weights[0, 0]
        weights[[0, 0, -1, -1], [0, -1, 0, -1]] -= corner * np.array([1, -1, -1, 1])
        a, b = np.nonzero(weights)
        return cls((z, y), values, (a, b, weights[a, b]), float(corner))

    def scores(
        self, integrals: tuple[NDArray, NDArray], templates: Sequence[_Template], spans: NDArray, out: NDArray
    ) -> None:
        rows, cols, sizes = _cells(templates)
        a, b, weights = self.corners
        moments = np.array([self._moments(t) for t in templates])
        correlation_scores(*integrals, spans, sizes, np.stack([rows[:, a], cols[:, b]], axis=-1),
                           weights, self.corner - moments[:, 0], moments[:, 1], out)

    def _moments(self, template: _Template) -> tuple[float, float]:
        """The raster's mean and norm about it at the template's cell boundaries."""
        key = template.rows.tobytes(), template.cols.tobytes()
        if key not in self.moments:
            area = np.diff(template.rows)[:, None] * np.diff(template.cols)[None, :]
            mean = float(np.sum(self.values * area)) / (template.height * template.width)
            self.moments[key] = mean, math.sqrt(float(np.sum((self.values - mean) ** 2 * area)))
        return self.moments[key]


@dataclass(frozen=True)
class _RegionMatch:
    """The region match (:func:`region_match`) with the face's regions, ``bands`` per pocket: it asks
    only that the wood is one surface and the pockets differ from it, not which is brighter.

    Every pocket band is a rectangle of cells, so its sum at every offset is four integral-image
    lookups; the wood's is the window's less the bands'.
    """

    edges: tuple[Array, Array]
    openings: NDArray[np.int_]  # (L - 1, 4) each band's first and past-last cell row, first and past-last column

    @classmethod
    def of(cls, face: FaceModel, bands: int) -> _RegionMatch:
        z, y, regions = face.regions(bands)
        rects = []
        for label in range(1, int(regions.max()) + 1):
            r, c = np.nonzero(regions == label)
            rects.append((r.min(), r.max() + 1, c.min(), c.max() + 1))
        return cls((z, y), np.array(rects, int).reshape(-1, 4))

    def scores(
        self, integrals: tuple[NDArray, NDArray], templates: Sequence[_Template], spans: NDArray, out: NDArray
    ) -> None:
        rows, cols, sizes = _cells(templates)
        r0, r1, c0, c1 = self.openings.T
        bands = np.stack([rows[:, r0], rows[:, r1], cols[:, c0], cols[:, c1]], axis=-1)
        region_scores(*integrals, spans, sizes, bands, out)


def region_match(sums: Array, areas: Array, total: Array, total_sq: Array) -> NDArray[np.float32]:
    """The share of a window's intensity variance explained by regions of constant intensity each
    (the ANOVA R^2: between-region over total sum of squares), in [0, 1]; 0 for a flat window.

    Parameters
    ----------
    sums : (L, ...) array
        Each region's intensity sum.
    areas : (L,) array
        Each region's pixel count (> 0), summing to the window's.
    total, total_sq : (...) arrays
        The window's intensity sum and sum of squares.

    Unlike a correlation with a fixed template, it does not ask which region is brighter: a pocket
    may be darker than the wood or lighter, as long as the wood is one surface and the pockets differ.
    """
    n = float(np.sum(areas))
    mean_sq = total * total / n
    between = np.tensordot(1.0 / areas, sums * sums, axes=1) - mean_sq
    variance = total_sq - mean_sq
    flat = variance <= 1e-9 * np.maximum(total_sq, 1e-30)  # no variance beyond rounding
    score = between / np.where(flat, 1.0, variance)
    score = np.where(flat, 0.0, score)
    return np.clip(score, 0.0, 1.0).astype(np.float32)


def _distinct(found: list[tuple[float, _Params]], face: FaceModel, eye: Array) -> list[tuple[float, _Params]]:
    """Keep the best candidate of each place in the image (along one line of sight, depth is a scale)."""
    positions = _positions([p for _, p in found])
    left = np.ones(len(found), bool)  # not yet at the place of a kept candidate
    kept: list[tuple[float, _Params]] = []
    while left.any():
        best = int(np.argmax(left))
        kept.append(found[best])
        left &= ~_same_places(positions[best], positions, face, eye)
    return kept


def _same_place(p: _Params, q: _Params, face: FaceModel, eye: Array) -> bool:
    """Whether two hypotheses put the face centre within a sixth of the face's width in the image."""
    return bool(_same_places(_positions([p])[0], _positions([q]), face, eye)[0])


def _same_places(a: Array, b: Array, face: FaceModel, eye: Array) -> NDArray[np.bool_]:
    """:func:`_same_place` for positions (fork frame) ``a`` (3,) and each of ``b`` (N, 3)."""
    a, b = a - eye, b - eye
    norm_a, norm_b = np.linalg.norm(a), np.linalg.norm(b, axis=1)
    angle = np.arccos(np.clip(b @ a / (norm_a * norm_b), -1.0, 1.0))
    return angle < face.width / 6 / np.maximum(norm_a, norm_b)


def _positions(params: list[_Params]) -> Array:
    return np.array([[p.x, p.y, p.z] for p in params]).reshape(-1, 3)


# -- fine stage -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Fit:
    """One Gauss-Newton fit after a step: the pose, and what :func:`_refine` reports of the step."""

    params: _Params
    residual: float = math.inf
    used: int = 0
    occluded: float = 0.0
    worst: float = 0.0
    J: Array | None = None  # of the step (None before the first)
    robust: Array | None = None  # the step's unnormalised robust weights

    def result(self) -> tuple:
        # Covariance of the last step with the unnormalised robust weights: residual^2 (J^T W J)^-1.
        information = (self.J * self.robust[:, None]).T @ self.J
        sigma = tuple(np.sqrt(np.abs(np.diag(np.linalg.pinv(information))) * self.residual**2).tolist())
        return self.params, self.residual, self.used, self.occluded, self.worst, sigma


def _refine(smooth, camera, camera_in_fork, starts: list[_Params], points, normals, groups, forks, config):
    """Gauss-Newton on pocket-edge offsets from each start, all in step: one projection and one edge
    search per step for all of them, as both cost mostly per call.

    Returns for each start (params, residual_px, edges_used, occluded, worst group inlier fraction, sigma)
    or None. Each edge group (pocket tops, bottoms, sides, and the face's ends once they join) weighs the
    same in total, so the many horizontal edge points cannot outvote the few vertical ones that fix the
    scale, hence the depth.
    """
    fork_in_camera = camera_in_fork.inverse()
    steps = np.array([1e-3, 1e-3, 1e-3, math.radians(0.05)])
    fits: list[_Fit | None] = [_Fit(params) for params in starts]
    pockets_only: list[_Fit | None] = []
    schedule = [(r, False) for r in config.radii_px] + [(config.radii_px[-1], True)] * config.end_steps
    for radius, ends in schedule:
        if ends and not pockets_only:
            pockets_only = list(fits)
        live = [k for k, fit in enumerate(fits) if fit is not None]
        if not live:
            break
        linear = _linearise(camera, fork_in_camera, [fits[k].params for k in live], points, normals, steps)
        starts_px = np.concatenate([p0 for p0, *_ in linear]) - smooth[1]
        directions = np.concatenate([d for _, d, *_ in linear])
        # either polarity: which side of a pocket edge is brighter depends on the viewpoint and the light
        found = search_edges(smooth[0], starts_px, directions, radius, either_polarity=True)
        for i, (k, (_, _, valid, J)) in enumerate(zip(live, linear, strict=True)):
            part = slice(i * len(points), (i + 1) * len(points))
            edges = EdgeSearch(found.offset[part], found.strength[part], found.valid[part])
            fits[k] = _step(fits[k].params, edges, valid, J, radius, points, groups, camera_in_fork.translation,
                            forks, ends)
    if pockets_only:
        fits = [_with_ends(both, alone, config.ends_agreement) for both, alone in zip(fits, pockets_only, strict=True)]
    return [None if fit is None else fit.result() for fit in fits]


def _with_ends(with_ends: _Fit | None, alone: _Fit | None, agreement: float) -> _Fit | None:
    """The fit with the face's ends where it stays within ``agreement`` (m) of the pocket edges' own."""
    if with_ends is None or alone is None:
        return alone
    a, b = with_ends.params, alone.params
    return with_ends if math.dist((a.x, a.y, a.z), (b.x, b.y, b.z)) <= agreement else alone


def _step(params: _Params, edges: EdgeSearch, valid, J, radius, points, groups, eye, forks, ends: bool) -> _Fit | None:
    """One robust, group-balanced Gauss-Newton step of :func:`_refine`, with the face's ends (group 5)
    or without; None when too few edges are found."""
    hidden = hidden_by_forks(params.transform().apply(points), eye, forks)
    seen = valid & ~hidden & (ends | (groups != ENDS))
    usable = seen & edges.valid
    if usable.sum() < 12:
        return None
    weights = _tukey(edges.offset, usable, edges.strength, floor=radius / 4)
    inliers = weights > 0
    fractions = [float(np.mean(inliers[seen & (groups == g)])) for g in np.unique(groups[seen])]
    robust = weights.copy()
    for g in np.unique(groups):
        total = weights[groups == g].sum()
        weights[groups == g] *= 1.0 / total if total > 0 else 0.0
    sw = np.sqrt(weights)
    delta = np.linalg.lstsq(J * sw[:, None], edges.offset * sw, rcond=None)[0]
    residual = float(np.sqrt(np.mean((edges.offset - J @ delta)[inliers] ** 2))) if inliers.any() else math.inf
    return _Fit(params.moved(delta), residual, int(inliers.sum()), float(np.mean(hidden)), min(fractions), J, robust)


def _linearise(camera, fork_in_camera, poses: list[_Params], points, normals, steps) -> list[tuple]:
    """For each pose: pixels (N, 2) of the edge points, unit image directions (N, 2) of their normals,
    which project validly (N,), and the image motion (N, 4) along those directions per unit x, y, z, yaw
    (forward differences by ``steps``).

    One projection of all poses' six point sets (those of :func:`~agf.vision.edges.project_with_normals`
    and the four moved poses), as the viewpoint-shift solve costs mostly per call.
    """
    n = len(points)
    sets = []
    for params in poses:
        T = fork_in_camera @ params.transform()
        base = T.apply(points)
        shifted = [base + fork_in_camera.rotation[:, k] * steps[k] for k in range(3)]  # x, y, z: a translation
        turned = (fork_in_camera @ params.moved(np.eye(4)[3] * steps[3]).transform()).apply(points)
        sets += [base, T.apply(points + 0.003 * normals), *shifted, turned]
    pixels, valid = camera.project(np.concatenate(sets))
    out = []
    for pose_pixels, pose_valid in zip(pixels.reshape(-1, 6 * n, 2), valid.reshape(-1, 6 * n), strict=True):
        p0 = pose_pixels[:n]
        direction = pose_pixels[n : 2 * n] - p0
        direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
        J = np.sum((pose_pixels[2 * n :].reshape(4, n, 2) - p0) * direction, axis=2).T / steps
        out.append((p0, direction, pose_valid[:n], J))
    return out


def _smooth_near(gray, camera, camera_in_fork, face: FaceModel, candidates: list[_Params]) -> tuple[NDArray, Array]:
    """The image blurred for the edge search only around the candidates' faces (blurring the whole
    frame cost a tenth of the search), and that window's top-left pixel (u, v).

    The window reaches half the faces' extent (at least 64 px) beyond them, far more than a fit moves,
    so the blur at every searched pixel is that of the whole frame.
    """
    fork_in_camera = camera_in_fork.inverse()
    corners = np.concatenate([(fork_in_camera @ p.transform()).apply(face.corners()) for p in candidates])
    pixels, _ = camera.project(corners)
    low, high = pixels.min(axis=0), pixels.max(axis=0)
    reach = np.maximum((high - low) / 2, 64.0)
    u0, v0 = np.maximum(np.floor(low - reach), 0).astype(int)
    u1, v1 = np.minimum(np.ceil(high + reach) + 1, [gray.shape[1], gray.shape[0]]).astype(int)
    return cv2.GaussianBlur(gray[v0:v1, u0:u1], (0, 0), 1.0), np.array([u0, v0], float)


def _tukey(offset: Array, usable: NDArray[np.bool_], strength: Array, floor: float) -> Array:
    """Tukey biweights with a scale from the median absolute offset (at least ``floor`` px); weak edges
    weigh less."""
    scale = max(1.4826 * float(np.median(np.abs(offset[usable]))), floor)
    c = 4.685 * scale
    w = np.where(usable & (np.abs(offset) < c), (1 - (offset / c) ** 2) ** 2, 0.0)
    strong = np.median(strength[usable])
    return w * np.clip(strength / max(strong, 1e-9), 0.0, 1.0)


def hidden_by_forks(points_f: Array, camera_f: Array, forks: ForkGeometry | None) -> NDArray[np.bool_]:
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


def _face_similarities(
    gray, camera, camera_in_fork, face: FaceModel, poses: list[_Params], config: PoseSearchConfig,
    pixel: float = 0.005,
) -> list[float]:
    """The similarity of the face with the image projected at each pose (``config.similarity``, as the
    search matched it), -1 where the face leaves the image (one projection for all, as the
    viewpoint-shift solve costs mostly per call)."""
    regions, ys, zs = face.region_raster(pixel, 1 if config.similarity == "correlation" else config.pocket_bands)
    yy, zz = np.meshgrid(ys, zs)
    points = np.stack([np.zeros(yy.size), yy.ravel(), zz.ravel()], axis=1)
    fork_in_camera = camera_in_fork.inverse()
    pixels, valid = camera.project(np.concatenate([(fork_in_camera @ p.transform()).apply(points) for p in poses]))
    labels = regions.ravel()
    areas = np.bincount(labels).astype(np.float64)
    wood = (labels == 0).astype(np.float64) - np.mean(labels == 0)
    scores = []
    for pose_pixels, pose_valid in zip(np.split(pixels, len(poses)), np.split(valid, len(poses)), strict=True):
        if not pose_valid.all():
            scores.append(-1.0)
            continue
        u, v = pose_pixels[:, 0:1].astype(np.float32), pose_pixels[:, 1:2].astype(np.float32)
        samples = cv2.remap(gray, u, v, cv2.INTER_LINEAR).ravel().astype(np.float64)
        if config.similarity == "correlation":
            centred = samples - samples.mean()
            score = centred @ wood / max(float(np.linalg.norm(centred) * np.linalg.norm(wood)), 1e-12)
        else:
            sums = np.bincount(labels, samples)[areas > 0]
            score = region_match(sums, areas[areas > 0], samples.sum(), samples @ samples)
        scores.append(float(score))
    return scores


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
    estimate: PoseEstimate, camera: CameraModel, face: FaceModel, config: PoseSearchConfig = PoseSearchConfig(),
    *, similarity: bool = True,
) -> None:
    """Raise :class:`MeasurementError` with the reason unless the estimate is convincing: face in view,
    not hidden by the forks, similar enough, clearly better than any rival, edges fitting.

    The similarity's two refusals (too low, a rival too close) are :class:`~agf.errors.FaceSimilarityError`;
    ``similarity`` False skips them, for a caller whose other evidence settled them."""
    score, margin, residual = estimate.score, estimate.margin, estimate.residual_px
    occluded, worst_group = estimate.occluded, estimate.group_inliers
    _, valid = camera.project(estimate.pallet_in_camera.apply(face.corners()))
    if not valid.all():
        raise MeasurementError("the pallet is partly out of view: a corner of its front face is outside the image")
    if occluded > config.max_occluded:
        raise PalletHiddenError(
            f"the forks hide {occluded:.0%} of the pallet's pocket edges from the camera", estimate.pallet_in_fork
        )
    if similarity:
        _check_similarity(score, margin, config)
    if worst_group < config.min_group_inliers:
        raise MeasurementError(
            f"pocket edges fit poorly: only {worst_group:.0%} of one edge group agrees with the fitted pose "
            f"(need {config.min_group_inliers:.0%})"
        )
    if residual > config.max_residual_px:
        raise MeasurementError(f"pocket edges fit poorly: residual {residual:.2f} px > {config.max_residual_px} px")


def _check_similarity(score: float, margin: float, config: PoseSearchConfig) -> None:
    """Raise :class:`~agf.errors.FaceSimilarityError` where the face's similarity is below the minimum or leads the
    best rival by less than the minimum margin."""
    if score < config.min_score:
        raise FaceSimilarityError(f"no convincing pallet front face: similarity {score:.2f} < {config.min_score:.2f}")
    if margin < 0:  # a pose refined at the measured pitch can score below a rival found at the assumed one
        raise FaceSimilarityError(
            f"ambiguous pallet: a rival scores {-margin:.2f} above the measured pose's similarity {score:.2f} "
            f"(need a lead of {config.min_margin:.2f})"
        )
    if margin < config.min_margin:
        raise FaceSimilarityError(
            f"ambiguous pallet: the runner-up is within {margin:.2f} of the best similarity {score:.2f} "
            f"(need a lead of {config.min_margin:.2f})"
        )


# -- image ----------------------------------------------------------------------------------------


def _gray(image: NDArray, camera: CameraModel) -> NDArray[np.float32]:
    if image.shape[:2] != (camera.height, camera.width):
        raise MeasurementError(
            f"image is {image.shape[1]} x {image.shape[0]} pixels but the camera model expects "
            f"{camera.width} x {camera.height}"
        )
    return grey_from_bgr(image).astype(np.float32, copy=False)


def _pyramid(gray: NDArray[np.float32], levels: int) -> list[NDArray[np.float32]]:
    """Levels 0 (``gray``) to ``levels``, each half the size of the one before."""
    pyramid = [gray]
    for _ in range(levels):
        pyramid.append(cv2.pyrDown(pyramid[-1]))
    return pyramid
