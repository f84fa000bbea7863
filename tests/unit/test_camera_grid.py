"""Maps from a projected lattice: within 0.005 px of projecting every node at the pitch panoramas'
resolution, on every lens we ship or read."""

from __future__ import annotations

import numpy as np
import pytest

from agf.camera import load_camera
from agf.camera.grid import pixels_from_grid
from agf.paths import repo_path
from agf.vision.panorama import Panorama
from agf.vision.pitch import PitchConfig

OCAMCALIB = repo_path("../shared/data/ocamcalib-1920x1208/calib_results.txt")
LENSES = [
    pytest.param(repo_path("configs/cameras/thetav_front.txt"), id="thetav"),
    pytest.param(
        OCAMCALIB,
        id="ocamcalib-1920x1208",
        marks=pytest.mark.skipif(not OCAMCALIB.exists(), reason=f"{OCAMCALIB} is absent (shared data)"),
    ),
]


def _exact(camera, panorama):
    v, u = np.mgrid[0 : panorama.height, 0 : panorama.width]
    nodes = np.stack([u.ravel(), v.ravel()], axis=1).astype(float)
    pixels, valid = camera.project_directions(panorama.directions_from_pixels(nodes))
    shape = (panorama.height, panorama.width)
    return pixels.reshape(*shape, 2), valid.reshape(shape)


@pytest.mark.parametrize("lens", LENSES)
@pytest.mark.parametrize("axis", [(0, 0, 1), (0.3, 0.2, 0.9), (0.9, -0.3, -0.3)])
def test_interpolated_pixels_match_the_projected_ones(lens, axis):
    camera = load_camera(lens)
    lon, lat = (-0.3, 0.3), (-0.25, 0.3)
    width, height = (round((r[1] - r[0]) / PitchConfig().pixel) for r in (lon, lat))
    panorama = Panorama.around(axis, width, height, lon_range=lon, lat_range=lat)
    exact, exact_valid = _exact(camera, panorama)
    pixels, valid = pixels_from_grid(camera, panorama.directions_from_pixels, panorama.width, panorama.height)
    assert valid.any()
    assert not np.any(valid & ~exact_valid), "a node the lens does not image was called valid"
    assert np.abs(pixels - exact)[valid].max() < 0.005
    assert np.all(pixels[~valid] == -1.0)


def test_step_one_is_the_projection_itself():
    camera = load_camera(repo_path("configs/cameras/thetav_front.txt"))
    panorama = Panorama.around((0, 0, 1), 40, 30, lon_range=(-0.3, 0.3), lat_range=(-0.2, 0.2))
    exact, _ = _exact(camera, panorama)
    pixels, valid = pixels_from_grid(camera, panorama.directions_from_pixels, 40, 30, step=1)
    assert valid.all()
    np.testing.assert_allclose(pixels, exact, atol=2e-4)  # float32


def test_a_map_one_node_wide_works():
    camera = load_camera(repo_path("configs/cameras/thetav_front.txt"))
    panorama = Panorama.around((0, 0, 1), 1, 9, lon_range=(-0.001, 0.001), lat_range=(-0.01, 0.01))
    exact, _ = _exact(camera, panorama)
    pixels, valid = pixels_from_grid(camera, panorama.directions_from_pixels, 1, 9)
    assert valid.all()
    np.testing.assert_allclose(pixels, exact, atol=0.005)


@pytest.mark.parametrize("width, height, step", [(0, 5, 4), (5, -1, 4), (5, 5, 3), (5, 5, 0)])
def test_bad_grid_is_refused(width, height, step):
    camera = load_camera(repo_path("configs/cameras/thetav_front.txt"))
    with pytest.raises(ValueError, match="grid size"):
        pixels_from_grid(camera, lambda nodes: np.tile([1.0, 0.0, 0.0], (len(nodes), 1)), width, height, step)
