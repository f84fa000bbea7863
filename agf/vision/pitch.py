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

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from numba import njit
from numpy.typing import NDArray

from agf.camera.base import CameraModel
from agf.geometry import Transform, matrix_from_euler
from agf.pallets import PalletType
from agf.vision.edges import mad_sigma
from agf.vision.hough import SphereLine, common_direction, fit_plane_normal, hough_line, refine_line
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
    # An ambiguous pair whose pairings' pitches all lie within this gives their midpoint (_between_rivals): half of it
    # is the most the midpoint can err from the pairing that is the pallet's, the measurement's max_sigma_pitch
    rival_spread: float = math.radians(0.1)
    anchor_tolerance: float = 5.0  # panorama pixels: an edge this close to the point the pose pins ...
    anchor_gap: float = 3.0  # ... beats a rival that misses that point by this many pixels more
    anchor_lines: int = 2  # lines after the strongest searched for one through that point (_line_through) ...
    pinned_strength: float = 0.8  # ... at least this strong against it
    # The lines on the load's face (carton joints, tape, label sides) are parallel to its edges: their
    # common direction gives the loaded pitch from many lines, not from two (see load_face_direction).
    face_inset: float = 4.0  # panorama pixels inside the load edges: a silhouette's gradient maximum
    # moves with the contrast against the background (wall above, floor below) and leaned the pitch 0.2 deg
    face_scan: float = math.radians(1.5)  # pitches searched either side of the pose's
    # ... and, where no face direction lies within face_scan but the load's edges agree on a pitch, this far: a face
    # leaning further is a contradiction, not silence (campaign seed 7 pick 206: a loaded pallet pitched 3.6 deg, its
    # edges found on lines at 0.72 deg, accepted there; its face's lines lay beyond 0.72 +- 1.5 deg)
    face_scan_wide: float = math.radians(5.0)
    face_step: float = math.radians(0.02)
    face_min_points: int = 25  # edge points (panorama rows) for a line on the face to count ...
    face_min_lines: int = 3  # ... and lines for the face's direction to count
    face_agreement: float = math.radians(0.12)  # the load edges' pitch (or one with a rival) must be this close
    face_max_sigma: float = math.radians(0.065)  # a face direction this uncertain is no pitch: 1.5 sigma
    # within the 0.1 deg the measurement promises
    # Two edges of the pallet meet at a point on its axis, which the face's pose puts within a degree of
    # yaw; shadows of two uprights across a deck meet where the light is (random looks: 2.0 deg across,
    # accepted 4.2 deg off in pitch). Calls within 0.15 deg of the true pitch ran at most 1.14 deg across. A pairing
    # with a rival line beside an edge that runs further across is no rival pitch either (session 48): campaign seed 7,
    # picks 13 and 27, such pairings 1.57 and 3.2 deg across (3.7 and 6.9 deg from the pair's pitch, the pair's 0.01
    # and 0.04 across) refused deck edges that measured 0.04 and 0.00 deg off without them.
    max_across: float = math.radians(1.5)
    # Many tight lines on the face give the pitch without the load's edges: on random looks the two edges,
    # fitted alone, sat 0.4-0.55 deg off on carton joints or background while 15 or more lines within
    # 0.03 deg were within 0.05 deg of the truth; with fewer or looser lines the face erred up to 0.27 deg.
    face_alone_lines: int = 15
    face_alone_sigma: float = math.radians(0.03)
    # ... or lines of any number that fix the pitch this tightly: at the true poses of the 185 loaded frames of the
    # randomised set (campaign seeds 7 and 4242, paper scenes under random looks), the 47 faces within 0.02 deg were
    # all within 0.1 deg of the truth (one 0.071 off), while 2 of the 53 with 15 lines within 0.03 deg were 0.18 and
    # 0.42 off. Measured, it took 6 frames more within the bounds and lost one, no wrong accept (374 frames).
    face_alone_tight: float = math.radians(0.02)
    # A pair of deck edges this uncertain (their tilts' standard errors, see tilt_sigma) is no pitch either.
    edge_max_sigma: float = math.radians(0.065)
    # Nor is one beside a deck this close to the sensor's 255 along both edges (each edge's median highlight,
    # edge_highlights): the optics blur an overexposed deck's light past its outline before the sensor clips it, and
    # JPEG's ringing at the clipped edge moves the edge's gradient maxima outwards by a growing fraction of a pixel
    # towards the deck's far end. Of the 181 unloaded measurements on 604 randomised first frames (374 as drawn,
    # 230 seen level with the forks), the 10 with both edges at 243 or more were 0.04-0.23 deg off in pitch, 4 of
    # them outside the 0.1 deg bound (campaign seed 7 pick 38: -0.146), while the next brightest (236) was within
    # 0.052; campaign seed 4242 pick 22 rendered without its JPEG step was 0.047 deg off instead of 0.194, at 0.7 of
    # its exposure 0.029. Lowering the camera's exposure keeps the deck's edges off the clipped highlights. Since
    # session 34 the highlight is the brightest colour channel's (grey where no colour frame is given): one clipped
    # channel does the same (a red deck at R 252-255 beside both edges, grey 170-200), and behind a JPEG no other
    # channel finds the edge again. On the 294 frames of 145 campaign picks (seed 7) it refused 8 measurements 0.1-0.34
    # deg off and 9 within the bounds; campaign picks 660, 707, 735, 858 and 930 accept none outside them now.
    max_deck_highlight: float = 240.0
    # ... nor one with this share of either edge's points beside a clipped channel (CLIPPED), bright as the other
    # edge may be: at the true poses of 303 unloaded frames (campaign seed 7's first 400 first frames, and its 76
    # picks refused for an overexposed deck rendered again at 0.6 and 0.36 of their light), the rule above flagged 11
    # of the 31 pitches outside the 0.1 deg bound, this one 4 more (one edge clipped: pick 163 +0.40 deg, 398 -0.33,
    # 31 -0.11; pick 360 at 0.6 of its light -0.15 with 36 % of an edge clipped, medians 227 and 218) and 21 more of
    # the 272 within it. Since session 35 the controller answers both with a shorter exposure, not a refused pick.
    max_deck_clipped: float = 0.2
    # Neither deck edges nor load edges found, with this share of the top deck clipped in every channel: refused as
    # overexposed (deck_top_clipped), as a deck and a floor both clipped show no edge to find and a shorter exposure
    # does (campaign seed 7, pick 214: 72 % clipped, refused for no pitch; at 0.36 of its light measured 0.08 deg
    # off). Not where a load's edges were found: the clipped top is then the load's, and measured again darker the
    # load's edges gave a pitch 0.185 deg off and were accepted (pick 205); of the other 21 loaded picks whose
    # exposures it changed, one more inserted (922, no load's edges found: kept) and one fewer (875).
    max_deck_top_clipped: float = 0.5
    # Edges found in the colour frame's gradient (the channels' gradients' root sum of squares) instead of the grey's,
    # where the colour frame is given: a terracotta deck on a grey bed differs from it by a few grey levels. Only to
    # look for the deck's edges past a load (measure_pallet check_deck_in_colour), never to measure: searched so
    # where the grey found no edges (session 44), they measured the first frames of campaign seed 7's picks 75 and
    # 108 -0.114 and -0.107 deg off in pitch, as a JPEG keeps hue at half the resolution of brightness.
    colour_edges: bool = False
    # A load hides the top deck's side edges: where the loaded hypothesis is taken, the unloaded one found them over
    # at most 26 % of their length on 62 right loaded measurements (random looks, campaign first frames). Rack
    # uprights behind an unloaded pallet, taken for a load's edges with the deck's edges found over 42 %, gave the
    # world's vertical: 2.4 deg off (campaign seed 7, pick 35, the forks 150 mm lower).
    max_deck_under_load: float = 0.3
    # Seen from above, a load's top face shows two side edges along pallet X, as the deck's do. At the true poses of
    # the 85 loaded frames of the randomised set whose camera was over 0.1 m above the load, they gave a pitch in 63,
    # 54 of them within 0.1 deg (the rest up to 0.17 off, as deck edges err): a third cue, counted only where it
    # agrees with the load's edges or its face's lines. The load's height is not known: tops are searched from
    # ``top_lowest`` above the deck to ``top_above`` below the camera, ``top_step`` apart (steps of 0.15 m found 51
    # pitches, 44 within 0.1 deg; 0.25 m 31, 27), each within the wider ``top_band`` (nor is the load's width).
    top_lowest: float = 0.3
    top_above: float = 0.1
    top_step: float = 0.1
    top_band: float = math.radians(6.0)
    # At those true poses, 5 of the 11 top faces fitted to over 0.035 deg were over 0.1 deg off, 4 of the 52 within it.
    top_max_sigma: float = math.radians(0.035)


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
        The edges' common direction, camera frame (NaN when not valid, unless ``ambiguous``).
    panorama : Panorama
        The panorama the edges were searched in (for overlays).
    regions : list of (4,) arrays
        Predicted regions as panorama (col_min, col_max, row_min, row_max).
    lines : list of SphereLine
        The edges found.
    sigma : float
        Standard deviation of the pitch (rad), from the scatter of each line's inlier directions (where
        ``ambiguous``, of the edges' own pair).
    ambiguous : bool
        A second strong line runs beside one of the edges (a rack upright next to a load edge, a shadow)
        and gives another pitch: the fit cannot tell which is the edge, so the hypothesis is not valid (unless
        the pairings' pitches lie close enough to give their midpoint, :func:`_between_rivals`).
    placed : bool
        The edges' positions are known too (no line beside them, or the deck's front corner picked the line
        through it): only then may they move the pose (:func:`pose_from_deck_edges`); a rival that gives the same
        pitch leaves the pitch valid.
    candidates : tuple of float
        The pitches (rad) of the edge pair and of every pair with a rival line in it whose direction runs along the
        pallet's axis (within the configured ``max_across``).
    face_points : (N, 3) array or None
        Loaded only: directions (camera frame) of the edge points between the load's edges.
    note : str
        Why a hypothesis whose edges were found is not valid, when it is not the ratio or a rival.
    lead : float
        Loaded, when the edges disagree with the lines on the load's face: the face's pitch (rad), at which
        the pose may be searched again, as the edges are searched around the pitch they are predicted at;
        never a measurement (NaN otherwise).
    highlights : tuple of float
        Each edge's median highlight (:func:`edge_highlights`): the brightest level (0-255) within a few pixels
        of its points along their rows, of the brightest colour channel where the colour frame was given, else of the
        grey (NaN for an edge not found).
    clipped : tuple of float
        Each edge's share of points whose highlight is clipped (:data:`CLIPPED` or more; NaN for an edge not found).
    shown : float
        ``ratio`` counting the edge points beside light clipped in every channel, which no channel places: what
        the edges would show with a shorter exposure (each edge counted so only where it is short of the configured
        ``min_ratio``; 0 for an edge not found with no point clipped so).
    top_clipped : float
        Unloaded, its edges found over less than the configured ``min_ratio``: the share of the top deck clipped in
        every channel (:func:`deck_top_clipped`; 0 otherwise).
    overexposed : bool
        Not valid because the highlights beside the edges are clipped: a shorter exposure may find the edges.
    top : PitchEvidence or None
        Loaded, where its edges and face did not settle the pitch by themselves: the load's top face
        (:func:`load_top_evidence`) searched at the same pose and checked against; None where none was searched or
        the camera is not above the load.
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
    candidates: tuple[float, ...] = ()
    face_points: Array | None = None
    note: str = ""
    lead: float = math.nan
    highlights: tuple[float, ...] = ()
    clipped: tuple[float, ...] = ()
    shown: float = 0.0
    top_clipped: float = 0.0
    overexposed: bool = False
    top: PitchEvidence | None = None

    @property
    def offered(self) -> list[float]:
        """The pitch (rad) where valid, else the pitches of its pairings (:attr:`candidates`; none where no pair was
        found)."""
        return [self.pitch] if self.valid else list(self.candidates)


def unloaded_evidence(
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig = PitchConfig(),
    *,
    colour: NDArray[np.uint8] | None = None,
) -> PitchEvidence:
    """The top deck's left and right edges, parallel to pallet X; ``colour``, the frame ``gray`` was made from,
    lets edges beside clipped light be read where a channel is not clipped (:func:`unclipped_edge_columns`)."""
    x = np.linspace(0.03, pallet.length - 0.03, 24)
    segments = [
        np.c_[x, np.full_like(x, side * pallet.width / 2), np.full_like(x, pallet.deck_top)] for side in (-1, 1)
    ]
    pair = _between_rivals(_evidence("unloaded", gray, camera, camera_in_fork, pallet_in_fork, segments, 0, config,
                                     anchored=True, colour=colour), config)
    if not pair.valid and pair.ratio < config.min_ratio:
        top = deck_top_clipped(gray if colour is None else colour, camera, camera_in_fork, pallet, pallet_in_fork)
        return _blinded(dataclasses.replace(pair, top_clipped=top), config)
    if not pair.valid:
        return pair
    if pair.sigma > config.edge_max_sigma:
        note = (f"the deck edges give the pitch only to +-{math.degrees(pair.sigma):.2f} deg (at most "
                f"{math.degrees(config.edge_max_sigma):.3f}): their points wander off the lines")
    elif min(pair.highlights) >= config.max_deck_highlight or max(pair.clipped) >= config.max_deck_clipped:
        note = (f"the top deck is overexposed beside its edges (brightest channel {pair.highlights[0]:.0f} and "
                f"{pair.highlights[1]:.0f} of 255, below {config.max_deck_highlight:.0f} on one side at least; "
                f"{pair.clipped[0]:.0%} and {pair.clipped[1]:.0%} of their points clipped, at most "
                f"{config.max_deck_clipped:.0%}): clipped highlights move the edges' lines; lower the camera's "
                "exposure")
        return _refused(pair, note, overexposed=True)
    else:
        return pair
    return _refused(pair, note)


def _between_rivals(pair: PitchEvidence, config: PitchConfig) -> PitchEvidence:
    """An ambiguous ``pair`` whose pairings' pitches lie within ``config.rival_spread``, made valid at their
    midpoint, half their spread added to its sigma, its edges' positions not known (``placed`` False); any other
    evidence as it is.

    Where one of the pairings is the pallet's edges, the midpoint is within half the spread of their pitch. At the
    true poses of the randomised bench's unloaded looks, the four ambiguous deck edges spread 0.06-0.13 deg and their
    midpoints were 0.003-0.039 deg off; random look 1 of paper scene unloaded-high-flat was refused for a line 2.6 px
    beside one deck edge (pairings +0.024 and -0.069 deg off). A load's such pair is checked against the lines on its
    face as any pair is (random look 5 of loaded-low-rear-up: +0.018 and -0.026, a face of -0.032 that agreed with
    both was refused for it). Pairings that are all off are not within half the spread (campaign seed 7 pick 22: 0.24
    and 0.31 deg low), so the midpoint meets every check a pair meets.
    """
    low, high = min(pair.candidates, default=0.0), max(pair.candidates, default=0.0)
    if not pair.ambiguous or high - low > config.rival_spread:
        return pair
    return dataclasses.replace(pair, valid=True, pitch=(low + high) / 2, sigma=math.hypot(pair.sigma, (high - low) / 2),
                               ambiguous=False, placed=False)


def _blinded(pair: PitchEvidence, config: PitchConfig) -> PitchEvidence:
    """The deck edges ``pair``, found over too little of their length, refused as overexposed where their points
    beside light clipped in every channel make up :attr:`PitchConfig.min_ratio` (:attr:`PitchEvidence.shown`).
    Campaign seed 7, pick 42: a white deck under three lamps showed its edges over 22 % of their length in colour,
    87 % with those points, and was refused for no pitch, with no shorter exposure asked for."""
    if pair.shown < config.min_ratio:
        return pair
    return _refused(pair, f"the top deck is overexposed beside its edges: they show over {pair.ratio:.0%} of their "
                    f"length, over {pair.shown:.0%} with the points beside light clipped in every channel (need "
                    f"{config.min_ratio:.0%}); lower the camera's exposure", overexposed=True)


def deck_top_clipped(
    image: NDArray, camera: CameraModel, camera_in_fork: Transform, pallet: PalletType, pallet_in_fork: Transform,
    samples: int = 12,
) -> float:
    """The share of the top deck that ``image`` (colour (H, W, 3) or grey (H, W), uint8) shows clipped in every
    channel (:data:`CLIPPED` or more), sampled on a grid ``samples`` x ``samples`` 50 mm inside its outline at the
    pose ``pallet_in_fork``; 0 where the camera is not above the deck or sees none of the grid."""
    pallet_in_camera = camera_in_fork.inverse() @ pallet_in_fork
    if pallet_in_camera.inverse().translation[2] <= pallet.deck_top:
        return 0.0
    x = np.linspace(0.05, pallet.length - 0.05, samples)
    y = np.linspace(0.05 - pallet.width / 2, pallet.width / 2 - 0.05, samples)
    grid = np.stack(np.meshgrid(x, y), axis=-1).reshape(-1, 2)
    pixels, seen = camera.project(pallet_in_camera.apply(np.c_[grid, np.full(len(grid), pallet.deck_top)]))
    if not seen.any():
        return 0.0
    columns, rows = np.round(pixels[seen]).astype(int).T
    levels = image[np.clip(rows, 0, image.shape[0] - 1), np.clip(columns, 0, image.shape[1] - 1)]
    return float(np.mean((levels if levels.ndim == 1 else levels.min(axis=1)) >= CLIPPED))


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
    normals = _deck_edge_normals(evidence)
    forward = camera_in_fork.apply_direction(evidence.direction)
    turned = Transform.from_euler(
        *pallet_in_fork.translation,
        0.0,
        math.atan2(-forward[2], math.hypot(forward[0], forward[1])),
        math.atan2(forward[1], forward[0]),
    )
    in_camera = camera_in_fork.inverse() @ turned
    R, origin = in_camera.rotation, in_camera.translation
    shift = np.linalg.solve(normals @ R[:, 1:], -np.sum(normals * in_camera.apply(_deck_front_corners(pallet)), axis=1))
    return camera_in_fork @ Transform(R, origin + R[:, 1:] @ shift)


def deck_corner_misses(
    evidence: PitchEvidence, pallet: PalletType, camera_in_fork: Transform, pallet_in_fork: Transform
) -> Array:
    """How far (panorama pixels) each deck edge line of a valid unloaded ``evidence`` passes from the deck's front
    corner at ``pallet_in_fork``, shape (2,): the left (-y) edge's, then the right's. Lines parallel to the edges
    (a bed seam, a neighbour's edge) give the edges' pitch and miss the corners; a shadow's edge that runs from a far
    corner past a near one does not give it."""
    normals = _deck_edge_normals(evidence)
    directions = _unit((camera_in_fork.inverse() @ pallet_in_fork).apply(_deck_front_corners(pallet)))
    return np.abs(np.sum(directions * normals, axis=1)) / evidence.panorama.pixel_size()


def _deck_edge_normals(evidence: PitchEvidence) -> Array:
    """The great-circle normals (2, 3) of a valid unloaded ``evidence``'s deck edges, left (-y) then right; else
    ValueError."""
    if evidence.hypothesis != "unloaded" or not evidence.valid:
        raise ValueError(
            f"deck edges need a valid unloaded hypothesis, got {evidence.hypothesis} (valid={evidence.valid})"
        )
    return np.array([line.normal for line in evidence.lines])


def _deck_front_corners(pallet: PalletType) -> Array:
    """The top deck's front corners (2, 3), pallet frame, left (-y) then right."""
    return np.array([[0.0, side * pallet.width / 2, pallet.deck_top] for side in (-1, 1)])


def loaded_evidence(
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig = PitchConfig(),
    *,
    colour: NDArray[np.uint8] | None = None,
) -> PitchEvidence:
    """The load's left and right vertical edges, parallel to pallet Z, within the pallet's width (``colour`` as
    for :func:`unloaded_evidence`)."""
    inset = config.load_search / 2

    def edges_up_to(height: float, count: int) -> list[Array]:
        z = np.linspace(pallet.deck_top + 0.02, pallet.deck_top + height, count)
        return [np.c_[np.zeros_like(z), np.full_like(z, side * (pallet.width / 2 - inset)), z] for side in (-1, 1)]

    band = math.atan2(inset + 0.03, float(np.linalg.norm(pallet_in_fork.translation - camera_in_fork.translation)))
    pair = _evidence(
        "loaded",
        gray,
        camera,
        camera_in_fork,
        pallet_in_fork,
        edges_up_to(config.load_height, 24),
        2,
        PitchConfig(**{**config.__dict__, "band": max(config.band, band)}),
        reach_p=edges_up_to(config.load_reach, 48),
        face=True,
        colour=colour,
    )
    pair = _between_rivals(pair, config)
    if not pair.candidates:
        return pair
    points = _face_points(pair, camera, camera_in_fork, pallet, pallet_in_fork, config)
    face = load_face_direction(pair, camera, camera_in_fork, pallet, pallet_in_fork, config, points=points)
    pair, face = _without_vague_face(pair, face, config)
    if face is None and pair.valid:
        checked = _checked_by_wide_face(pair, points, camera, camera_in_fork, pallet, pallet_in_fork, config)
        if not checked.valid:
            return checked
        top = load_top_evidence(gray, camera, camera_in_fork, pallet, pallet_in_fork, config, colour=colour)
        return _checked_by_load_top(checked, top, config)
    if face is None:
        return _confirmed_by_load_top(pair, None, gray, camera, camera_in_fork, pallet, pallet_in_fork, config, colour)
    nearest = min(pair.candidates, key=lambda c: abs(c - face.pitch))
    miss = abs(nearest - face.pitch)
    alone = face.sigma <= config.face_alone_tight or (
        face.lines >= config.face_alone_lines and face.sigma <= config.face_alone_sigma
    )
    if miss > config.face_agreement and not alone:
        lead = face.pitch if face.sigma <= config.face_max_sigma else math.nan
        return _confirmed_by_load_top(_refused(pair, _edges_against_face(pair.candidates, face), lead), face, gray,
                                      camera, camera_in_fork, pallet, pallet_in_fork, config, colour)
    # A face that is no pitch alone picks a pairing with a line beside an edge over the edges' own pair only where no
    # other pitch agrees with it: paper scene loaded-middle-front-up under random look 4, its face's 10 lines 0.17 deg
    # low to +-0.034, took the nearer of two rival pairings 0.11 and 0.07 deg low (the edges' own pair 0.12 high) and
    # was accepted 0.135 off. Agreeing with the edges' own pair it may (campaign seed 7 pick 597's third view: the
    # pair 1.93 deg, a rival pairing 1.88, the face 1.92).
    rivals = [c for c in pair.candidates
              if abs(c - face.pitch) <= config.face_agreement and abs(c - nearest) > config.rival_pitch]
    if pair.ambiguous and rivals and not alone and abs(nearest - pair.candidates[0]) > config.rival_pitch:
        refused = _refused(pair, f"{_edges_against_face(pair.candidates, face)}, which agrees with more than one of "
                                 "the edges' pitches")
        return _confirmed_by_load_top(refused, face, gray, camera, camera_in_fork, pallet, pallet_in_fork, config,
                                      colour)
    if alone and miss > config.face_agreement:
        return dataclasses.replace(pair, valid=True, pitch=face.pitch, direction=face.direction, ambiguous=False,
                                   sigma=face.sigma)
    # Where the face agrees with the edges, the edges count as much as the face: its lines lean together by up to
    # 0.13 deg (one carton row's joints), the edges err on their own; at the true pose of 36 random looks the face
    # was up to 0.13 deg off where the two agreed, their mean at most 0.08. So also a face that fixes the pitch
    # alone: campaign seed 7 pick 107's verifying frame, 15 lines to +-0.025 deg 0.11 deg high, its edges (a line
    # beside one pairing 0.046 deg from it) within 0.04 deg, was accepted 0.109 deg off from the face alone.
    return _loaded_at(pair, (face.pitch + nearest) / 2, math.hypot(face.sigma, miss / 2), camera_in_fork,
                      pallet_in_fork)


def _without_vague_face(
    pair: PitchEvidence, face: FaceDirection | None, config: PitchConfig
) -> tuple[PitchEvidence, FaceDirection | None]:
    """The load's edges ``pair`` and the lines on its ``face``, the face dropped where it fixes the pitch more loosely
    than :attr:`PitchConfig.face_max_sigma` and agrees with one of the edges' candidates within
    :attr:`PitchConfig.face_agreement`: such a face cannot check the edges and says nothing against them, as no face
    does (then the face scanned wider and the load's top must not disagree). How far it lies from them still counts
    in their sigma, as where a sure face agrees. Until session 50 such frames were refused ("the N lines on the
    load's face give its pitch only to ..."): of the 494 loaded first frames of campaign seed 7's picks 0-999, 11 more
    are measured within the bounds and one fewer (821), none more outside them; without that sigma, 14 more were
    accepted, one of them 0.103 deg off (pick 530, its vague face and its edges both 0.1 deg off the same way). In
    that campaign's picks 0-728 it inserted 8 more picks, and one of them, 488, accepted its verifying frame 0.102 deg
    off (open: tests/integration/test_clock_pick.py)."""
    if face is None or face.sigma <= config.face_max_sigma:
        return pair, face
    miss = min(abs(c - face.pitch) for c in pair.candidates)
    if miss > config.face_agreement:
        return pair, face
    return (dataclasses.replace(pair, sigma=math.hypot(pair.sigma, miss / 2)) if pair.valid else pair), None


def _edges_against_face(candidates: Sequence[float], face: FaceDirection) -> str:
    """Why the load's edges (their candidate pitches, rad) and the lines on its face disagree."""
    return (f"the load's edges give a pitch of {', '.join(f'{math.degrees(c):.2f}' for c in candidates)} deg, "
            f"the {face.lines} lines on its face {math.degrees(face.pitch):.2f} deg")


def _refused(evidence: PitchEvidence, note: str, lead: float = math.nan, overexposed: bool = False) -> PitchEvidence:
    """``evidence`` made invalid for ``note``, with the pitch (rad) the face leads to, if any, and whether clipped
    highlights are why."""
    return dataclasses.replace(evidence, valid=False, pitch=math.nan, direction=np.full(3, np.nan), ambiguous=False,
                               note=note, lead=lead, overexposed=overexposed)


def _checked_by_wide_face(
    pair: PitchEvidence,
    points: Array,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig,
) -> PitchEvidence:
    """A valid pair of load edges whose face showed no direction within :attr:`PitchConfig.face_scan` of the pose's
    pitch, refused where the face's lines, scanned :attr:`PitchConfig.face_scan_wide` either side, lean further than
    :attr:`PitchConfig.face_agreement` from the edges' pitch (led to the face's pitch when it is sure enough, as any
    face the edges disagree with); else ``pair`` as it is. A face found only so far away never gives the pitch
    itself: among more pitches, lines of another direction (rack uprights, a neighbour's load) bunch more easily.
    ``points``: the face's points (:func:`_face_points`), as the narrow scan had them."""
    wide = load_face_direction(pair, camera, camera_in_fork, pallet, pallet_in_fork, config, scan=config.face_scan_wide,
                               points=points)
    if wide is None or abs(wide.pitch - pair.pitch) <= config.face_agreement:
        return pair
    return _refused(pair, _edges_against_face(pair.candidates, wide),
                    wide.pitch if wide.sigma <= config.face_max_sigma else math.nan)


def _checked_by_load_top(pair: PitchEvidence, top: PitchEvidence | None, config: PitchConfig) -> PitchEvidence:
    """A valid pair of load edges that no line on the load's face confirmed, refused where the load's ``top`` face
    disagrees with it (:func:`load_top_disagrees`); else ``pair`` as it is; either carries ``top``. Two edges alone
    follow a rival line as easily as the load's outline: a loaded pallet pitched 3.32 deg, seen from 150 mm below
    campaign seed 7 pick 29's start, was accepted 0.15 deg off from its edges alone, its top face at 3.26 deg (its
    face's lines, 5-6 of them, found at some poses and not at others)."""
    pair = dataclasses.replace(pair, top=top)
    if not load_top_disagrees(pair.pitch, top, config):
        return pair
    return _refused(pair, f"the load's edges give a pitch of {math.degrees(pair.pitch):.2f} deg, its top face "
                          f"{math.degrees(top.pitch):.2f} deg")


def load_top_disagrees(pitch: float, top: PitchEvidence | None, config: PitchConfig) -> bool:
    """Whether the load's ``top`` face (:func:`load_top_evidence`), fitted to :attr:`PitchConfig.top_max_sigma`,
    gives a pitch more than :attr:`PitchConfig.face_agreement` from a loaded ``pitch`` (rad)."""
    if top is None or not top.valid or top.sigma > config.top_max_sigma:
        return False
    return abs(top.pitch - pitch) > config.face_agreement


def _loaded_at(
    evidence: PitchEvidence, pitch: float, sigma: float, camera_in_fork: Transform, pallet_in_fork: Transform
) -> PitchEvidence:
    """``evidence`` made valid at ``pitch`` (rad) to ``sigma``, its direction the load's vertical at that pitch."""
    yaw, _, roll = pallet_in_fork.euler
    direction = camera_in_fork.inverse().rotation @ matrix_from_euler(yaw, pitch, roll)[:, 2]
    return dataclasses.replace(evidence, valid=True, pitch=pitch, direction=direction, ambiguous=False, sigma=sigma,
                               note="", lead=math.nan)


def _confirmed_by_load_top(
    refused: PitchEvidence,
    face: FaceDirection | None,
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig,
    colour: NDArray[np.uint8] | None,
) -> PitchEvidence:
    """A loaded hypothesis the edges and face could not settle, given the pitch where the load's top face
    (:func:`load_top_evidence`, fitted to :attr:`PitchConfig.top_max_sigma`) agrees within
    :attr:`PitchConfig.face_agreement` with the edges' pitch or with a face that is sure enough (their mean); else
    ``refused`` as it is; either carries the top searched, if any. Two independent cues must agree: the top face
    alone errs as the deck edges do, and the pitches of the edges paired with a rival line are not offered to it
    (among several, one agrees by chance: a load accepted 0.16 deg off so, campaign seed 7 pick 134)."""
    cues = list(refused.candidates[:1])
    if face is not None and face.sigma <= config.face_max_sigma:
        cues.append(face.pitch)
    if not cues:
        return refused
    top = load_top_evidence(gray, camera, camera_in_fork, pallet, pallet_in_fork, config, colour=colour)
    refused = dataclasses.replace(refused, top=top)
    if top is None or not top.valid or top.sigma > config.top_max_sigma:
        return refused
    nearest = min(cues, key=lambda c: abs(c - top.pitch))
    miss = abs(nearest - top.pitch)
    if miss > config.face_agreement:
        return refused
    return _loaded_at(refused, (top.pitch + nearest) / 2, math.hypot(top.sigma, miss / 2), camera_in_fork,
                      pallet_in_fork)


def load_top_evidence(
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig = PitchConfig(),
    *,
    colour: NDArray[np.uint8] | None = None,
) -> PitchEvidence | None:
    """The side edges of a load's top face, parallel to pallet X, where the camera looks down on it; None when the
    camera is not :attr:`PitchConfig.top_above` over the lowest top searched.

    Tops are searched from :attr:`PitchConfig.top_lowest` above the deck to ``top_above`` below the camera,
    :attr:`PitchConfig.top_step` apart, all in one panorama, each pair within :attr:`PitchConfig.top_band` of lines
    ``load_search / 2`` inside the pallet's sides; the valid pair with the highest ratio is returned, else the
    highest ratio. Any line along X on the load's top (a carton joint) gives the same pitch as its sides."""
    lowest = pallet.deck_top + config.top_lowest
    highest = (pallet_in_fork.inverse() @ camera_in_fork).translation[2] - config.top_above
    if highest <= lowest:
        return None
    x = np.linspace(0.03, pallet.length - 0.03, 24)
    y = pallet.width / 2 - config.load_search / 2
    pairs = [[np.c_[x, np.full_like(x, side * y), np.full_like(x, z)] for side in (-1, 1)]
             for z in np.arange(lowest, highest, config.top_step)]
    found = _evidences("load top", gray, camera, camera_in_fork, pallet_in_fork, pairs, 0,
                       dataclasses.replace(config, band=config.top_band), colour=colour)
    return max(found, key=lambda e: (e.valid, e.ratio))


@dataclass(frozen=True)
class FaceDirection:
    """The common direction of the lines on a load's face.

    Attributes
    ----------
    direction : (3,) array
        Unit direction of the lines (pallet Z), camera frame.
    pitch : float
        The pallet pitch it gives, fork frame (rad).
    sigma : float
        Standard deviation of ``pitch`` (rad), from the lines' fits, scaled up by their disagreement.
    lines : int
        How many lines agreed on it.
    """

    direction: Array
    pitch: float
    sigma: float
    lines: int


def load_face_direction(
    evidence: PitchEvidence,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig = PitchConfig(),
    *,
    scan: float | None = None,
    points: Array | None = None,
) -> FaceDirection | None:
    """The direction shared by the lines between the load's two edges (carton joints, tape, labels).

    Cartons stack with their sides parallel to the load's, so every vertical line on the load's face
    points at the vanishing point of its edges. Many lines across the face fix it where two edges,
    each fitted alone, follow a joint of an offset carton row or a stretch of background beside a
    weak silhouette (random looks: 2 of 18 loaded scenes measured within bounds from the two edges,
    15 from the face's lines, at the true pose). Pitches within ``scan`` of the
    pose's are scored by how sharply the edge points' longitudes around the candidate direction bunch
    into lines; at the best one the lines are fitted and their direction is solved for by weighted
    least squares, dropping lines that disagree.

    Parameters
    ----------
    evidence : PitchEvidence
        A loaded hypothesis whose two edges were found, with its ``face_points``.
    camera, camera_in_fork, pallet, pallet_in_fork
        Camera, calibration, pallet type and the pose the edges were searched from.
    scan : float, optional
        Pitches searched either side of the pose's (rad); :attr:`PitchConfig.face_scan` by default.
    points : (N, 3) array, optional
        The face's points where the caller has them already (a second scan of the same evidence); they
        depend on the evidence and the pose, not on the scan.

    Returns
    -------
    FaceDirection or None
        None when fewer than :attr:`PitchConfig.face_min_lines` lines agree, or the best pitch lies at
        the end of the scan.
    """
    if evidence.face_points is None or len(evidence.lines) != 2:
        raise ValueError("the face's direction needs a loaded hypothesis with both edges found and its face points")
    pixel = evidence.panorama.pixel_size()
    if points is None:
        points = _face_points(evidence, camera, camera_in_fork, pallet, pallet_in_fork, config)
    if len(points) < config.face_min_points * config.face_min_lines:
        return None
    yaw, pitch0, roll = pallet_in_fork.euler
    scan = config.face_scan if scan is None else scan
    pitches = pitch0 + np.arange(-scan, scan + config.face_step / 2, config.face_step)
    to_camera = camera_in_fork.inverse().rotation
    # the matrices alone: ~200 Transforms a call (copied and frozen) cost 0.6 s of 18 s of bench measurements
    axes = np.array([to_camera @ matrix_from_euler(yaw, p, roll)[:, 2] for p in pitches])
    found = direction_of_parallel_lines(points, axes, pixel, config)
    if found is None:
        return None
    direction, sigma, lines = found
    pitch = _pitch_from_direction(camera_in_fork.apply_direction(direction), pallet_in_fork, 2)
    return FaceDirection(direction, pitch, sigma, lines)


def direction_of_parallel_lines(
    points: Array, axes: Array, pixel: float, config: PitchConfig = PitchConfig()
) -> tuple[Array, float, int] | None:
    """The common direction of the parallel 3D lines that edge ``points`` lie on.

    Parameters
    ----------
    points : (N, 3) array
        Unit directions of edge points from the viewpoint.
    axes : (K, 3) array
        Candidate directions, K >= 3, one step apart along one path (a scan of pitch): the lines'
        direction is searched among them, then fitted.
    pixel : float
        Angular size of the panorama pixel the points were found in, rad.
    config : PitchConfig
        ``face_min_points`` and ``face_min_lines``, ``inlier_tolerance`` (panorama pixels).

    Returns
    -------
    tuple of ((3,) array, float, int) or None
        The direction (signed like ``axes``), its standard deviation along the scan's path (rad) and
        how many lines agreed on it; None when fewer than ``face_min_lines`` lines agree or the best
        candidate is at either end of the scan.
    """
    reference = _unit(points.mean(axis=0, keepdims=True))[0]
    best = int(np.argmax(_line_sharpness(points, axes, reference, pixel)))
    if best in (0, len(axes) - 1):
        return None
    normals, weights = _face_lines(points, axes[best], reference, pixel, config)
    if len(normals) < config.face_min_lines:
        return None
    keep = np.ones(len(normals), bool)
    for _ in range(3):  # drop the lines that disagree with the others by over 3 sigma, and fit again
        direction = fit_plane_normal(normals[keep], weights[keep], axes[best])
        keep = np.abs(normals @ direction) * np.sqrt(weights) <= 3.0
        if keep.sum() < config.face_min_lines:
            return None
    normals, weights = normals[keep], weights[keep]
    direction = fit_plane_normal(normals, weights, axes[best])
    chi = (normals @ direction) * np.sqrt(weights)
    scale = math.sqrt(max(1.0, float(np.sum(chi**2)) / max(len(normals) - 2, 1)))
    along = _unit((axes[best + 1] - axes[best - 1])[None])[0]
    a, b = normals @ along, normals @ np.cross(direction, along)
    information = np.array([[np.sum(weights * a * a), np.sum(weights * a * b)],
                            [np.sum(weights * a * b), np.sum(weights * b * b)]])  # fmt: skip
    return direction, scale * math.sqrt(float(np.linalg.inv(information)[0, 0])), len(normals)


def _face_points(
    evidence: PitchEvidence,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig,
) -> Array:
    """The loaded hypothesis' face points (N, 3) that lie between its edges, inset by
    :attr:`PitchConfig.face_inset`, above the deck and below where the edges end (the load's top), as
    directions from the reference viewpoint to where they meet the load's front plane."""
    pallet_in_camera = camera_in_fork.inverse() @ pallet_in_fork
    points = evidence.face_points
    pixel = evidence.panorama.pixel_size()
    centre = _unit(pallet_in_camera.apply(np.array([[0.0, 0.0, pallet.deck_top + config.load_height / 2]])))[0]
    between = np.ones(len(points), bool)
    tops = []
    on_plane = _onto_plane(camera, points, pallet_in_camera)
    height = pallet_in_camera.inverse().apply(on_plane)[:, 2]
    for line in evidence.lines:
        distance = points @ line.normal * np.sign(centre @ line.normal)
        between &= distance > config.face_inset * pixel
        on_line = np.abs(distance) < config.inlier_tolerance * pixel
        tops.append(np.percentile(height[on_line], 90) if on_line.any() else pallet.deck_top + config.load_height)
    between &= (height > pallet.deck_top + 0.02) & (height < min(tops))
    return _unit(on_plane[between])


def _onto_plane(camera: CameraModel, directions: Array, pallet_in_camera: Transform) -> Array:
    """Where the rays of ``directions`` (N, 3), from their shifted pupils, meet the plane x = 0 of the
    pallet (camera frame, m): the viewpoint shift leaned the face's lines by up to 0.2 deg of pitch."""
    origins = camera.origins(directions)
    normal, point = pallet_in_camera.rotation[:, 0], pallet_in_camera.translation
    depth = ((point - origins) @ normal) / (directions @ normal)
    return origins + depth[:, None] * directions


def _line_sharpness(points: Array, axes: Array, reference: Array, pixel: float) -> Array:
    """For each candidate axis (K, 3), how sharply the points' longitudes around it bunch: the sum of
    squared counts in bins of half a panorama pixel (each bin with its neighbour), (K,)."""
    e1 = _unit(np.cross(axes, reference))
    e2 = np.cross(axes, e1)
    lon = np.arctan2(e2 @ points.T, e1 @ points.T)  # (K, N)
    return _bunching(lon, 0.5 * pixel)


@njit(cache=True)
def _bunching(lon: Array, half: float) -> Array:  # pragma: no cover - compiled
    """:func:`_line_sharpness` of longitudes ``lon`` (K, N) in bins ``half`` wide, each row's bins counted from its
    lowest: the sums of integer squares are exact, so they equal numpy's (its floor, bincount and sum over the (K, N)
    bins, 0.1 s of a refused campaign frame's 3 s, in two passes without them)."""
    k, n = lon.shape
    if n == 0:
        return np.zeros(k)  # no points bunch anywhere (numpy's minimum over no bins raised)
    low, width = np.empty(k, np.int64), 0
    for i in range(k):
        lo = hi = math.floor(lon[i, 0] / half)
        for j in range(1, n):
            b = math.floor(lon[i, j] / half)
            lo, hi = min(lo, b), max(hi, b)
        low[i], width = lo, max(width, hi - lo + 2)
    sharpness, counts = np.empty(k), np.empty(width, np.int64)
    for i in range(k):
        counts[:] = 0
        for j in range(n):
            counts[math.floor(lon[i, j] / half) - low[i]] += 1
        total = 0
        for b in range(width - 1):
            total += (counts[b] + counts[b + 1]) ** 2
        sharpness[i] = total
    return sharpness


def _face_lines(points: Array, axis: Array, reference: Array, pixel: float, config: PitchConfig) -> tuple[Array, Array]:
    """The lines among ``points`` near the meridians of ``axis``: their great circles' normals (K, 3) and
    weights (K,), the inverse variance of each circle's tilt from its points' scatter and length."""
    e1 = _unit(np.cross(axis, reference)[None])[0]
    e2 = np.cross(axis, e1)
    lon = np.arctan2(points @ e2, points @ e1)
    half = 0.5 * pixel
    bins = np.floor(lon / half).astype(np.int64)
    counts = np.bincount(bins - bins.min())
    paired = counts[:-1] + np.r_[counts[1:]]
    peaks = np.flatnonzero(
        (paired >= config.face_min_points) & (paired >= np.r_[0, paired[:-1]]) & (paired > np.r_[paired[1:], 0])
    )
    tolerance = config.inlier_tolerance * pixel
    normals, weights = [], []
    for peak in peaks:
        centre = (peak + bins.min() + 1.0) * half
        members = points[np.abs(lon - centre) <= pixel]
        start = _unit(np.cross(axis, math.cos(centre) * e1 + math.sin(centre) * e2)[None])[0]
        line = refine_line(members, np.ones(len(members)), start, tolerance)
        if line is None or line.inliers.sum() < config.face_min_points:
            continue
        on = members[line.inliers]
        along = on @ axis
        length = float(np.arcsin(np.clip(along.max(), -1, 1)) - np.arcsin(np.clip(along.min(), -1, 1)))
        spread = max(float(np.std(on @ line.normal)), 0.1 * pixel)
        tilt = spread * math.sqrt(12.0 / len(on)) / max(length, pixel)
        normals.append(line.normal)
        weights.append(1.0 / tilt**2)
    return np.array(normals).reshape(-1, 3), np.array(weights)


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
    face: bool = False,
    colour: NDArray[np.uint8] | None = None,
) -> PitchEvidence:
    """Edges along ``segments_p`` (pallet frame, parallel to pallet axis ``axis_index``); ``anchored``
    when each segment's first point is a model point the pose pins (the deck's front corners); ``reach_p``,
    longer segments along which a found edge is followed for its fit (the load's full height); ``face``:
    keep the edge points of the area the edges' regions span (``face_points``); ``colour``: the frame ``gray`` was
    made from, for the edges beside clipped light."""
    return _evidences(hypothesis, gray, camera, camera_in_fork, pallet_in_fork, [segments_p], axis_index, config,
                      anchored, None if reach_p is None else [reach_p], face, colour)[0]


class _EdgePoints(NamedTuple):
    """Edge points of a panorama (:func:`_edge_points`): directions (N, 3), strong (N,), columns and rows (N,), the
    highlight beside each (N,), and which are ``blinded`` (N,): beside light that clips where no channel shows the
    edge (never strong, never an edge's support; what the edge would show with a shorter exposure)."""

    directions: Array
    strong: NDArray[np.bool_]
    columns: Array
    rows: Array
    highlight: Array
    blinded: NDArray[np.bool_]


def _evidences(
    hypothesis: str,
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet_in_fork: Transform,
    pairs_p: list[list[Array]],
    axis_index: int,
    config: PitchConfig,
    anchored: bool = False,
    reaches_p: list[list[Array]] | None = None,
    face: bool = False,
    colour: NDArray[np.uint8] | None = None,
) -> list[PitchEvidence]:
    """:func:`_evidence` for several pairs of segments at once, from one panorama and one set of edge points (the
    panorama and its edge points cost most); ``face`` keeps the points of the area all regions span."""
    pallet_in_camera = camera_in_fork.inverse() @ pallet_in_fork
    pairs = [[pallet_in_camera.apply(s) for s in pair] for pair in pairs_p]
    reaches = [[pallet_in_camera.apply(s) for s in pair] for pair in reaches_p] if reaches_p is not None else pairs
    segments = [s for pair in pairs + reaches for s in pair]
    search = _searched(hypothesis, gray, camera, camera_in_fork, pallet_in_fork, segments, axis_index, config,
                       anchored=anchored, face=face, colour=colour)
    regions = [[_region(search.panorama, segment, config) for segment in pair] for pair in pairs]
    reach_regions = [[_region(search.panorama, far, config) for far in pair] for pair in reaches]
    return [_pair_evidence(search, pair, far, region, reach_region)
            for pair, far, region, reach_region in zip(pairs, reaches, regions, reach_regions, strict=True)]


def _searched(
    hypothesis: str,
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet_in_fork: Transform,
    segments: list[Array],
    axis_index: int,
    config: PitchConfig,
    *,
    anchored: bool = False,
    face: bool = False,
    colour: NDArray[np.uint8] | None = None,
) -> _Search:
    """The panorama over ``segments`` (camera frame, along pallet axis ``axis_index``) and its edge points in their
    predicted regions, which edges are searched among; ``face`` keeps the points of the area the regions span."""
    pallet_in_camera = camera_in_fork.inverse() @ pallet_in_fork
    panorama = _panorama_over(pallet_in_camera.rotation[:, axis_index], segments, config)
    image, valid = render_panorama(gray, camera, panorama)
    colour_panorama = render_panorama(colour, camera, panorama)[0] if colour is not None else None
    edged = colour_panorama if config.colour_edges and colour_panorama is not None else image
    spanned = np.array([_region(panorama, segment, config) for segment in segments])
    area = np.array([spanned[:, 0].min(), spanned[:, 1].max(), spanned[:, 2].min(), spanned[:, 3].max()])
    areas = list(spanned) + ([area] if face else [])
    points = _EdgePoints(*_edge_points(edged.astype(np.float32), valid, panorama, areas, colour_panorama))
    face_points = points.directions[_inside(area, points.columns, points.rows) & points.strong] if face else None
    return _Search(hypothesis, camera, camera_in_fork, pallet_in_fork, pallet_in_camera, axis_index, config,
                   panorama, points, anchored, face_points)


def deck_front_yaw(
    gray: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    pallet_in_fork: Transform,
    config: PitchConfig = PitchConfig(),
    *,
    colour: NDArray[np.uint8] | None = None,
) -> float | None:
    """The pallet's yaw (rad, fork frame) from the top deck's front edge alone, a line along pallet Y searched as
    any edge here (with ``colour`` as for :func:`unloaded_evidence`), at the pitch and roll of ``pallet_in_fork``
    (with no roll, pallet Y does not turn with the pitch); None where the edge is found along less than
    :attr:`PitchConfig.min_ratio` of its length.

    A third, independent cue to the deck edges' yaw: their direction gives the yaw and the pitch together, so a deck
    edge that follows something beside it (shading on a floor as light as the deck) turns both, while the face's
    own yaw, from the template and pocket fit, was up to 0.44 deg off on frames whose deck edges were right. At the
    true pose of 70 unloaded frames (random looks of the paper scenes, campaign seed 7 first frames and views of them
    from other heights), this edge gave the yaw within 0.047 deg (most within 0.01); the deck edges of the three
    accepted outside the bounds in pitch were 0.15, 0.13 and 0.04 deg off in yaw, of the others 0.045 at most."""
    pallet_in_camera = camera_in_fork.inverse() @ pallet_in_fork
    y = np.linspace(0.03 - pallet.width / 2, pallet.width / 2 - 0.03, 24)
    segment = pallet_in_camera.apply(np.c_[np.zeros_like(y), y, np.full_like(y, pallet.deck_top)])
    search = _searched("deck front", gray, camera, camera_in_fork, pallet_in_fork, [segment], 1, config,
                       colour=colour)
    region = _region(search.panorama, segment, config)
    edge = _edge(search, segment, segment, region, region)
    if edge.line is None or edge.ratio < config.min_ratio:
        return None
    return yaw_from_circle(camera_in_fork.rotation @ edge.line.normal, pallet_in_fork)


def yaw_from_circle(normal: Array, pallet_in_fork: Transform) -> float:
    """The yaw (rad) that puts pallet Y, at the pitch and roll of ``pallet_in_fork``, in the plane of a great circle
    whose unit ``normal`` (3,) is given in the fork frame; of the two, the one nearer the pose's yaw.

    With ``R = Rz(yaw) b``, ``b`` pallet Y turned by the pitch and roll, ``normal . R = 0`` reads
    ``A cos(yaw) + B sin(yaw) + C = 0``."""
    yaw, pitch, roll = pallet_in_fork.euler
    b = matrix_from_euler(0.0, pitch, roll)[:, 1]
    a = b[0] * normal[0] + b[1] * normal[1]
    c = b[0] * normal[1] - b[1] * normal[0]
    base = math.atan2(c, a)
    turn = math.acos(float(np.clip(-b[2] * normal[2] / max(math.hypot(a, c), 1e-12), -1.0, 1.0)))
    return min((math.remainder(base + turn, math.tau), math.remainder(base - turn, math.tau)),
               key=lambda y: abs(math.remainder(y - yaw, math.tau)))


@dataclass(frozen=True)
class _Search:
    """What the pairs searched in one panorama share (:func:`_evidences`): the hypothesis, the geometry, the
    panorama with its edge ``points``, and the pair's options (``anchored``, ``face_points``)."""

    hypothesis: str
    camera: CameraModel
    camera_in_fork: Transform
    pallet_in_fork: Transform
    pallet_in_camera: Transform
    axis_index: int
    config: PitchConfig
    panorama: Panorama
    points: _EdgePoints
    anchored: bool
    face_points: Array | None

    @property
    def predicted(self) -> Array:
        """The edges' predicted direction, camera frame (3,)."""
        return self.pallet_in_camera.rotation[:, self.axis_index]


class _Edge(NamedTuple):
    """One edge of a pair (:func:`_edge`): its line (the fit along the reach where there was one), a rival line
    beside it that the anchor does not rule out, its tilt (:func:`tilt_sigma`), its support ratio, the median
    highlight beside its points (:func:`edge_highlights`) and their share clipped, its support ratio counting the
    points clipped light blinded (:func:`_shown_with_clipped`), and whether the anchor ``pinned``
    the line among others (:func:`_line_through`, or a rival through the anchor; the stronger line is then the rival,
    which the pitch must agree with)."""

    line: SphereLine | None
    rival: SphereLine | None
    tilt: tuple[Array, float] | None
    ratio: float
    highlight: float
    clipped: float
    shown: float  # the ratio with the points blinded by clipped light (_shown_with_clipped) where ``ratio`` is short
    # of min_ratio, else ``ratio``
    pinned: bool = False


def _edge(search: _Search, segment: Array, far: Array, region: Array, reach_region: Array) -> _Edge:
    """The edge along ``segment`` (camera frame) in its predicted ``region``, followed along ``far`` (its
    ``reach_region``) for its fit."""
    panorama, config = search.panorama, search.config
    directions, strong, columns, rows, highlights, blinded = search.points
    inside = _inside(region, columns, rows)
    blind = inside & blinded
    inside &= ~blinded
    lon = (
        panorama.angles_from_pixels(region[None, [0, 2]])[0][0],
        panorama.angles_from_pixels(region[None, [1, 2]])[0][0],
    )
    corrected = _from_reference_viewpoint(search.camera, directions[inside], segment)
    fitted = corrected[strong[inside]]
    ones = np.ones(len(fitted))
    line = _line(panorama, fitted, ones, lon, config)
    length = max(region[3] - region[2], 1.0)  # panorama rows
    if line is None:
        return _Edge(None, None, None, 0.0, math.nan, math.nan,
                     _shown_with_clipped(search, segment, corrected, rows[inside], blind, lon, length))
    rival = _rival_nearby(panorama, fitted, ones, line, lon, config)
    anchor = _unit(segment[:1])[0] if search.anchored else None
    pinned = False
    if rival is not None and _anchor_decides(line, rival, anchor, panorama, config):
        rival = None
    elif rival is not None and _anchor_decides(rival, line, anchor, panorama, config):
        line, rival, pinned = _refit(rival, fitted, ones, panorama, config), line, True
    elif rival is None and anchor is not None:
        through = _line_through(anchor, panorama, fitted, ones, line, lon, config)
        if through is not None:
            line, rival, pinned = through, line, True
    along = _inside(reach_region, columns, rows) & strong
    grown = _from_reference_viewpoint(search.camera, directions[along], far)
    fit = refine_line(grown, np.ones(len(grown)), line.normal, config.inlier_tolerance * panorama.pixel_size())
    tilt = tilt_sigma(grown[fit.inliers] if fit is not None else fitted[line.inliers],
                      fit.normal if fit is not None else line.normal)
    ratio = min(_support(line, corrected, rows[inside], panorama, config) / length, 1.0)
    # Only an edge short of min_ratio is counted again with its blinded points: one that reaches it cannot be why
    # its pair falls short, and the count costs a Hough line over the points
    shown = ratio if ratio >= config.min_ratio else max(
        _shown_with_clipped(search, segment, corrected, rows[inside], blind, lon, length), ratio)
    beside = highlights[inside][strong[inside]][line.inliers]
    return _Edge(fit if fit is not None else line, rival, tilt, ratio, float(np.median(beside)),
                 float(np.mean(beside >= CLIPPED)), shown, pinned)


def _shown_with_clipped(
    search: _Search, segment: Array, corrected: Array, rows: Array, blind: NDArray[np.bool_],
    lon: tuple[float, float], length: float,
) -> float:
    """The support ratio an edge would have with its ``blind`` points (beside light clipped in every channel; a mask
    of the search's points) taken as its own: of the line through them and the edge's other points (``corrected``,
    with their ``rows``) over the edge's ``length`` in panorama rows. 0 where no point is blinded."""
    if not blind.any():
        return 0.0
    panorama, config = search.panorama, search.config
    both = np.concatenate([corrected, _from_reference_viewpoint(search.camera, search.points.directions[blind],
                                                                segment)])
    line = _line(panorama, both, np.ones(len(both)), lon, config)
    if line is None:
        return 0.0
    return min(_support(line, both, np.concatenate([rows, search.points.rows[blind]]), panorama, config) / length,
               1.0)


def _pair_evidence(
    search: _Search, segments: list[Array], reach: list[Array], regions: list[Array], reaches: list[Array]
) -> PitchEvidence:
    """The edges of one pair of ``segments`` (camera frame) among the search's edge points, followed along
    ``reach`` for their fits; ``regions`` and ``reaches`` are their predicted regions."""
    config, predicted = search.config, search.predicted
    edges = [_edge(search, *edge) for edge in zip(segments, reach, regions, reaches, strict=True)]
    lines = [e.line for e in edges if e.line is not None]
    ratio = float(min(e.ratio for e in edges))
    nan = np.full(3, np.nan)
    found = functools.partial(PitchEvidence, search.hypothesis, ratio, panorama=search.panorama, regions=regions,
                              lines=lines, face_points=search.face_points,
                              highlights=tuple(e.highlight for e in edges), clipped=tuple(e.clipped for e in edges),
                              shown=float(min(e.shown for e in edges)))
    if len(lines) < 2 or ratio < config.min_ratio:
        return found(False, math.nan, nan)
    pitches = []
    for left in (edges[0].line, edges[0].rival):
        for right in (edges[1].line, edges[1].rival):
            if left is not None and right is not None:
                try:
                    direction = common_direction(left.normal, right.normal, predicted)
                except ValueError:
                    return found(False, math.nan, nan)
                if pitches and _across(direction, search) > config.max_across:
                    # Not both the pallet's edges (as the pair itself is refused so below): a line beside an edge
                    # that pairs so is not parallel to the pallet's axis, and its pitch is no rival's.
                    continue
                pitches.append(_pitch_from_direction(search.camera_in_fork.apply_direction(direction),
                                                     search.pallet_in_fork, search.axis_index))
    direction = common_direction(lines[0].normal, lines[1].normal, predicted)
    across = math.degrees(_across(direction, search))
    if across > math.degrees(config.max_across):
        return found(False, math.nan, nan, note=f"the {search.hypothesis} edges run {across:.1f} deg across the "
                     f"pallet's axis (at most {math.degrees(config.max_across):.1f}): they are not the pallet's")
    pitch, spread = pitches[0], max(abs(p - pitches[0]) for p in pitches)
    tilts = math.hypot(*_pitch_spread_of_tilts(lines, [e.tilt for e in edges], predicted, search.camera_in_fork,
                                               search.pallet_in_fork, search.axis_index))
    if spread > config.rival_pitch:
        return found(False, math.nan, direction, sigma=tilts, ambiguous=True, candidates=tuple(pitches))
    placed = all(e.rival is None or e.pinned for e in edges)
    return found(True, pitch, direction, sigma=math.hypot(tilts, spread / 2), placed=placed,
                 candidates=tuple(pitches))


def _across(direction: Array, search: _Search) -> float:
    """How far (rad) ``direction`` (camera frame) runs across the pallet's axis, towards its Y axis."""
    return math.asin(min(abs(float(direction @ search.pallet_in_camera.rotation[:, 1])), 1.0))


def tilt_sigma(points: Array, normal: Array, blocks: int = 8) -> tuple[Array, float]:
    """The centre of a fitted great circle's points and the standard error of its tilt about that centre.

    Edge points of a low-contrast or textured edge wander off the line together over tens of rows
    (plank gaps, grain and the background's tone pull the gradient maximum), so they are not
    independent: the tilt is fitted to the mean residual of ``blocks`` runs of the points along the
    circle, and its standard error comes from the scatter of those means. A deck edge whose points
    lay on the line over its middle and 1-2 px off it near one end gave +-0.003 deg of pitch from the
    points' own scatter, 0.11 deg from the runs, where the pitch was 0.34 deg off (random look 3 of
    paper scene unloaded-high-front-up).

    Parameters
    ----------
    points : (N, 3) array
        Unit directions of the points the circle was fitted to.
    normal : (3,) array
        The circle's unit normal.
    blocks : int
        How many runs of points the tilt is fitted to (at least 3).

    Returns
    -------
    centre : (3,) array
        Unit direction of the points' mean.
    sigma : float
        Standard error (rad) of the circle's rotation about ``centre``; infinite for fewer than two points a run.
    """
    if blocks < 3:
        raise ValueError(f"a tilt is fitted to at least 3 runs of points, got blocks={blocks}")
    centre = points.mean(axis=0)
    centre = centre / np.linalg.norm(centre)
    if len(points) < 2 * blocks:
        return centre, math.inf
    along = points @ np.cross(normal, centre)
    runs = np.array_split(np.argsort(along), blocks)
    t = np.array([float(np.mean(along[run])) for run in runs])
    r = np.array([float(np.mean(points[run] @ normal)) for run in runs])
    slope, offset = np.polyfit(t, r, 1)
    spread = float(np.sum((t - t.mean()) ** 2))
    sigma = math.sqrt(float(np.sum((r - slope * t - offset) ** 2)) / (blocks - 2) / max(spread, 1e-18))
    return centre, sigma


def _pitch_spread_of_tilts(
    lines: list[SphereLine], tilts: list[tuple[Array, float]], predicted: Array, camera_in_fork: Transform,
    pallet_in_fork: Transform, axis_index: int,
) -> list[float]:
    """How far the pitch moves (rad) when each line is turned by its tilt's standard error about its centre."""
    def pitch_of(normals: list[Array]) -> float:
        direction = common_direction(normals[0], normals[1], predicted)
        return _pitch_from_direction(camera_in_fork.apply_direction(direction), pallet_in_fork, axis_index)

    normals = [line.normal for line in lines]
    base = pitch_of(normals)
    moved = []
    for i, (centre, sigma) in enumerate(tilts):
        if not math.isfinite(sigma):
            moved.append(math.inf)
            continue
        turned = list(normals)
        turned[i] = normals[i] * math.cos(sigma) + np.cross(centre, normals[i]) * math.sin(sigma)
        moved.append(abs(pitch_of(turned) - base))
    return moved


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


def _line_through(
    anchor: Array, panorama: Panorama, directions: Array, weights: Array, line: SphereLine,
    lon: tuple[float, float], config: PitchConfig,
) -> SphereLine | None:
    """Where the strongest ``line`` misses the point the pose pins (``anchor``) by more than
    ``anchor_tolerance``: a line among the other edge points that passes through it, at least ``pinned_strength``
    as strong, else None.

    A deck seen from above shows lines parallel to its edges inside them (a board's joint, the lit and shaded
    sides of a chamfer): campaign seed 7, picks 28 and 120, verifying: one deck edge's strongest line ran 40 px
    (70 mm) inside the edge, the edge itself scored 0.87-1.0 of it and passed 0.3 px from the corner the face's
    pose put within 2 mm; the pair placed the pallet 65 mm high and was refused. At half as strong, a line through
    the corner 22 px from a stronger one (0.6 of it) agreed with it on a pitch 1.6 deg off: both were shadows'
    edges (picks 751 and 691 of that campaign were accepted 1.55 and 0.62 deg off).
    """
    if _anchor_miss(anchor, line, panorama) <= config.anchor_tolerance:
        return None
    rest = ~line.inliers
    for _ in range(config.anchor_lines):
        other = _line(panorama, directions[rest], weights[rest], lon, config)
        if other is None or other.score < config.pinned_strength * line.score:
            return None
        if _anchor_miss(anchor, other, panorama) <= config.anchor_tolerance:
            return _refit(other, directions, weights, panorama, config)
        rest &= np.abs(directions @ other.normal) >= config.inlier_tolerance * panorama.pixel_size()
    return None


def _refit(line: SphereLine, directions: Array, weights: Array, panorama: Panorama, config: PitchConfig) -> SphereLine:
    """``line``, found among some of the edge points, fitted to all of them (its inliers among all)."""
    fit = refine_line(directions, weights, line.normal, config.inlier_tolerance * panorama.pixel_size())
    return fit if fit is not None else line


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
    miss_line, miss_rival = _anchor_miss(anchor, line, panorama), _anchor_miss(anchor, rival, panorama)
    return miss_line <= config.anchor_tolerance and miss_rival - miss_line >= config.anchor_gap


def _anchor_miss(anchor: Array, line: SphereLine, panorama: Panorama) -> float:
    """How far (panorama pixels) ``line`` passes from the unit direction ``anchor``."""
    return abs(float(anchor @ line.normal)) / panorama.pixel_size()


def _pitch_from_direction(direction_f: Array, pallet_in_fork: Transform, axis_index: int) -> float:
    """The pitch (rad) at which pallet axis ``axis_index`` (0: X, 2: Z) points along ``direction_f`` (fork frame)."""
    yaw = pallet_in_fork.euler[0]
    forward = direction_f[0] * math.cos(yaw) + direction_f[1] * math.sin(yaw)
    if axis_index == 0:  # the direction is pallet X: positive pitch tips it down
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


def _edge_points(
    image: NDArray[np.float32], valid: NDArray[np.bool_], panorama: Panorama, areas: list[Array],
    colour: NDArray[np.uint8] | None = None,
):
    """Sub-pixel maxima of the horizontal gradient along each row above half an adaptive threshold, and
    which of them reach the threshold itself (the strong ones that lines are fitted to). The gradient of a colour
    ``image`` (H, W, 3) is its channels' root sum of squares over the square root of 3 (a grey edge's own).

    Directions (camera frame) are computed only for maxima in one of the ``areas`` (regions as
    :func:`_region` gives them), NaN elsewhere: the rest of the panorama only sets the threshold. With the
    ``colour`` panorama, maxima beside clipped light are found again in it (:func:`unclipped_edge_columns`), and
    those no channel finds are returned ``blinded``, never strong.
    """
    gx = _row_gradient(image)
    if gx.ndim == 3:
        gx = np.sqrt(np.einsum("ijk,ijk->ij", gx, gx) / 3.0)
    gx[~cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)] = 0.0
    # The statistics of the gradient, from every 4th row and column: the full sort cost 15 ms a panorama.
    sample, sampled_valid = gx[::4, ::4], valid[::4, ::4]
    inside = sample[sampled_valid]
    noise = float(mad_sigma(inside)) if inside.size else 0.0
    threshold = max(6.0 * noise, 0.2 * float(np.percentile(sample, 99)), 1e-3)
    centre = gx[:, 1:-1]
    peak = (centre > gx[:, :-2]) & (centre >= gx[:, 2:]) & (centre > 0.5 * threshold)  # not in the outer columns
    rows, cols = np.nonzero(peak)
    cols += 1
    c = gx[rows, cols]
    columns, rows = cols + _peak_offset(gx[rows, cols - 1], c, gx[rows, cols + 1]), rows.astype(float)
    needed = np.any([_inside(area, columns, rows) for area in areas], axis=0)
    blinded = np.zeros(len(rows), dtype=bool)
    if colour is not None:
        found = unclipped_edge_columns(colour, columns[needed], rows[needed], threshold)
        blinded[needed] = np.isnan(found)  # kept at the grey's column, which is all that shows where they are
        columns[needed] = np.where(blinded[needed], columns[needed], found)
    directions = np.full((len(rows), 3), np.nan)
    directions[needed] = panorama.directions_from_pixels(np.stack([columns[needed], rows[needed]], axis=1))
    # The highlight is the brightest channel's: one clipped channel moves the grey's gradient maxima outwards as a
    # clipped grey does (a red deck at R 255, grey 170-200, its edges' maxima 0.5-0.8 px outside the outline), and
    # behind a JPEG no channel finds the edge again (unclipped_edge_columns): its fine detail is the luma's
    highlights = edge_highlights(image if colour is None else colour, columns, rows, needed)
    return directions, (c > threshold) & ~blinded, columns, rows, highlights, blinded


HIGHLIGHT_REACH = 4  # panorama pixels either side of an edge point along its row


def edge_highlights(image: NDArray, columns: Array, rows: Array, needed: NDArray[np.bool_]) -> Array:
    """The brightest level of ``image`` (grey (H, W), or colour (H, W, 3): its brightest channel) within
    :data:`HIGHLIGHT_REACH` pixels of each ``needed`` edge point along its row (N,), NaN for the others. Only the
    points' windows are read: the channels' maximum over a whole panorama cost a pass a call."""
    out = np.full(len(rows), np.nan)
    window = _row_windows(columns[needed], HIGHLIGHT_REACH, image.shape[1])
    levels = image[rows[needed].astype(int)[:, None], window]  # (n, W) or (n, W, 3)
    out[needed] = levels.max(axis=tuple(range(1, levels.ndim)))
    return out


def _row_windows(columns: Array, reach: int, width: int) -> NDArray[np.int_]:
    """The columns (N, 2 reach + 1) within ``reach`` of each of ``columns`` (rounded), clipped to a row ``width``
    wide."""
    return np.clip(np.round(columns).astype(int)[:, None] + np.arange(-reach, reach + 1), 0, width - 1)


CLIPPED = 250  # a colour channel this bright may be clipped


def unclipped_edge_columns(
    colour: NDArray[np.uint8], columns: Array, rows: Array, threshold: float, reach: int = 3
) -> Array:
    """Edge columns (N,) found again, where a colour channel clips within ``reach`` px of them along the row,
    in the channel that does not clip there and has the strongest gradient; NaN where every channel clips or
    the unclipped ones show no edge (their gradient under half ``threshold``).

    Blur spreads an overexposed surface's light past its outline before the sensor clips it, so the
    gradient maximum of a clipped channel (and of the grey made from it) lies outside the outline."""
    r = rows.astype(int)
    window = _row_windows(columns, reach, colour.shape[1])  # (N, W)
    clipped = colour[r[:, None], window].max(axis=1) >= CLIPPED  # (N, 3)
    near = np.flatnonzero(clipped.any(axis=1))
    if near.size == 0:
        return columns
    # The gradient over the rows and columns these points need only (4 px: the blur's and the Sobel kernel's
    # reach): over the whole panorama it cost 5 ms a call
    top, bottom = max(int(r[near].min()) - 4, 0), int(r[near].max()) + 5
    first, last = max(int(window[near].min()) - 4, 0), int(window[near].max()) + 5
    g = _row_gradient(colour[top:bottom, first:last].astype(np.float32))[r[near, None] - top, window[near] - first]
    peak = np.where(clipped[near], -1.0, g.max(axis=1))  # (n, 3)
    channel = np.argmax(peak, axis=1)
    profile = g[np.arange(near.size), :, channel]  # (n, W)
    k = np.clip(np.argmax(profile, axis=1), 1, 2 * reach - 1)
    i = np.arange(near.size)
    left, mid, right = profile[i, k - 1], profile[i, k], profile[i, k + 1]
    found = window[near, 0] + k + _peak_offset(left, mid, right)
    usable = (peak[i, channel] >= 0.5 * threshold) & (mid >= np.maximum(left, right))
    out = columns.copy()
    out[near] = np.where(usable, found, np.nan)
    return out


def _row_gradient(image: NDArray[np.float32]) -> NDArray[np.float32]:
    """The horizontal gradient's magnitude along the rows of a panorama (grey or colour), lightly smoothed."""
    return np.abs(cv2.Sobel(cv2.GaussianBlur(image, (0, 0), 0.8), cv2.CV_32F, 1, 0, ksize=3))


def _peak_offset(left: Array, centre: Array, right: Array) -> Array:
    """Sub-pixel offset of a maximum from its sample, by the parabola through it and its two neighbours."""
    curvature = left - 2 * centre + right
    return 0.5 * (left - right) / np.where(curvature < 0, curvature, -1.0)


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
