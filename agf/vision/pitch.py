"""Pitch inclination of the pallet from parallel 3D edges (paper section III).

Two hypotheses, each looking for two long parallel edges in a panorama whose axis is the edges'
predicted direction (from the pose and the calibration, so a pitched-down camera works too; with a
level mount these are the paper's camera Z and camera X):

* loaded: the load's left and right vertical edges, parallel to pallet Z;
* unloaded: the left and right edges of the top deck, parallel to pallet X.

Each edge is found by the spherical Hough transform in its predicted region; the pair's common
direction gives the pallet's axis, hence its pitch in the fork frame. The hypothesis is valid when
its Hough scores cover enough of the predicted edge length (the paper's ratio test).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from agf.camera.base import CameraModel
from agf.geometry import Transform
from agf.pallets import PalletType
from agf.vision.hough import SphereLine, common_direction, hough_line, refine_line
from agf.vision.panorama import Panorama, render_panorama

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PitchConfig:
    """Tuning of the pitch measurement (SI units)."""

    pixel: float = math.radians(0.08)  # panorama resolution, rad per pixel
    band: float = math.radians(4.0)  # half-width of a predicted region around the predicted edge
    tau_max: float = math.radians(9.0)  # largest inclination of an edge against the predicted direction
    inlier_tolerance: float = 0.8  # panorama pixels: edge points this close to a line are fitted to it; at
    # 1.5 px the fit took in the gradient of a loaded neighbour's side face and leaned up to 0.5 deg
    min_ratio: float = 0.5  # Hough score / predicted length for a valid hypothesis
    load_search: float = 0.25  # m: how much narrower than the pallet a load may be, each side
    load_height: float = 0.4  # m of load edge above the deck that is searched and must be found ...
    load_reach: float = 1.0  # ... and how far up a found edge is followed for the fit: over 0.4 m, sensor
    # noise leaned the pair 0.07-0.17 deg on 13 random loaded picks; followed up a 0.5-1 m load, 0.05 deg at most
    rival_gap: float = 12.0  # panorama pixels: a parallel line this close to an edge makes it ambiguous ...
    rival_pitch: float = math.radians(0.03)  # ... unless the pitch with it instead is within this: a line
    # parallel in 3D (the deck board's lower edge, a bed seam, an upright beside a level load) gives the
    # same direction, hence the same pitch; only where the edge lies stays in doubt
    anchor_tolerance: float = 5.0  # panorama pixels: an edge this close to the point the pose pins ...
    anchor_gap: float = 3.0  # ... beats a rival that misses that point by this many pixels more


@dataclass(frozen=True)
class PitchEvidence:
    """What one hypothesis found.

    Attributes
    ----------
    hypothesis : str
        ``"loaded"`` or ``"unloaded"``.
    ratio : float
        The smaller of the two edges' Hough score over predicted length (0..1).
    valid : bool
        ``ratio`` reached the configured minimum and the two edges gave a direction.
    pitch : float
        Pallet pitch in the fork frame (rad); NaN when not valid.
    direction : (3,) array
        The edges' common direction, camera frame (NaN when not valid).
    panorama : Panorama
        The panorama the edges were searched in (for overlays).
    regions : list of (4,) arrays
        Predicted regions as panorama (col_min, col_max, row_min, row_max).
    lines : list of SphereLine
        The edges found.
    sigma : float
        Standard deviation of the pitch (rad), from the scatter of each line's inlier directions.
    ambiguous : bool
        A second strong line runs beside one of the edges (a rack upright next to a load edge, a shadow)
        and gives another pitch: the fit cannot tell which is the edge, so the hypothesis is not valid.
    placed : bool
        The edges' positions are known too (no line beside them): only then may they move the pose
        (:func:`pose_from_deck_edges`); a rival that gives the same pitch leaves the pitch valid.
    """

    hypothesis: str
    ratio: float
    valid: bool
    pitch: float
    direction: Array
    panorama: Panorama
    regions: list[Array]
    lines: list[SphereLine]
    sigma: float = math.nan
    ambiguous: bool = False
    placed: bool = True


def unloaded_evidence(
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig = PitchConfig(),
) -> PitchEvidence:
    """The top deck's left and right edges, parallel to pallet X."""
    x = np.linspace(0.03, pallet.length - 0.03, 24)
    segments = [
        np.c_[x, np.full_like(x, side * pallet.width / 2), np.full_like(x, pallet.deck_top)] for side in (-1, 1)
    ]
    return _evidence("unloaded", gray, camera, camera_in_fork, pallet_in_fork, segments, 0, config, anchored=True)


def pose_from_deck_edges(
    evidence: PitchEvidence, pallet: PalletType, camera_in_fork: Transform, pallet_in_fork: Transform
) -> Transform:
    """``pallet_in_fork`` turned and moved so that the top deck's edges lie on the lines found.

    Each deck edge and the camera centre span the plane of its great circle, so the two edges fix the
    pallet's yaw, pitch and its position across them (y and z); only x comes from ``pallet_in_fork``.
    Seen steeply from above, the face match settled 7-29 mm off in z and up to 0.75 deg in yaw where
    the deck edges were right to a fraction of a millimetre (random picks 30, 115 and 195).

    Parameters
    ----------
    evidence : PitchEvidence
        A valid unloaded hypothesis: lines of the left (-y) and right (+y) deck edges.
    pallet : PalletType
    camera_in_fork, pallet_in_fork : Transform
        Calibration, and the pose the edges were searched from.

    Raises
    ------
    ValueError
        When ``evidence`` is not a valid unloaded hypothesis.
    """
    if evidence.hypothesis != "unloaded" or not evidence.valid:
        raise ValueError(
            f"deck edges need a valid unloaded hypothesis, got {evidence.hypothesis} (valid={evidence.valid})"
        )
    forward = camera_in_fork.apply_direction(evidence.direction)
    turned = Transform.from_euler(
        *pallet_in_fork.translation,
        0.0,
        math.atan2(-forward[2], math.hypot(forward[0], forward[1])),
        math.atan2(forward[1], forward[0]),
    )
    in_camera = camera_in_fork.inverse() @ turned
    R, origin = in_camera.rotation, in_camera.translation
    normals = np.array([line.normal for line in evidence.lines])
    corners = np.array([[0.0, side * pallet.width / 2, pallet.deck_top] for side in (-1, 1)])
    shift = np.linalg.solve(normals @ R[:, 1:], -np.sum(normals * in_camera.apply(corners), axis=1))
    return camera_in_fork @ Transform(R, origin + R[:, 1:] @ shift)


def loaded_evidence(
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig = PitchConfig(),
) -> PitchEvidence:
    """The load's left and right vertical edges, parallel to pallet Z, within the pallet's width."""
    inset = config.load_search / 2

    def edges_up_to(height: float, count: int) -> list[Array]:
        z = np.linspace(pallet.deck_top + 0.02, pallet.deck_top + height, count)
        return [np.c_[np.zeros_like(z), np.full_like(z, side * (pallet.width / 2 - inset)), z] for side in (-1, 1)]

    band = math.atan2(inset + 0.03, float(np.linalg.norm(pallet_in_fork.translation - camera_in_fork.translation)))
    return _evidence(
        "loaded",
        gray,
        camera,
        camera_in_fork,
        pallet_in_fork,
        edges_up_to(config.load_height, 24),
        2,
        PitchConfig(**{**config.__dict__, "band": max(config.band, band)}),
        reach_p=edges_up_to(config.load_reach, 48),
    )


def _evidence(
    hypothesis: str,
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet_in_fork: Transform,
    segments_p: list[Array],
    axis_index: int,
    config: PitchConfig,
    anchored: bool = False,
    reach_p: list[Array] | None = None,
) -> PitchEvidence:
    """Edges along ``segments_p`` (pallet frame, parallel to pallet axis ``axis_index``); ``anchored``
    when each segment's first point is a model point the pose pins (the deck's front corners); ``reach_p``,
    longer segments along which a found edge is followed for its fit (the load's full height)."""
    pallet_in_camera = camera_in_fork.inverse() @ pallet_in_fork
    predicted = pallet_in_camera.rotation[:, axis_index]
    segments = [pallet_in_camera.apply(s) for s in segments_p]
    reach = [pallet_in_camera.apply(s) for s in reach_p] if reach_p is not None else segments
    panorama = _panorama_over(predicted, segments + reach, config)
    image, valid = render_panorama(gray, camera, panorama)
    regions = [_region(panorama, segment, config) for segment in segments]
    reaches = [_region(panorama, far, config) for far in reach]
    directions, strong, columns, rows = _edge_points(image.astype(np.float32), valid, panorama, regions + reaches)
    lines, ratios, scatter = [], [], []
    rivals: list[SphereLine | None] = []
    for segment, far, region, reach_region in zip(segments, reach, regions, reaches, strict=True):
        inside = _inside(region, columns, rows)
        lon = (
            panorama.angles_from_pixels(region[None, [0, 2]])[0][0],
            panorama.angles_from_pixels(region[None, [1, 2]])[0][0],
        )
        corrected = _from_reference_viewpoint(camera, directions[inside], segment)
        fitted = corrected[strong[inside]]
        ones = np.ones(len(fitted))
        line = _line(panorama, fitted, ones, lon, config)
        if line is not None:
            rival = _rival_nearby(panorama, fitted, ones, line, lon, config)
            anchor = _unit(segment[:1])[0] if anchored else None
            rivals.append(None if rival is None or _anchor_decides(line, rival, anchor, panorama, config) else rival)
            along = _inside(reach_region, columns, rows) & strong
            grown = _from_reference_viewpoint(camera, directions[along], far)
            fit = refine_line(grown, np.ones(len(grown)), line.normal, config.inlier_tolerance * panorama.pixel_size())
            spread = grown[fit.inliers] @ fit.normal if fit is not None else np.zeros(0)
            scatter.append(float(np.std(spread)) / math.sqrt(len(spread)) if len(spread) else 0.0)
        length = max(region[3] - region[2], 1.0)
        ratios.append(
            0.0 if line is None else min(_support(line, corrected, rows[inside], panorama, config) / length, 1.0)
        )
        if line is not None:
            lines.append(fit if fit is not None else line)
    ratio = float(min(ratios))
    nan = np.full(3, np.nan)
    if len(lines) < 2 or ratio < config.min_ratio:
        return PitchEvidence(hypothesis, ratio, False, math.nan, nan, panorama, regions, lines, math.nan)
    pitches = []
    for left in (lines[0], rivals[0]):
        for right in (lines[1], rivals[1]):
            if left is not None and right is not None:
                try:
                    direction = common_direction(left.normal, right.normal, predicted)
                except ValueError:
                    return PitchEvidence(hypothesis, ratio, False, math.nan, nan, panorama, regions, lines)
                pitches.append(_pitch_from_direction(camera_in_fork.apply_direction(direction), pallet_in_fork,
                                                     hypothesis))
    direction = common_direction(lines[0].normal, lines[1].normal, predicted)
    pitch, spread = pitches[0], max(abs(p - pitches[0]) for p in pitches)
    if spread > config.rival_pitch:
        return PitchEvidence(hypothesis, ratio, False, math.nan, nan, panorama, regions, lines, math.nan, True)
    sigma = math.hypot(*scatter, spread / 2)
    placed = all(rival is None for rival in rivals)
    return PitchEvidence(hypothesis, ratio, True, pitch, direction, panorama, regions, lines, sigma, placed=placed)


def _region(panorama: Panorama, segment: Array, config: PitchConfig) -> Array:
    """Predicted region of an edge along ``segment`` (camera frame): panorama (col_min, col_max, row_min,
    row_max), the band wide to either side."""
    pixels = panorama.pixels_from_directions(_unit(segment))
    band_px = config.band / panorama.pixel_size()
    return np.array(
        [pixels[:, 0].min() - band_px, pixels[:, 0].max() + band_px, pixels[:, 1].min(), pixels[:, 1].max()]
    )


def _inside(region: Array, columns: Array, rows: Array) -> NDArray[np.bool_]:
    return (columns >= region[0]) & (columns <= region[1]) & (rows >= region[2]) & (rows <= region[3])


def _rival_nearby(
    panorama: Panorama,
    directions: Array,
    weights: Array,
    line: SphereLine,
    lon: tuple[float, float],
    config: PitchConfig,
) -> SphereLine | None:
    """Another line, at least half as strong, within a few pixels of ``line``, if there is one."""
    gap = config.rival_gap * panorama.pixel_size()
    distance = np.abs(directions @ line.normal)
    others = distance > 2.0 * panorama.pixel_size()
    nearby = others & (distance < gap)
    rival = _line(panorama, directions[nearby], weights[nearby], lon, config)
    return rival if rival is not None and rival.score >= 0.5 * line.score else None


def _support(line: SphereLine, directions: Array, rows: Array, panorama: Panorama, config: PitchConfig) -> int:
    """Panorama rows with an edge point on ``line``, weak points included: a real edge against a background
    of nearly its own brightness falls below the fitting threshold over half its length (random picks
    11 and 61: a load edge before a grey wall scored 0.49 of its length), but its maxima stay on the line."""
    on_line = np.abs(directions @ line.normal) < config.inlier_tolerance * panorama.pixel_size()
    return int(np.unique(rows[on_line]).size)


def _line(
    panorama: Panorama, directions: Array, weights: Array, lon: tuple[float, float], config: PitchConfig
) -> SphereLine | None:
    """:func:`~agf.vision.hough.hough_line` with the configured inclination range and inlier distance."""
    tolerance = config.inlier_tolerance * panorama.pixel_size()
    return hough_line(panorama, directions, weights, lon, config.tau_max, tolerance=tolerance)


def _anchor_decides(
    line: SphereLine, rival: SphereLine, anchor: Array | None, panorama: Panorama, config: PitchConfig
) -> bool:
    """Whether the point the pose pins tells the edge from its rival.

    The deck edge must pass through the deck's front corner, which the pose puts within a pixel or
    two; a bed seam or a neighbour's edge beside it misses that corner, a shadow hugging the edge
    does not, so a rival closer than ``anchor_gap`` to the corner still makes the edge ambiguous.
    """
    if anchor is None:
        return False
    pixel = panorama.pixel_size()
    miss_line, miss_rival = abs(anchor @ line.normal) / pixel, abs(anchor @ rival.normal) / pixel
    return miss_line <= config.anchor_tolerance and miss_rival - miss_line >= config.anchor_gap


def _pitch_from_direction(direction_f: Array, pallet_in_fork: Transform, hypothesis: str) -> float:
    yaw = pallet_in_fork.euler[0]
    forward = direction_f[0] * math.cos(yaw) + direction_f[1] * math.sin(yaw)
    if hypothesis == "unloaded":  # the direction is pallet X: positive pitch tips it down
        return math.atan2(-direction_f[2], forward)
    return math.atan2(forward, direction_f[2])  # pallet Z, turned by 90 deg


def _panorama_over(axis: Array, segments: list[Array], config: PitchConfig) -> Panorama:
    """A panorama around ``axis`` just large enough for the segments and their bands.

    Longitude 0 points at the segments, so that their longitude range never wraps through the back of
    the sphere (the deck edges, below a camera, were 300 deg apart through its top, not 60 through its
    bottom: a panorama five times too wide).
    """
    directions = _unit(np.concatenate(segments))
    probe = Panorama.around(axis, 3600, 1800, reference=directions.mean(axis=0))
    pixels = probe.pixels_from_directions(directions)
    lon, lat = probe.angles_from_pixels(pixels)
    margin = config.band + math.radians(1.0)
    lon_range = (float(lon.min() - margin), float(lon.max() + margin))
    lat_range = (
        float(max(lat.min() - math.radians(1.0), -math.pi / 2)),
        float(min(lat.max() + math.radians(1.0), math.pi / 2)),
    )
    width = int(math.ceil((lon_range[1] - lon_range[0]) / config.pixel))
    height = int(math.ceil((lat_range[1] - lat_range[0]) / config.pixel))
    return Panorama.around(axis, width, height, reference=probe.reference, lon_range=lon_range, lat_range=lat_range)


def _edge_points(image: NDArray[np.float32], valid: NDArray[np.bool_], panorama: Panorama, areas: list[Array]):
    """Sub-pixel maxima of the horizontal gradient along each row above half an adaptive threshold, and
    which of them reach the threshold itself (the strong ones that lines are fitted to).

    Directions (camera frame) are computed only for maxima in one of the ``areas`` (regions as
    :func:`_region` gives them), NaN elsewhere: the rest of the panorama only sets the threshold.
    """
    smooth = cv2.GaussianBlur(image, (0, 0), 0.8)
    gx = np.abs(cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3))
    gx[~cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)] = 0.0
    # The statistics of the gradient, from every 4th row and column: the full sort cost 15 ms a panorama.
    sample, sampled_valid = gx[::4, ::4], valid[::4, ::4]
    inside = sample[sampled_valid]
    noise = 1.4826 * np.median(np.abs(inside - np.median(inside))) if inside.size else 0.0
    threshold = max(6.0 * noise, 0.2 * float(np.percentile(sample, 99)), 1e-3)
    centre = gx[:, 1:-1]
    peak = (centre > gx[:, :-2]) & (centre >= gx[:, 2:]) & (centre > 0.5 * threshold)  # not in the outer columns
    rows, cols = np.nonzero(peak)
    cols += 1
    l, c, r = gx[rows, cols - 1], gx[rows, cols], gx[rows, cols + 1]
    offset = 0.5 * (l - r) / np.where(l - 2 * c + r < 0, l - 2 * c + r, -1.0)
    columns, rows = cols + offset, rows.astype(float)
    needed = np.any([_inside(area, columns, rows) for area in areas], axis=0)
    directions = np.full((len(rows), 3), np.nan)
    directions[needed] = panorama.directions_from_pixels(np.stack([columns[needed], rows[needed]], axis=1))
    return directions, c > threshold, columns, rows


def _from_reference_viewpoint(camera: CameraModel, directions: Array, segment: Array) -> Array:
    """Directions from the reference viewpoint to the edge points, undoing the viewpoint shift.

    A ray leaves the lens at its own shifted pupil, so edge points of one 3D line are not on one great
    circle of ray directions. Placing each point on its ray at the depth of the predicted line (a depth
    error of a few per cent moves it by a fraction of the millimetre-scale shift) restores that.
    """
    origins = camera.origins(directions)
    if not np.any(origins):
        return directions
    start, u = segment[0], _unit(segment[-1:] - segment[:1])[0]
    w = start - origins
    du = directions @ u
    depth = (np.sum(w * directions, axis=1) - (w @ u) * du) / np.maximum(1.0 - du**2, 1e-9)
    return _unit(origins + depth[:, None] * directions)


def _unit(points: Array) -> Array:
    return points / np.linalg.norm(points, axis=1, keepdims=True)
