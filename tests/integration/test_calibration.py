"""Camera-to-fork calibration on rendered panel scenes with mount errors up to 3 deg and 20 mm."""

from __future__ import annotations

import dataclasses
import json
import math

import cv2
import numpy as np
import pytest

from agf.camera import load_camera
from agf.config import load_calibration, load_config
from agf.errors import MeasurementError
from agf.geometry import Transform
from agf.paths import DEFAULT_CONFIG
from agf.scene import load_scene
from agf.vision.calibration import WITHOUT_SHIFT, Panel, calibrate, fit_panel
from drivers.sim.render import render
from tests.integration.conftest import SCENES

# one pytest-xdist worker runs them all: its module fixture renders the panel images once for all its tests
pytestmark = pytest.mark.xdist_group("test_calibration")

CONFIG = load_config(DEFAULT_CONFIG)
NOMINAL = load_calibration(CONFIG.vision.calibration)
BASE = load_scene(SCENES / "panel.yaml")
CAMERA = load_camera(BASE.camera)
PANEL = Panel(*BASE.panel.size, BASE.panel.thickness)


def mounted(seed: int) -> Transform:
    """A mount off the nominal one by up to 20 mm and 3 deg on every axis."""
    d = np.random.default_rng(seed).uniform(-1, 1, 6) * np.r_[0.02, 0.02, 0.02, np.radians([3, 3, 3])]
    return Transform.from_euler(*(NOMINAL.translation + d[:3]), d[3], d[4], d[5])


@pytest.fixture(scope="module")
def panel_images():
    truths = [mounted(seed) for seed in (1, 2, 3)]
    images = [
        cv2.cvtColor(render(dataclasses.replace(BASE, camera_in_fork=t, seed=i), CAMERA)[0], cv2.COLOR_BGR2GRAY)
        for i, t in enumerate(truths)
    ]
    return truths, images


def pose_error(estimate: Transform, truth: Transform) -> tuple[float, float]:
    """Largest translation error (mm) and largest Euler-angle error (deg)."""
    e, t = estimate.to_dict(), truth.to_dict()
    return (
        max(abs(e[k] - t[k]) for k in ("x_mm", "y_mm", "z_mm")),
        max(abs(e[k] - t[k]) for k in ("roll_deg", "pitch_deg", "yaw_deg")),
    )


def test_each_mount_is_recovered_within_2mm_and_005deg(panel_images):
    truths, images = panel_images
    for truth, image in zip(truths, images, strict=True):
        fit = fit_panel(image, CAMERA, PANEL, CONFIG.forks, NOMINAL)
        mm, deg = pose_error(fit.camera_in_fork, truth)
        assert mm <= 2.0 and deg <= 0.05, (mm, deg)


def test_ignoring_the_viewpoint_shift_biases_the_height(panel_images):
    truths, images = panel_images
    shifted = fit_panel(images[0], CAMERA, PANEL, CONFIG.forks, NOMINAL)
    naive = fit_panel(
        images[0], CAMERA.without_viewpoint_shift(), PANEL, CONFIG.forks, shifted.camera_in_fork, WITHOUT_SHIFT
    )
    bias = naive.camera_in_fork.translation[2] - truths[0].translation[2]
    assert abs(shifted.camera_in_fork.translation[2] - truths[0].translation[2]) < 0.002
    assert abs(bias) > 0.005  # paper Table 1: about 10 mm of height


def test_images_of_one_mount_combine_and_an_outlier_is_rejected(panel_images):
    truths, images = panel_images
    same = [
        cv2.cvtColor(render(dataclasses.replace(BASE, camera_in_fork=truths[0], seed=s), CAMERA)[0], cv2.COLOR_BGR2GRAY)
        for s in (21, 22)
    ]
    result = calibrate([images[0], *same, images[1]], CAMERA, PANEL, CONFIG.forks, NOMINAL)
    mm, deg = pose_error(result.camera_in_fork, truths[0])
    assert mm <= 2.0 and deg <= 0.05
    assert 3 in result.rejected and "outlier" in result.rejected[3]
    assert result.spread["z_mm"] < 1.0


def test_an_image_without_the_panel_is_refused():
    blank = np.full((CAMERA.height, CAMERA.width), 90, np.uint8)
    with pytest.raises(MeasurementError, match="panel"):
        fit_panel(blank, CAMERA, PANEL, CONFIG.forks, NOMINAL)


def test_tools_calibrate_writes_yaml_json_and_overlay_and_never_overwrites(panel_images, tmp_path, capsys):
    from agf.cli import main

    image = tmp_path / "panel.png"
    cv2.imwrite(str(image), panel_images[1][0])
    out = tmp_path / "calibration.yaml"
    args = ["calibrate", str(image), "--panel", "1000", "600", "--out", str(out), "--json"]
    assert main(args) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["ok"] and set(result["camera_in_fork"]) >= {"x_mm", "z_mm", "pitch_deg"}
    assert abs(load_calibration(out).translation[2] - panel_images[0][0].translation[2]) < 0.002
    assert cv2.imread(result["overlay"]) is not None
    assert result["without_viewpoint_shift"]["z_mm"] != pytest.approx(result["camera_in_fork"]["z_mm"], abs=3)
    assert main(args) == 2  # exists: refused without --force
    assert "--force" in json.loads(capsys.readouterr().out)["error"]
    assert main([*args, "--force"]) == 0
    assert math.isfinite(json.loads(capsys.readouterr().out)["residual_px"])


def test_regression_mount_that_converged_to_a_wrong_pose_with_one_grid_start():
    """Mount seed 0 (roll -2.9, pitch 1.9, yaw 2.5 deg) once ended 59 mm and 2.1 deg off with a 0.6 px
    residual from the single best grid node; several starts and stricter acceptance fix it."""
    truth = mounted(0)
    image = cv2.cvtColor(render(dataclasses.replace(BASE, camera_in_fork=truth, seed=0), CAMERA)[0], cv2.COLOR_BGR2GRAY)
    fit = fit_panel(image, CAMERA, PANEL, CONFIG.forks, NOMINAL)
    mm, deg = pose_error(fit.camera_in_fork, truth)
    assert mm <= 2.0 and deg <= 0.05, (mm, deg)
