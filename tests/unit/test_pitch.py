"""The deck-edge pose: an unloaded pallet's y, z, yaw and pitch from the great circles of its deck edges."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agf.config import load_config
from agf.geometry import Transform
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.vision.hough import SphereLine, fit_plane_normal
from agf.vision.pitch import (
    HIGHLIGHT_REACH,
    FaceDirection,
    PitchConfig,
    PitchEvidence,
    _edge_points,
    _line,
    _line_through,
    _panorama_over,
    _without_vague_face,
    deck_corner_misses,
    direction_of_parallel_lines,
    edge_highlights,
    pose_from_deck_edges,
    tilt_sigma,
    unclipped_edge_columns,
    yaw_from_circle,
)

PALLET = load_pallets(load_config(DEFAULT_CONFIG).vision.pallets)["jis-t11"]
CAMERA_IN_FORK = Transform.from_euler(-0.705, 0.0, 1.055)


def deck_edge_evidence(pallet_in_fork: Transform, hypothesis: str = "unloaded", valid: bool = True) -> PitchEvidence:
    """The two deck edges as they project exactly, from the camera centre."""
    in_camera = CAMERA_IN_FORK.inverse() @ pallet_in_fork
    forward = in_camera.rotation[:, 0]
    lines = []
    for side in (-1, 1):
        corner = in_camera.apply(np.array([[0.0, side * PALLET.width / 2, PALLET.deck_top]]))[0]
        normal = np.cross(corner, forward)
        lines.append(SphereLine(normal / np.linalg.norm(normal), 1.0, np.ones(1, bool)))
    return PitchEvidence(hypothesis, 1.0, valid, 0.0, forward, None, [], lines, 0.0)


@pytest.mark.parametrize("seed", range(5))
def test_deck_edges_recover_y_z_yaw_and_pitch_but_keep_x(seed):
    rng = np.random.default_rng(seed)
    truth = Transform.from_euler(rng.uniform(0.15, 0.4), rng.uniform(-0.03, 0.03), rng.uniform(-0.3, 0.45), 0.0,
                                 np.radians(rng.uniform(-5, 5)), np.radians(rng.uniform(-3, 3)))
    x, y, z = truth.translation
    yaw, pitch, _ = truth.euler
    start = Transform.from_euler(x + 0.01, y - 0.02, z + 0.03, 0.0, pitch + 0.01, yaw - 0.01)
    found = pose_from_deck_edges(deck_edge_evidence(truth), PALLET, CAMERA_IN_FORK, start)
    np.testing.assert_allclose(found.euler, truth.euler, atol=1e-9)
    # x is only what the start had: the deck edges run along it.
    along = found.translation - truth.translation
    np.testing.assert_allclose(along - (along @ truth.rotation[:, 0]) * truth.rotation[:, 0], 0, atol=1e-9)


def load_edges(pitch_deg: float, sigma_deg: float = 0.03) -> PitchEvidence:
    """A valid pair of load edges at ``pitch_deg`` (its only candidate), to ``sigma_deg``."""
    pitch = math.radians(pitch_deg)
    return PitchEvidence("loaded", 0.9, True, pitch, np.array([0.0, 0.0, 1.0]), None, [], [], math.radians(sigma_deg),
                         candidates=(pitch,))


def face_lines(pitch_deg: float, sigma_deg: float) -> FaceDirection:
    return FaceDirection(np.array([0.0, 0.0, 1.0]), math.radians(pitch_deg), math.radians(sigma_deg), 8)


def test_a_vague_face_that_agrees_with_the_load_edges_is_dropped_and_its_miss_widens_their_sigma():
    config = PitchConfig()
    pair, face = _without_vague_face(load_edges(1.0), face_lines(1.08, 0.1), config)
    assert face is None
    assert pair.valid and pair.pitch == pytest.approx(math.radians(1.0))
    assert math.degrees(pair.sigma) == pytest.approx(math.hypot(0.03, 0.04))


def test_a_sure_face_or_a_face_that_disagrees_is_kept_for_the_load_edges_to_answer():
    config = PitchConfig()
    edges = load_edges(1.0)
    sure = face_lines(1.08, 0.05)
    far = face_lines(1.0 + math.degrees(config.face_agreement) + 0.01, 0.1)
    for face in (sure, far, None):
        kept, answered = _without_vague_face(edges, face, config)
        assert kept is edges and answered is face


def test_deck_edges_need_a_valid_unloaded_hypothesis():
    truth = Transform.from_euler(0.3, 0.0, 0.1)
    with pytest.raises(ValueError, match="valid unloaded"):
        pose_from_deck_edges(deck_edge_evidence(truth, "loaded"), PALLET, CAMERA_IN_FORK, truth)
    with pytest.raises(ValueError, match="valid unloaded"):
        pose_from_deck_edges(deck_edge_evidence(truth, valid=False), PALLET, CAMERA_IN_FORK, truth)


def test_a_line_from_a_far_deck_corner_past_the_near_one_misses_it_on_its_side_only():
    """Campaign seed 7, pick 386: a shadow's edge ran from the deck's far right corner to 30 mm inside its near one."""
    from types import SimpleNamespace

    truth = Transform.from_euler(0.24, 0.03, 0.144, 0.0, math.radians(2.28), math.radians(-2.37))
    pixel = math.radians(0.08)
    exact = deck_edge_evidence(truth)
    exact = dataclasses.replace(exact, panorama=SimpleNamespace(pixel_size=lambda: pixel))
    np.testing.assert_allclose(deck_corner_misses(exact, PALLET, CAMERA_IN_FORK, truth), 0.0, atol=1e-9)
    in_camera = CAMERA_IN_FORK.inverse() @ truth
    far, inside = in_camera.apply(np.array([[PALLET.length, PALLET.width / 2, PALLET.deck_top],
                                            [0.0, PALLET.width / 2 - 0.03, PALLET.deck_top]]))
    normal = np.cross(far, inside)
    shadow = SphereLine(normal / np.linalg.norm(normal), 1.0, np.ones(1, bool))
    misses = deck_corner_misses(dataclasses.replace(exact, lines=[exact.lines[0], shadow]), PALLET, CAMERA_IN_FORK,
                                truth)
    corner = in_camera.apply(np.array([[0.0, PALLET.width / 2, PALLET.deck_top]]))[0]
    # 30 mm across the line of sight at the corner's distance, nearly all of it across the line
    assert misses[0] == pytest.approx(0.0, abs=1e-9)
    assert 0.7 * 0.03 / np.linalg.norm(corner) / pixel < misses[1] < 0.03 / np.linalg.norm(corner) / pixel
    with pytest.raises(ValueError, match="valid unloaded"):
        deck_corner_misses(dataclasses.replace(exact, valid=False), PALLET, CAMERA_IN_FORK, truth)


def pitched_axes(pitches: np.ndarray) -> np.ndarray:
    """Pallet Z pitched by each of ``pitches`` (rad): the candidates a scan of pitch tries, (K, 3)."""
    return np.array([Transform.from_euler(pitch=p).rotation[:, 2] for p in pitches])


def face_line_points(pitch: float, ys: np.ndarray, rng: np.random.Generator, noise: float) -> np.ndarray:
    """Unit directions of points on vertical lines of a face 1.5 m ahead, pitched by ``pitch`` (rad), at
    lateral offsets ``ys`` (m), 0.5 m long, 80 points each, with ``noise`` (rad) across each line."""
    axis = pitched_axes(np.array([pitch]))[0]
    points = []
    for y in ys:
        foot = np.array([1.5, y, -0.3])
        along = foot + np.linspace(0.0, 0.5, 80)[:, None] * axis
        points.append(along / np.linalg.norm(along, axis=1, keepdims=True))
    points = np.concatenate(points)
    side = np.cross(points, axis)
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    points = points + rng.normal(0.0, noise, (len(points), 1)) * side
    return points / np.linalg.norm(points, axis=1, keepdims=True)


PIXEL = np.radians(0.08)
SCAN = np.radians(np.arange(-1.5, 1.501, 0.02))


@pytest.mark.parametrize("seed", range(4))
def test_parallel_lines_give_their_pitch_beside_lines_of_another(seed):
    """Lines of a load's face (carton joints, tape) pitched like the pallet, and two rack uprights at
    pitch 0 among them: the uprights disagree with the rest and are dropped."""
    rng = np.random.default_rng(seed)
    pitch = np.radians(rng.uniform(-1.0, 1.0))
    face = face_line_points(pitch, np.linspace(-0.35, 0.35, 8) + rng.uniform(-0.02, 0.02, 8), rng, 0.1 * PIXEL)
    uprights = face_line_points(0.0, np.array([-0.45, 0.42]), rng, 0.1 * PIXEL)
    found = direction_of_parallel_lines(np.concatenate([face, uprights]), pitched_axes(SCAN), PIXEL)
    assert found is not None
    direction, sigma, lines = found
    measured = np.arctan2(direction[0], direction[2])
    assert abs(np.degrees(measured - pitch)) < 0.02 and lines >= 8
    assert abs(measured - pitch) < 3.0 * sigma < np.radians(0.1)  # an honest uncertainty, well inside the bound


def test_parallel_lines_are_no_direction_when_two_lines_remain():
    rng = np.random.default_rng(7)
    points = face_line_points(np.radians(0.4), np.array([-0.3, 0.3]), rng, 0.1 * PIXEL)
    assert direction_of_parallel_lines(points, pitched_axes(SCAN), PIXEL) is None


def test_parallel_lines_are_no_direction_beyond_the_scan():
    rng = np.random.default_rng(8)
    points = face_line_points(np.radians(2.5), np.linspace(-0.3, 0.3, 6), rng, 0.1 * PIXEL)
    assert direction_of_parallel_lines(points, pitched_axes(SCAN), PIXEL) is None


def _points_on_circle(rng: np.random.Generator, offsets_px: np.ndarray, pixel: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions along 20 deg of the great circle with normal +z (the equator), each moved off it by
    ``offsets_px`` panorama pixels of ``pixel`` rad; and that normal."""
    lon = np.radians(np.linspace(-10.0, 10.0, len(offsets_px)))
    lat = offsets_px * pixel
    points = np.c_[np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]
    return points, np.array([0.0, 0.0, 1.0])


@pytest.mark.parametrize("seed", range(3))
def test_tilt_sigma_matches_the_scatter_of_tilts_fitted_to_independent_noise(seed):
    """White noise: the runs' standard error is the slope's, as the tilts of many noisy copies scatter."""
    rng = np.random.default_rng(seed)
    pixel = np.radians(0.08)
    tilts, sigmas = [], []
    for _ in range(300):
        points, normal = _points_on_circle(rng, rng.normal(0.0, 0.5, 240), pixel)
        fitted = fit_plane_normal(points, np.ones(len(points)), normal)
        centre, sigma = tilt_sigma(points, fitted)
        tilts.append(float(fitted @ np.array([0.0, 1.0, 0.0])))  # rotation about the circle's centre (+x)
        sigmas.append(sigma)
    assert np.median(sigmas) == pytest.approx(np.std(tilts), rel=0.3)


def test_tilt_sigma_sees_points_that_wander_off_the_line_together():
    """Regression (random look 3 of paper scene unloaded-high-front-up, a deck edge 0.34 deg off in pitch):
    points on the line over the middle and 1-2 px off near one end. The points' own scatter would say the
    tilt is known to a few thousandths of a degree; the runs say it is not."""
    rows = np.arange(240)
    wander = np.where(rows < 60, 1.5 * (60 - rows) / 60, 0.0) + 0.3 * np.sin(rows / 9.0)
    points, normal = _points_on_circle(np.random.default_rng(0), wander, np.radians(0.08))
    fitted = fit_plane_normal(points, np.ones(len(points)), normal)
    residual = points @ fitted
    along = points @ np.cross(fitted, points.mean(axis=0) / np.linalg.norm(points.mean(axis=0)))
    white = np.std(residual) / np.sqrt(np.sum((along - along.mean()) ** 2))
    _, sigma = tilt_sigma(points, fitted)
    assert sigma > 3 * white


def test_tilt_sigma_is_infinite_for_too_few_points_and_refuses_too_few_runs():
    points, normal = _points_on_circle(np.random.default_rng(1), np.zeros(10), np.radians(0.08))
    assert tilt_sigma(points, normal)[1] == np.inf
    with pytest.raises(ValueError, match="at least 3 runs"):
        tilt_sigma(points, normal, blocks=2)


def _overexposed_step(edge: float, gains: tuple[float, float, float], blur: float = 1.5) -> np.ndarray:
    """Rows (8, 64, 3) uint8 of a lit surface left of column ``edge`` against a dark one: blurred in linear light,
    then each channel scaled by its gain and clipped at 255, as a sensor does."""
    from math import erf, sqrt

    cols = np.arange(64, dtype=float)
    lit = np.array([0.5 * (1.0 - erf((c - edge) / (blur * sqrt(2.0)))) for c in cols])
    row = 40.0 + lit[:, None] * np.array(gains)[None, :]
    return np.repeat(np.clip(np.round(row), 0, 255).astype(np.uint8)[None], 8, axis=0)


def _grey_edge_column(colour: np.ndarray) -> float:
    """Where the grey frame's horizontal gradient peaks on row 4 (sub-pixel, as the pitch search finds it)."""
    import cv2

    grey = cv2.GaussianBlur(cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY).astype(np.float32), (0, 0), 0.8)
    g = np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3))[4]
    k = int(np.argmax(g[1:-1])) + 1
    return k + 0.5 * (g[k - 1] - g[k + 1]) / (g[k - 1] - 2 * g[k] + g[k + 1])


def test_regression_an_overexposed_deck_edge_is_found_where_a_channel_is_not_clipped():
    """Campaign seed 7 pick 42: blur spread the overexposed deck's light outward before the sensor clipped it,
    so its edges read 0.5-1.2 px outward in grey and the pitch was accepted 0.18 deg off."""
    colour = _overexposed_step(30.3, (150.0, 900.0, 1400.0))  # B in range, G and R clipped
    grey = _grey_edge_column(colour)
    assert grey - 30.3 > 0.5  # the bias this guards against
    [column] = unclipped_edge_columns(colour, np.array([grey]), np.array([4.0]), threshold=10.0)
    assert abs(column - 30.3) < 0.15


def test_edges_beside_clipping_in_every_channel_are_dropped_and_those_away_from_it_kept():
    clipped = _overexposed_step(30.3, (900.0, 900.0, 900.0))
    assert np.isnan(unclipped_edge_columns(clipped, np.array([31.0]), np.array([4.0]), threshold=10.0)).all()
    unclipped = _overexposed_step(30.3, (150.0, 180.0, 200.0))
    columns = np.array([_grey_edge_column(unclipped), 12.0])
    assert np.array_equal(unclipped_edge_columns(unclipped, columns, np.array([4.0, 4.0]), threshold=10.0), columns)


def test_edge_points_beside_light_clipped_in_every_channel_are_blinded_not_dropped_and_never_strong():
    """Campaign seed 7 pick 42 (session 41): the deck's edge points beside light clipped in every channel were
    dropped, so the edges showed over 22 % of their length and the refusal asked for no shorter exposure. They are
    kept, ``blinded``: never strong (no line is fitted to them), counted only for what a shorter exposure shows."""
    from agf.vision.panorama import Panorama

    panorama = Panorama.around(np.array([0.0, 0.0, 1.0]), 64, 8)
    valid = np.ones((8, 64), bool)
    area = [np.array([2.0, 61.0, 0.0, 7.0])]
    for gains, blinded in (((900.0, 900.0, 900.0), True), ((150.0, 900.0, 1400.0), False)):
        colour = _overexposed_step(30.3, gains)
        grey = colour.mean(axis=2).astype(np.float32)
        directions, strong, columns, rows, highlights, found_blinded = _edge_points(grey, valid, panorama, area,
                                                                                    colour)
        at_edge = np.abs(columns - 30.3) < 2.0
        assert at_edge.any() and np.all(found_blinded[at_edge] == blinded), (gains, columns[at_edge])
        assert not np.any(strong & found_blinded)
        assert np.all(np.isfinite(directions[at_edge]))  # placed where the grey shows them, for the count


def test_an_edge_of_two_hues_and_one_grey_is_found_in_the_colour_gradient_only():
    """PitchConfig.colour_edges (campaign seed 7, pick 35: a terracotta deck on a grey bed, 3 grey levels apart): an
    edge between two colours of one grey is no edge point in grey and a strong one in the colour gradient, at its
    column; a grey edge elsewhere sets the threshold in both."""
    from agf.vision.grey import grey_from_bgr
    from agf.vision.panorama import Panorama

    rng = np.random.default_rng(3)
    cols = np.arange(64, dtype=float)
    hue = 0.5 * (1.0 + np.tanh((cols - 20.3) / 1.2))  # terracotta (B, G, R) to grey left of a dark stripe
    row = (1 - hue)[:, None] * np.array([60.0, 92.0, 172.0]) + hue[:, None] * np.array([112.0, 112.0, 112.0])
    row[44:] *= 0.3
    colour = np.clip(np.repeat(row[None], 8, axis=0) + rng.normal(0, 1.0, (8, 64, 3)), 0, 255).astype(np.uint8)
    grey = grey_from_bgr(colour).astype(np.float32)
    assert abs(float(grey[:, :16].mean() - grey[:, 24:40].mean())) < 3.0  # one grey either side of the hue edge
    panorama = Panorama.around(np.array([0.0, 0.0, 1.0]), 64, 8)
    valid, area = np.ones((8, 64), bool), [np.array([2.0, 61.0, 0.0, 7.0])]
    for image, found in ((grey, False), (colour.astype(np.float32), True)):
        _, strong, columns, _, _, _ = _edge_points(image, valid, panorama, area, colour)
        at_edge = strong & (np.abs(columns - 20.3) < 1.0)
        assert at_edge.sum() == (8 if found else 0), (image.ndim, columns[strong])
        assert strong[np.abs(columns - 43.5) < 1.5].sum() >= 6  # the grey edge, in both
    assert np.abs(columns[at_edge] - 20.3).max() < 0.3


def test_the_top_deck_clipped_in_every_channel_is_counted_only_where_the_camera_looks_down_on_it():
    """PitchConfig.max_deck_top_clipped (campaign seed 7, pick 214): a deck and a floor both clipped show no edge."""
    from agf.camera import load_camera
    from agf.paths import repo_path
    from agf.vision.pitch import deck_top_clipped

    camera = load_camera(repo_path("configs/cameras/thetav_front.txt"))
    below = Transform.from_euler(0.4, 0.0, -0.3)  # the deck 0.3 m below the forks, the camera above it
    image = np.full((camera.height, camera.width, 3), 255, np.uint8)
    assert deck_top_clipped(image, camera, CAMERA_IN_FORK, PALLET, below) == 1.0
    image[..., 0] = 200  # blue not clipped: some channel still shows the deck
    assert deck_top_clipped(image, camera, CAMERA_IN_FORK, PALLET, below) == 0.0
    half = np.full((camera.height, camera.width), 255, np.uint8)
    pallet_in_camera = CAMERA_IN_FORK.inverse() @ below
    pixels, _ = camera.project(pallet_in_camera.apply([[PALLET.length / 2, 0.0, PALLET.deck_top]]))
    half[int(pixels[0, 1]):] = 100  # the deck's near half (lower in the image) is not clipped
    assert 0.3 < deck_top_clipped(half, camera, CAMERA_IN_FORK, PALLET, below) < 0.7
    level = Transform.from_euler(0.4, 0.0, CAMERA_IN_FORK.translation[2] - PALLET.deck_top + 0.05)
    assert deck_top_clipped(np.full_like(image, 255), camera, CAMERA_IN_FORK, PALLET, level) == 0.0


def test_an_edge_point_reads_the_brightest_grey_within_reach_along_its_row_only():
    """PitchConfig.max_deck_highlight refuses deck edges beside grey this close to 255 (campaign seed 7 pick 38)."""
    image = np.full((3, 40), 100.0, np.float32)
    image[1, 20:] = 250.0  # a deck nearly clipped right of column 20, on the middle row only
    columns = np.array([19.6, 19.6, 20.0 - HIGHLIGHT_REACH - 1.0, 20.0 - HIGHLIGHT_REACH, 30.0])
    rows = np.array([1.0, 0.0, 1.0, 1.0, 1.0])
    needed = np.array([True, True, True, True, False])
    highlights = edge_highlights(image, columns, rows, needed)
    np.testing.assert_array_equal(highlights[:4], [250.0, 100.0, 100.0, 250.0])
    assert np.isnan(highlights[4])


def test_an_edge_point_in_colour_reads_the_brightest_channel_within_reach():
    """Campaign seed 7 picks 660-930: a deck clipped in red only (grey 170-200) moved its edges as a clipped grey
    does; in a colour frame the highlight is the brightest channel's, so the deck counts as overexposed."""
    image = np.full((3, 40, 3), 100, np.uint8)
    image[1, 20:] = (90, 150, 252)  # B, G, R: red nearly clipped right of column 20, middle row only
    columns = np.array([19.6, 19.6, 20.0 - HIGHLIGHT_REACH - 1.0])
    rows = np.array([1.0, 0.0, 1.0])
    highlights = edge_highlights(image, columns, rows, np.ones(3, bool))
    np.testing.assert_array_equal(highlights, [252.0, 100.0, 100.0])
    np.testing.assert_array_equal(edge_highlights(image, columns, rows, np.zeros(3, bool)), [np.nan] * 3)


def test_no_load_top_is_searched_where_the_camera_is_not_above_the_lowest_one():
    """A camera 0.3 m over the deck cannot look down on a load top at least PitchConfig.top_lowest above it."""
    from agf.camera import load_camera
    from agf.paths import repo_path
    from agf.vision.pitch import PitchConfig, load_top_evidence

    camera = load_camera(repo_path("configs/cameras/thetav_front.txt"))
    image = np.zeros((camera.height, camera.width), np.uint8)
    config = PitchConfig()
    # the pallet's height in the fork frame at which the lowest top searched lies top_above below the camera
    level = CAMERA_IN_FORK.translation[2] - PALLET.deck_top - config.top_lowest - config.top_above
    high = Transform.from_euler(0.3, 0.0, level + 0.01)
    assert load_top_evidence(image, camera, CAMERA_IN_FORK, PALLET, high, config) is None
    low = Transform.from_euler(0.3, 0.0, level - 0.2)
    assert load_top_evidence(image, camera, CAMERA_IN_FORK, PALLET, low, config) is not None


def deck_lines_seen(insides: list[float], rng: np.random.Generator):
    """Edge points (unit directions, camera frame) on the right deck edge of a level pallet 0.3 m ahead of the forks
    and on lines parallel to it ``insides`` (m) inside it, 0.2 mm of noise; the deck's front corner; the panorama
    the edges are searched in and its longitude range."""
    in_camera = CAMERA_IN_FORK.inverse() @ Transform.from_euler(0.3, 0.0, 0.0)
    x = np.linspace(0.03, PALLET.length - 0.03, 300)
    lines = [np.c_[x, np.full_like(x, PALLET.width / 2 - inside), np.full_like(x, PALLET.deck_top)]
             for inside in [0.0, *insides]]
    points = in_camera.apply(np.concatenate(lines) + rng.normal(0.0, 2e-4, (len(x) * len(lines), 3)))
    corner = in_camera.apply(lines[0][:1])[0]
    panorama = _panorama_over(in_camera.rotation[:, 0], [in_camera.apply(lines[0])], PitchConfig())
    ends = panorama.angles_from_pixels(np.array([[0.0, 0.0], [panorama.width - 1.0, 0.0]]))[0]
    points = points / np.linalg.norm(points, axis=1, keepdims=True)
    return points, corner / np.linalg.norm(corner), panorama, (float(ends[0]), float(ends[1]))


@pytest.mark.parametrize("seed", range(3))
def test_regression_a_deck_line_inside_the_edge_gives_way_to_the_edge_through_the_corner(seed):
    """Campaign seed 7, picks 28 and 120, verifying: the strongest line ran 70 mm inside a deck edge, and the edge,
    as strong, passed through the corner the face's pose pins; the edges' pose was 73 mm off and refused."""
    config = PitchConfig()
    points, corner, panorama, lon = deck_lines_seen([0.07], np.random.default_rng(seed))
    weights = np.r_[np.ones(300), np.full(300, 1.2)]
    strongest = _line(panorama, points, weights, lon, config)
    assert abs(corner @ strongest.normal) / panorama.pixel_size() > 20  # the inner line wins on strength
    through = _line_through(corner, panorama, points, weights, strongest, lon, config)
    assert abs(corner @ through.normal) / panorama.pixel_size() < 0.5
    assert through.inliers[:300].mean() > 0.9 and through.inliers[300:].mean() < 0.01
    # The edge through the corner is not searched for when the strongest line is already there ...
    edge_only, corner, panorama, lon = deck_lines_seen([], np.random.default_rng(seed))
    found = _line(panorama, edge_only, np.ones(len(edge_only)), lon, config)
    assert _line_through(corner, panorama, edge_only, np.ones(len(edge_only)), found, lon, config) is None
    # ... and nothing is taken where no line passes through the corner
    inner_only = points[300:]
    inner = _line(panorama, inner_only, np.ones(len(inner_only)), lon, config)
    assert _line_through(corner, panorama, inner_only, np.ones(len(inner_only)), inner, lon, config) is None


@pytest.mark.parametrize("seed", range(5))
def test_yaw_from_circle_recovers_the_yaw_of_a_line_along_pallet_y(seed):
    # the great circle of a line along pallet Y seen from the origin gives back the pose's yaw, whatever its pitch and
    # roll, from a pose whose own yaw is up to 1 deg off
    rng = np.random.default_rng(seed)
    yaw, pitch, roll = np.radians(rng.uniform(-5, 5, 3))
    pose = Transform.from_euler(*rng.uniform([0.2, -0.3, -0.4], [1.5, 0.3, 0.4]), roll, pitch, yaw)
    along = pose.rotation[:, 1]
    point = pose.apply(np.array([[0.0, rng.uniform(-0.5, 0.5), 0.07]]))[0]
    normal = np.cross(point, along)
    guess = Transform.from_euler(*pose.translation, roll, pitch, yaw + math.radians(rng.uniform(-1, 1)))
    assert yaw_from_circle(normal / np.linalg.norm(normal), guess) == pytest.approx(yaw, abs=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_compiled_line_sharpness_equals_numpy_counts_of_the_same_bins(seed):
    """The longitudes' bunching (compiled) is numpy's: each row's bins counted from its lowest, each bin summed with
    its neighbour and squared; rows of different spreads share one width, as they did in one bincount."""
    from agf.vision.pitch import _bunching

    rng = np.random.default_rng(seed)
    lon = np.concatenate([rng.normal(0.0, 0.002, (4, 300)), rng.uniform(-0.3, 0.3, (3, 300))])
    half = 0.5 * PIXEL
    bins = np.floor(lon / half).astype(np.int64)
    bins -= bins.min(axis=1, keepdims=True)
    width = int(bins.max()) + 2
    counts = np.array([np.bincount(row, minlength=width) for row in bins], float)
    np.testing.assert_array_equal(_bunching(lon, half), np.sum((counts[:, :-1] + counts[:, 1:]) ** 2, axis=1))
    np.testing.assert_array_equal(_bunching(lon[:, :0], half), np.zeros(len(lon)))  # no points: sharp nowhere
