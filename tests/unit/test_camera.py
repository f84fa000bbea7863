"""Camera models: round trips, agreement with OpenCV and between Kalibr models, file errors."""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.polynomial import polynomial

from agf.camera import KannalaBrandt, OCamCalib, ViewpointShift, load_camera
from agf.camera.ocamcalib import _polyval, read_calib_results, write_calib_results
from agf.errors import ConfigError
from agf.paths import repo_path

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
THETAV = repo_path("configs/cameras/thetav_front.txt")
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"real camera data not found at {DATA}")

REAL_FILES = [
    "ocamcalib-webcam/calib_results.txt",
    "ocamcalib-1920x1208/calib_results.txt",
    "ricoh-theta-s-front/ds.yaml",
    "ricoh-theta-s-front/eucm.yaml",
    "ricoh-theta-s-front/omni-radtan.yaml",
]


def kannala_brandt(shift: ViewpointShift | None = None) -> KannalaBrandt:
    return KannalaBrandt(
        1400, 1400, math.radians(100), shift, 330.0, 331.5, 701.2, 698.9, (0.03, -0.011, 0.004, -0.0006)
    )


def load_quietly(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_camera(path)


def all_models():
    models = {"thetav": load_camera(THETAV), "kannala_brandt": kannala_brandt()}
    if DATA.is_dir():
        models.update({name: load_quietly(DATA / name) for name in REAL_FILES})
    return models


def sample_valid_pixels(camera, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pixels = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], size=(4 * n, 2))
    return pixels[camera.valid_pixels(pixels)][:n]


@pytest.mark.parametrize("name", list(all_models()))
@pytest.mark.parametrize("shifted", [False, True])
def test_project_unproject_round_trip_below_1e3_px(name, shifted):
    camera = all_models()[name]
    shift = ViewpointShift(poly=np.array([0.0, 0.012, 0.006])) if shifted else None
    camera = dataclasses.replace(camera, shift=shift) if shifted or camera.shift is not None else camera
    pixels = sample_valid_pixels(camera, 3000, seed=1)
    origins, directions = camera.unproject(pixels)
    distance = np.random.default_rng(2).uniform(0.2, 6.0, size=(len(pixels), 1))
    back, valid = camera.project(origins + distance * directions)
    assert valid.all()
    assert np.max(np.linalg.norm(back - pixels, axis=1)) < 1e-3


def test_viewpoint_shift_moves_ray_origins_forward_at_wide_angles():
    camera = load_camera(THETAV)
    incidence = np.radians([45.0, 80.0])
    directions = np.stack([np.cos(incidence), np.sin(incidence), np.zeros(2)], axis=1)
    pixels, valid = camera.project_directions(directions)
    origins, _ = camera.unproject(pixels)
    assert valid.all()
    assert origins[0, 0] == pytest.approx(0.0, abs=1e-9)
    assert 0.008 < origins[1, 0] < 0.012  # paper IV.B: about 10 mm between 45 and 80 deg


def test_shifted_projection_differs_from_central_one_near_the_lens():
    camera = load_camera(THETAV)
    point = np.array([[0.3, 0.0, -0.9]])  # a panel corner below and in front: about 72 deg
    shifted, _ = camera.project(point)
    central, _ = camera.without_viewpoint_shift().project(point)
    assert np.linalg.norm(shifted - central) > 1.0


def test_kannala_brandt_matches_cv2_fisheye_inside_90_deg():
    camera = kannala_brandt()
    rng = np.random.default_rng(3)
    incidence = rng.uniform(0.0, math.radians(89.0), 500)
    azimuth = rng.uniform(-math.pi, math.pi, 500)
    optical = np.stack(
        [np.sin(incidence) * np.cos(azimuth), np.sin(incidence) * np.sin(azimuth), np.cos(incidence)], 1
    )
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    D = np.array(camera.k)
    expected, _ = cv2.fisheye.projectPoints(optical[:, None, :], np.zeros(3), np.zeros(3), K, D)
    expected = expected[:, 0, :]
    camera_frame = np.stack([optical[:, 2], -optical[:, 0], -optical[:, 1]], axis=1)
    ours, valid = camera.project_directions(camera_frame)
    assert valid.all()
    np.testing.assert_allclose(ours, expected, rtol=1e-6)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    undistorted = cv2.fisheye.undistortPoints(expected[:, None, :], K, D, criteria=criteria)[:, 0, :]
    _, directions = camera.unproject(expected)
    # OpenCV clamps the distorted angle theta_d to pi/2 before undistorting; compare where it does not.
    usable = camera._distort(incidence)[0] < math.pi / 2
    assert usable.sum() > 400
    ours_x, ours_y = -directions[:, 1] / directions[:, 0], -directions[:, 2] / directions[:, 0]
    np.testing.assert_allclose(ours_x[usable], undistorted[usable, 0], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(ours_y[usable], undistorted[usable, 1], rtol=1e-6, atol=1e-9)


def test_kannala_brandt_holds_beyond_180_deg():
    camera = kannala_brandt()
    incidence = math.radians(98.0)
    direction = np.array([[math.cos(incidence), 0.0, math.sin(incidence)]])
    pixels, valid = camera.project_directions(direction)
    _, back = camera.unproject(pixels)
    assert valid.all()
    np.testing.assert_allclose(back, direction, atol=1e-9)


@needs_data
def test_theta_s_double_sphere_and_eucm_agree_within_1px_to_85_deg():
    ds = load_camera(DATA / "ricoh-theta-s-front/ds.yaml")
    eucm = load_camera(DATA / "ricoh-theta-s-front/eucm.yaml")
    incidence, azimuth = np.meshgrid(np.radians(np.linspace(0, 85, 86)), np.radians(np.arange(0, 360, 5)))
    directions = np.stack(
        [np.cos(incidence), np.sin(incidence) * np.cos(azimuth), np.sin(incidence) * np.sin(azimuth)], -1
    ).reshape(-1, 3)
    a, valid_a = ds.project_directions(directions)
    b, valid_b = eucm.project_directions(directions)
    assert valid_a.all() and valid_b.all()
    assert np.max(np.linalg.norm(a - b, axis=1)) < 1.0


def _fit_grid_rms(camera, corners: np.ndarray, grid: np.ndarray) -> float:
    """RMS (px) of a planar-grid pose fitted through ``camera`` by Gauss-Newton from a PnP start."""
    _, rays = camera.unproject(corners)
    optical = np.stack([-rays[:, 1], -rays[:, 2], rays[:, 0]], axis=1)
    ok, rvec, tvec = cv2.solvePnP(grid, optical[:, :2] / optical[:, 2:], np.eye(3), None)
    assert ok
    params = np.concatenate([rvec.ravel(), tvec.ravel()])

    def residual(p: np.ndarray) -> np.ndarray:
        R, _ = cv2.Rodrigues(p[:3])
        points_optical = grid @ R.T + p[3:]
        points_camera = np.stack([points_optical[:, 2], -points_optical[:, 0], -points_optical[:, 1]], 1)
        pixels, _ = camera.project(points_camera)
        return (pixels - corners).ravel()

    for _ in range(30):
        r = residual(params)
        J = np.stack([(residual(params + h) - r) / 1e-7 for h in np.eye(6) * 1e-7], axis=1)
        params = params - np.linalg.lstsq(J, r, rcond=None)[0]
    return float(np.sqrt(np.mean(residual(params).reshape(-1, 2) ** 2 * 2)))


@needs_data
def test_ocamcalib_reprojects_real_checkerboards_below_1px_median():
    camera = load_quietly(DATA / "ocamcalib-webcam/calib_results.txt")
    swapped = dataclasses.replace(camera, center_row=camera.center_col, center_col=camera.center_row)
    grid = np.array([[x, y, 0.0] for y in range(4) for x in range(5)])
    ours, wrong = [], []
    for image_path in sorted((DATA / "ocamcalib-webcam").glob("cal*.jpg")):
        gray = cv2.imread(str(image_path), cv2.IMREAD_GRAYSCALE)
        found, corners = cv2.findChessboardCornersSB(gray, (5, 4))
        if not found:
            continue
        corners = corners.reshape(-1, 2).astype(float)
        ours.append(_fit_grid_rms(camera, corners, grid))
        wrong.append(_fit_grid_rms(swapped, corners, grid))
    assert len(ours) >= 6
    assert np.median(ours) <= 1.0
    assert np.median(wrong) > 1.5 * np.median(ours)  # the test can tell a row/column mix-up


def test_calib_results_write_read_round_trip(tmp_path):
    camera = load_camera(THETAV)
    write_calib_results(camera, tmp_path / "copy.txt")
    again = read_calib_results(tmp_path / "copy.txt")
    np.testing.assert_allclose(again.pol, camera.pol, rtol=1e-8)
    assert (again.center_row, again.center_col) == pytest.approx((camera.center_row, camera.center_col))
    np.testing.assert_allclose(again.shift.offsets, camera.shift.offsets, atol=1e-7)


def test_poor_invpol_is_warned(tmp_path):
    camera = load_camera(THETAV)
    bad = dataclasses.replace(
        camera, invpol=camera.invpol * np.r_[1.0, 1.01, np.ones(camera.invpol.size - 2)]
    )
    write_calib_results(bad, tmp_path / "bad.txt")
    with pytest.warns(UserWarning, match="invpol disagrees"):
        read_calib_results(tmp_path / "bad.txt")


def _valid_lines() -> list[str]:
    return THETAV.read_text().splitlines()


CORRUPTIONS = {
    "truncated": lambda lines, k: lines[: 8 + k % 10],
    "wrong_count": lambda lines, k: [
        _recount(line) if i == _data_index(lines, 0) else line for i, line in enumerate(lines)
    ],
    "nan": lambda lines, k: [
        _nan(line) if i == _data_index(lines, k % 4) else line for i, line in enumerate(lines)
    ],
    "wrong_size": lambda lines, k: [
        ("0 1920" if k % 2 else "1920.5 1920") if i == _data_index(lines, 4) else line
        for i, line in enumerate(lines)
    ],
    "text": lambda lines, k: [
        line.replace("0", "O", 1) if i == _data_index(lines, k % 5) else line for i, line in enumerate(lines)
    ],
}


def _data_index(lines: list[str], n: int) -> int:
    data = [i for i, line in enumerate(lines) if line.strip() and not line.startswith("#")]
    return data[n]


def _recount(line: str) -> str:
    count, rest = line.split(" ", 1)
    return f"{int(count) + 1} {rest}"


def _nan(line: str) -> str:
    tokens = line.split()
    tokens[-1] = "nan"
    return " ".join(tokens)


@settings(max_examples=40, deadline=None)
@given(kind=st.sampled_from(sorted(CORRUPTIONS)), k=st.integers(0, 100))
def test_malformed_calib_results_is_a_clear_error(tmp_path_factory, kind, k):
    path = tmp_path_factory.mktemp("calib") / "calib_results.txt"
    path.write_text("\n".join(CORRUPTIONS[kind](_valid_lines(), k)) + "\n")
    with pytest.raises(ConfigError, match=str(path)):
        read_calib_results(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("model: fisheye_magic\nwidth: 10\nheight: 10\n", "model: expected one of"),
        ("model: eucm\nwidth: 10\nheight: 10\nfx: 1\nfy: 1\ncx: 5\ncy: 5\nalpha: 0.5\n", "beta: missing"),
        (
            "model: eucm\nwidth: -4\nheight: 10\nfx: 1\nfy: 1\ncx: 5\ncy: 5\nalpha: 0.5\nbeta: 1\n",
            "width: expected",
        ),
        (
            "model: kannala_brandt\nwidth: 10\nheight: 10\nfx: 1\nfy: 1\ncx: 5\ncy: 5\nk: [0, 0]\ncolour: 3\n",
            "colour: unknown key",
        ),
        (
            "cam0:\n  camera_model: pinhole\n  distortion_model: radtan\n  intrinsics: [1, 1, 1, 1]\n"
            "  resolution: [10, 10]\n",
            "unsupported Kalibr model",
        ),
    ],
)
def test_bad_camera_yaml_names_the_key(tmp_path, text, message):
    path = tmp_path / "camera.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_camera(path)


def test_our_yaml_form_matches_the_kalibr_form(tmp_path):
    path = tmp_path / "ds.yaml"
    path.write_text(
        "model: double_sphere\nwidth: 640\nheight: 640\nfx: 155.87\nfy: 154.44\ncx: 320.3\ncy: 318.17\n"
        "xi: -0.1886\nalpha: 0.6051\nmax_incidence_deg: 95\n"
        "viewpoint_shift: {angles_deg: [0, 45, 90], offsets_mm: [-2, 0, 8]}\n"
    )
    camera = load_camera(path)
    assert math.degrees(camera.max_incidence) == pytest.approx(95)
    assert camera.shift.offset(math.radians(90)) == pytest.approx(0.008)


def test_ocamcalib_model_rejects_positive_pol0():
    with pytest.raises(ValueError, match="pol"):
        OCamCalib(100, 100, 1.0, None, np.array([5.0, 0.0]), np.array([1.0, 2.0]), 50.0, 50.0)


def test_tabulated_viewpoint_shift_interpolates_with_its_derivative():
    """The table's spline passes through its points, its slope is the derivative of its value, and it
    continues linearly beyond the table's ends."""
    angles = np.radians([10.0, 30.0, 45.0, 60.0, 80.0, 95.0])
    offsets = np.array([-0.004, -0.002, 0.0, 0.003, 0.009, 0.014])
    shift = ViewpointShift(angles=angles, offsets=offsets)
    assert np.allclose(shift.offset(angles), offsets, atol=1e-15)
    theta = np.random.default_rng(3).uniform(angles[0] - 0.3, angles[-1] + 0.3, 200)
    step = 1e-6
    numeric = (shift.offset(theta + step) - shift.offset(theta - step)) / (2 * step)
    assert np.allclose(shift.derivative(theta), numeric, atol=1e-7)
    beyond = angles[-1] + 0.2
    assert shift.offset(beyond) == pytest.approx(offsets[-1] + 0.2 * shift.derivative(angles[-1]))


@pytest.mark.parametrize("degree", [0, 1, 4, 9])
def test_ocamcalib_in_place_polyval_equals_numpys(degree):
    # _polyval keeps numpy's Horner order so that the projection's bits did not change when it replaced polyval
    rng = np.random.default_rng(degree)
    x, coefficients = rng.normal(size=257) * 900.0, rng.normal(size=degree + 1)
    x_before = x.copy()
    assert np.array_equal(_polyval(x, coefficients), polynomial.polyval(x, coefficients))
    assert np.array_equal(x, x_before)  # the argument is not overwritten by the in-place steps
