"""Panoramas: known directions land on the expected pixels; the remap samples where it should."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agf.camera import load_camera
from agf.paths import repo_path
from agf.vision.panorama import Panorama, panorama_maps, render_panorama

CAMERA = load_camera(repo_path("configs/cameras/thetav_front.txt"))


def test_known_directions_land_on_expected_pixels():
    pano = Panorama.around([0, 0, 1], 720, 360)
    # Around camera Z with longitude 0 forward: forward is the centre column, right is +90 deg.
    directions = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0], [math.cos(0.3), 0, math.sin(0.3)]])
    expected = np.array(
        [[359.5, 179.5], [539.5, 179.5], [359.5, -0.5], [359.5, 179.5 - math.degrees(0.3) * 2]]
    )
    got = pano.pixels_from_directions(directions)
    np.testing.assert_allclose(got[[0, 1, 3]], expected[[0, 1, 3]], atol=1e-9)
    assert got[2, 1] == pytest.approx(-0.5)


@pytest.mark.parametrize("axis", [(0, 0, 1), (1, 0, 0), (0, 1, 0), (0.3, -0.2, 0.9)])
def test_pixel_direction_round_trip(axis):
    pano = Panorama.around(axis, 400, 200, lon_range=(-2.0, 2.5), lat_range=(-1.2, 1.0))
    rng = np.random.default_rng(4)
    pixels = rng.uniform([0, 0], [399, 199], size=(1000, 2))
    directions = pano.directions_from_pixels(pixels)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    np.testing.assert_allclose(pano.pixels_from_directions(directions), pixels, atol=1e-8)


def test_lines_parallel_to_the_axis_are_columns():
    pano = Panorama.around([0, 0, 1], 1024, 512)
    t = np.linspace(-1.0, 1.0, 50)[:, None]
    points = np.array([1.2, 0.4, 0.0]) + t * np.array([0.0, 0.0, 1.0])  # a vertical edge
    pixels = pano.pixels_from_directions(points / np.linalg.norm(points, axis=1, keepdims=True))
    assert np.ptp(pixels[:, 0]) < 1e-9


def test_remap_samples_the_camera_pixel_of_each_direction():
    """An image whose value is its own column shows, in the panorama, which pixel was sampled."""
    pano = Panorama.around([0, 0, 1], 512, 256, lon_range=(-1.5, 1.5), lat_range=(-1.2, 1.2))
    columns = np.tile(np.arange(CAMERA.width, dtype=np.float32), (CAMERA.height, 1))
    rows = np.tile(np.arange(CAMERA.height, dtype=np.float32)[:, None], (1, CAMERA.width))
    sampled_u, valid = render_panorama(columns, CAMERA, pano)
    sampled_v, _ = render_panorama(rows, CAMERA, pano)
    v, u = np.mgrid[0:256, 0:512]
    expected, ok = CAMERA.project_directions(pano.directions_from_pixels(np.stack([u.ravel(), v.ravel()], 1)))
    assert np.array_equal(ok.reshape(valid.shape), valid)
    error = np.hypot(sampled_u.ravel() - expected[:, 0], sampled_v.ravel() - expected[:, 1])[ok]
    assert np.max(error) < 0.1  # cv2.remap's fixed-point maps: 1/32 px steps


def test_directions_outside_the_lens_are_invalid_not_black():
    pano = Panorama.around([0, 0, 1], 360, 180)
    _, _, valid = panorama_maps(CAMERA, pano)
    directions = pano.directions_from_pixels(np.array([[0.0, 90.0], [180.0, 90.0]]))  # backwards, forwards
    col = pano.pixels_from_directions(directions).round().astype(int)
    assert not valid[col[0, 1], col[0, 0]]
    assert valid[col[1, 1], col[1, 0]]


def test_maps_are_cached_per_camera_and_panorama():
    pano = Panorama.around([1, 0, 0], 64, 32)
    assert panorama_maps(CAMERA, pano) is panorama_maps(CAMERA, Panorama.around([1, 0, 0], 64, 32))


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(axis=[0, 0, 0], width=10, height=10),
        dict(axis=[0, 0, 1], width=0, height=10),
        dict(axis=[0, 0, 1], width=10, height=10, reference=[0, 0, 2]),
    ],
)
def test_bad_panorama_is_refused(kwargs):
    with pytest.raises(ValueError):
        Panorama.around(**kwargs)


def test_image_of_wrong_size_is_refused():
    with pytest.raises(ValueError, match="1920 x 1920"):
        render_panorama(np.zeros((10, 10), np.uint8), CAMERA, Panorama.around([0, 0, 1], 8, 4))
