"""The renderer is the test bed: its edges must land where the camera model says, to a fraction of a
pixel, with and without the viewpoint shift, and a seed must give the same image bit for bit."""

from __future__ import annotations

import dataclasses
import json
import math

import cv2
import numpy as np
import pytest

from agf.camera import KannalaBrandt, load_camera
from agf.pallets import load_pallets
from agf.paths import repo_path
from agf.scene import load_scene
from agf.vision.edges import project_with_normals, search_edges
from drivers.sim.render import render, render_command

SCENE = load_scene(repo_path("tests/data/scenes/paper/unloaded-middle-flat.yaml"))
PALLET = load_pallets(repo_path("configs/pallets.yaml"))["jis-t11"]


def corner_errors(image: np.ndarray, camera, pallet_in_camera) -> list[float]:
    """Distance (px) between each pocket corner's projection and the intersection of the two image
    edges that meet there, each edge located sub-pixel along its projected normal and fitted by a line."""
    smooth = cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32), (0, 0), 0.7)
    half = PALLET.pocket_height / 2
    errors = []
    for y0, y1 in PALLET.pockets():
        for y_corner, inward in ((y0, 1.0), (y1, -1.0)):
            along = np.linspace(0.008, 0.044, 36)
            top = np.c_[0 * along, y_corner + inward * along, 0 * along + half]
            side = np.c_[0 * along, 0 * along + y_corner, half - along]
            lines = []
            for points, normal in ((top, (0.0, 0.0, -1.0)), (side, (0.0, inward, 0.0))):
                p0, d, _ = project_with_normals(camera, pallet_in_camera, points, np.tile(normal, (len(points), 1)))
                found = search_edges(smooth, p0, d, 3.0)
                edge = p0 + found.offset[:, None] * d
                centre = edge.mean(axis=0)
                _, _, vt = np.linalg.svd(edge - centre)
                lines.append((centre, vt[0]))
            (a, u), (b, v) = lines
            t = np.linalg.solve(np.c_[u, -v], b - a)
            measured = a + t[0] * u
            truth, _ = camera.project(pallet_in_camera.apply([[0.0, y_corner, half]]))
            errors.append(float(np.linalg.norm(measured - truth[0])))
    return errors


@pytest.mark.parametrize("shift", [True, False], ids=["with-viewpoint-shift", "without"])
def test_rendered_pocket_corners_land_within_half_a_pixel(shift):
    camera = load_camera(SCENE.camera)
    camera = camera if shift else camera.without_viewpoint_shift()
    image, _ = render(SCENE, camera, shading="geometry")
    pallet_in_camera = SCENE.camera_in_fork.inverse() @ SCENE.pallet.in_fork
    errors = corner_errors(image, camera, pallet_in_camera)
    assert len(errors) == 4 and max(errors) < 0.5, errors


SMALL = KannalaBrandt(320, 320, math.radians(97), None, 95.0, 95.0, 159.5, 159.5, (0.0, 0.0, 0.0, 0.0))


def test_same_seed_same_image_bit_for_bit_and_another_seed_differs():
    a, _ = render(SCENE, SMALL)
    b, _ = render(SCENE, SMALL)
    c, _ = render(dataclasses.replace(SCENE, seed=SCENE.seed + 1), SMALL)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_light_scales_exposure():
    dark, _ = render(dataclasses.replace(SCENE, environment=dataclasses.replace(SCENE.environment, light=0.4)), SMALL)
    bright, _ = render(SCENE, SMALL)
    assert dark.mean() < 0.6 * bright.mean()


def test_agf_render_writes_image_and_truth(tmp_path, capsys):
    from agf.cli import main

    out, truth = tmp_path / "frame.png", tmp_path / "truth.json"
    assert (
        main(
            [
                "render",
                str(repo_path("tests/data/scenes/paper/loaded-low-flat.yaml")),
                "--out",
                str(out),
                "--truth",
                str(truth),
                "--json",
            ]
        )
        == 0
    )
    gt = json.loads(truth.read_text())
    assert gt["loaded"] is True and gt["pallet_in_fork"]["z_mm"] == pytest.approx(355)
    assert gt["pallet_in_camera"]["z_mm"] == pytest.approx(355 - 1055)
    assert len(gt["pocket_corners_px"]) == 2 and cv2.imread(str(out)).shape == (1920, 1920, 3)


def test_agf_render_refuses_a_bad_scene(tmp_path, capsys):
    from agf.cli import main

    bad = tmp_path / "bad.yaml"
    bad.write_text(repo_path("tests/data/scenes/paper/loaded-low-flat.yaml").read_text().replace("seed:", "sed:"))
    assert (
        main(["render", str(bad), "--out", str(tmp_path / "x.png"), "--truth", str(tmp_path / "x.json"), "--json"]) == 2
    )
    assert "unknown key" in json.loads(capsys.readouterr().out)["error"]
    assert render_command is not None
