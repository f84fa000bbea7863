"""Sub-pixel edge search along normals (agf/vision/edges.py) on synthetic steps of known position."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agf.vision.edges import _falling_slope, mad_sigma, search_edges

WIDTH, HEIGHT = 120, 60


def _steps(*steps: tuple[float, float], sigma: float = 1.0) -> np.ndarray:
    """A float32 image (HEIGHT, WIDTH) falling by ``drop`` grey levels at column ``at`` for each (at, drop),
    each step blurred by ``sigma`` px (the exact integral of a Gaussian, not a blurred raster)."""
    x = np.arange(WIDTH, dtype=np.float64)
    row = np.full(WIDTH, 200.0)
    for at, drop in steps:
        row -= drop * 0.5 * (1.0 + np.vectorize(math.erf)((x - at) / (sigma * math.sqrt(2.0))))
    return np.tile(row, (HEIGHT, 1)).astype(np.float32)


def _along_rows(columns: list[float]) -> tuple[np.ndarray, np.ndarray]:
    starts = np.array([[c, 10.0 + 5 * i] for i, c in enumerate(columns)])
    return starts, np.tile([1.0, 0.0], (len(columns), 1))


def test_a_blurred_step_is_found_within_0_65_px_at_any_phase_and_0_1_px_on_average():
    """Bilinear sampling makes the profile's slope piecewise constant between pixel centres, so a single
    profile finds a step up to 0.65 px off, depending on where the step lies between two centres; along an
    edge that crosses the pixel grid the errors average out (a known limit, not a target)."""
    errors = []
    for at in np.arange(50.0, 51.0, 0.125):
        starts, normals = _along_rows([47.3, 48.6, 50.0, 52.9])
        found = search_edges(_steps((at, 100.0)), starts, normals, 5.0)
        assert found.valid.all()
        errors.append(starts[:, 0] + found.offset - at)
    assert np.abs(errors).max() <= 0.65
    assert abs(np.mean(errors)) <= 0.1


def test_a_rising_step_needs_either_polarity():
    image = 200.0 - _steps((50.5, 100.0))  # dark to bright along the normal
    starts, normals = _along_rows([48.0])
    assert not search_edges(image, starts, normals, 5.0).valid[0]
    found = search_edges(image, starts, normals, 5.0, either_polarity=True)
    assert found.valid[0] and abs(starts[0, 0] + found.offset[0] - 50.5) < 0.2


def test_a_radius_per_point_keeps_each_search_to_its_own_range():
    """A weak edge 1 px ahead and a strong one 5 px ahead: the whole radius finds the strong one, a radius of
    3 px the weak one (the pocket top beside the face's stronger top edge)."""
    image = _steps((52.5, 30.0), (56.5, 100.0))
    starts, normals = _along_rows([51.0, 51.0])
    found = search_edges(image, starts, normals, np.array([8.0, 3.0]))
    assert found.valid.all()
    np.testing.assert_allclose(starts[:, 0] + found.offset, [56.5, 52.5], atol=0.2)


def test_a_step_beyond_a_points_range_is_no_edge():
    """The slope still rises at the end of the range: the maximum lies outside it."""
    image = _steps((60.0, 100.0))
    starts, normals = _along_rows([51.0, 51.0])
    found = search_edges(image, starts, normals, np.array([3.0, 12.0]))
    assert not found.valid[0] and found.strength[0] == 0.0
    assert found.valid[1]


def test_a_step_in_one_colour_channel_is_found_at_that_channels_strength():
    """A blue pallet in dim light: its pocket edge a step of 78 in blue, flat in red and green."""
    blue = _steps((40.5, 78.0))
    flat = np.full_like(blue, 50.0)
    image = np.dstack([blue, flat, flat])
    starts, normals = _along_rows([38.0, 43.0])
    found = search_edges(image, starts, normals, 5.0, either_polarity=True)
    assert found.valid.all()
    np.testing.assert_allclose(starts[:, 0] + found.offset, 40.5, atol=0.2)
    alone = search_edges(blue, starts, normals, 5.0, either_polarity=True)
    np.testing.assert_allclose(found.strength, alone.strength)


def test_a_colour_image_without_either_polarity_is_refused():
    image = np.zeros((HEIGHT, WIDTH, 3), np.float32)
    starts, normals = _along_rows([40.0])
    with pytest.raises(ValueError, match="3-channel image has no single polarity"):
        search_edges(image, starts, normals, 5.0)


def test_profiles_leaving_the_image_are_not_edges():
    image = _steps((3.0, 100.0))
    starts, normals = _along_rows([2.0, 6.0])
    found = search_edges(image, starts, normals, 4.0)
    assert not found.valid[0]  # its profile starts 2 px left of the image
    assert found.valid[1]


def test_no_points_give_an_empty_search():
    found = search_edges(_steps((50.0, 100.0)), np.zeros((0, 2)), np.zeros((0, 2)), 4.0)
    assert found.offset.shape == found.strength.shape == found.valid.shape == (0,)


def test_regression_more_profiles_than_opencv_remap_takes_in_one_call():
    """``cv2.remap`` refuses maps of 32767 rows or more; the face-edge check with its rival poses reaches
    20,000 profiles for the catalogue's faces and would pass that for a wider pallet or a finer spacing."""
    image = _steps((50.5, 100.0))
    n = 40_000
    starts = np.column_stack([np.full(n, 48.0), np.linspace(2.0, HEIGHT - 3.0, n)])
    found = search_edges(image, starts, np.tile([1.0, 0.0], (n, 1)), 4.0)
    assert found.valid.all()
    np.testing.assert_allclose(starts[:, 0] + found.offset, 50.5, atol=0.2)


@pytest.mark.parametrize("shape", [(7, 9), (300, 41), (50, 33, 3)])
def test_falling_slope_is_minus_numpys_gradient(shape):
    profile = np.random.default_rng(17).uniform(0, 255, shape).astype(np.float32)
    np.testing.assert_allclose(_falling_slope(profile, 0.25), -np.gradient(profile, 0.25, axis=1), atol=1e-3)


def test_mad_sigma_is_the_noise_sigma_per_channel_and_ignores_edges():
    rng = np.random.default_rng(11)
    noise = rng.normal(0.0, [1.0, 2.0, 4.0], size=(200, 200, 3))
    noise[:, 100:102] += 500.0  # an edge: a few large values
    sigma = mad_sigma(noise, axis=(0, 1))
    assert sigma.shape == (3,)
    np.testing.assert_allclose(sigma, [1.0, 2.0, 4.0], rtol=0.03)
    assert abs(float(mad_sigma(noise[..., 0].ravel())) - 1.0) < 0.03
