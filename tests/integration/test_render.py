"""The renderer is the test bed: its edges must land where the camera model says, to a fraction of a
pixel, with and without the viewpoint shift, on the reference and the campaign renderer alike; a seed
must give the same image bit for bit, and the fixed scenes keep the look they had when the random looks
came (tests/data/render_hashes.json, written by the renderer before that change)."""

from __future__ import annotations

import dataclasses
import hashlib
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
from drivers.sim.fast_render import render_fast
from drivers.sim.render import render, render_command, truth

SCENE = load_scene(repo_path("tests/data/scenes/paper/unloaded-middle-flat.yaml"))
PALLET = load_pallets(repo_path("configs/pallets.yaml"))["jis-t11"]


def corner_errors(image: np.ndarray, camera, pallet_in_camera) -> list[float]:
    """Distance (px) between each pocket corner's projection and the intersection of the two image
    edges that meet there, each edge located sub-pixel along its projected normal and fitted by a line."""
    return [float(np.linalg.norm(m - t)) for m, t in corners(image, camera, pallet_in_camera)]


def corners(image: np.ndarray, camera, pallet_in_camera) -> list[tuple[np.ndarray, np.ndarray]]:
    """(measured, projected) pixel of each outer pocket corner (see :func:`corner_errors`)."""
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
            projected, _ = camera.project(pallet_in_camera.apply([[0.0, y_corner, half]]))
            errors.append((measured, projected[0]))
    return errors


@pytest.mark.parametrize("shift", [True, False], ids=["with-viewpoint-shift", "without"])
def test_rendered_pocket_corners_land_within_half_a_pixel(shift):
    """Both renderers; the campaign renderer's corners also within 0.05 px of the reference's."""
    camera = load_camera(SCENE.camera)
    camera = camera if shift else camera.without_viewpoint_shift()
    pallet_in_camera = SCENE.camera_in_fork.inverse() @ SCENE.pallet.in_fork
    reference = corners(render(SCENE, camera, shading="geometry")[0], camera, pallet_in_camera)
    fast = corners(render_fast(SCENE, camera, shading="geometry")[0], camera, pallet_in_camera)
    for found in (reference, fast):
        errors = [np.linalg.norm(m - t) for m, t in found]
        assert len(errors) == 4 and max(errors) < 0.5, errors
    between = [np.linalg.norm(f[0] - r[0]) for f, r in zip(fast, reference, strict=True)]
    assert max(between) < 0.05, between


@pytest.mark.parametrize("seed", [3, 11])
def test_random_looks_keep_the_geometry_and_the_truth(seed):
    """A random look moves the bed edge, adds rack and clutter and changes every surface, but the pocket
    corners still land where the truth says."""
    scene = dataclasses.replace(SCENE, look="random", seed=seed)
    camera = load_camera(SCENE.camera)
    image, gt = render_fast(scene, camera, shading="geometry")
    assert gt == truth(SCENE, camera)
    pallet_in_camera = SCENE.camera_in_fork.inverse() @ SCENE.pallet.in_fork
    errors = corner_errors(image, camera, pallet_in_camera)
    assert len(errors) == 4 and max(errors) < 0.5, errors


def test_fixed_scenes_keep_their_look_bit_for_bit(rendered):
    expected = json.loads(repo_path("tests/data/render_hashes.json").read_text())
    changed = [key for key, path in rendered.items() if hashlib.sha1(cv2.imread(str(path)).tobytes()).hexdigest()
               != expected[key]]  # fmt: skip
    assert set(expected) >= set(rendered) and not changed, changed


SMALL = KannalaBrandt(320, 320, math.radians(97), None, 95.0, 95.0, 159.5, 159.5, (0.0, 0.0, 0.0, 0.0))
MID = KannalaBrandt(640, 640, math.radians(97), None, 190.0, 190.0, 319.5, 319.5, (0.0, 0.0, 0.0, 0.0))


@pytest.mark.parametrize(("look", "mean_abs", "p99"), [("fixed", 1.5, 10), ("random", 3.0, 25)])
def test_campaign_renderer_matches_the_reference(look, mean_abs, p99):
    """Same scene, same noise: the images differ only where one sample per pixel (and, away from the
    pallet, one per face in a 4 x 4 block) meets texture the reference averages over four (measured:
    fixed 0.8 grey levels mean, 6 at the 99th percentile; random looks 1.2-2.7 and 9-22; since session 60, texture
    steps sub-sampled near the pallet, fixed 0.69 and 6, the random look here 1.56 and 16, from 1.99 and 20)."""
    scene = dataclasses.replace(load_scene(repo_path("tests/data/scenes/paper/loaded-low-flat.yaml")), look=look)
    reference, _ = render(scene, MID)
    fast, _ = render_fast(scene, MID)
    diff = fast.astype(float) - reference
    assert np.abs(diff).mean() < mean_abs and np.percentile(np.abs(diff), 99) <= p99
    assert abs(diff.mean()) < 0.5 and (np.abs(diff).max(axis=2) > 40).mean() < 0.01


@pytest.mark.parametrize("look", ["fixed", "random"])
def test_regression_campaign_frames_sub_sample_texture_steps_where_the_vision_reads(look):
    """Inside the region the vision reads, the campaign renderer's frame is the reference's to within sensor noise:
    texture steps (carton joints, tape, wood grain) are sub-sampled as outlines are. Point-sampled, the random look
    differed by 2.3 grey levels on average there, 1.05 % of its pixels by more than 20 (fixed look 0.50, 0.002 %), and
    the lines on a load's face, fitted to the stair-stepped joints, leaned 0.1-0.2 deg off the reference's: the
    randomised bench's loaded refusals came from them (session 60). Sub-sampled: 1.3 and 0.17 % (fixed 0.27, none)."""
    from agf.config import ForkGeometry
    from drivers.sim.fast_render import _region

    scene = dataclasses.replace(load_scene(repo_path("tests/data/scenes/paper/loaded-low-flat.yaml")), look=look)
    reference, _ = render(scene, MID)
    fast, _ = render_fast(scene, MID)
    u0, v0, u1, v1 = _region(scene, MID, ForkGeometry())
    inside = (slice(max(v0, 0), v1), slice(max(u0, 0), u1))
    diff = np.abs(fast[inside].astype(float) - reference[inside])
    assert diff.mean() < 1.5 and (diff.max(axis=2) > 20).mean() < 0.004, (diff.mean(), (diff.max(axis=2) > 20).mean())


# sha1 of the region the vision reads (fast_render._region, 24 px in from its border for the blur kernels
# and JPEG's blocks), rendered by the campaign renderer before it was made three times faster: the frames
# of random looks whose wrong accepts the regression scenes hold (paper/loaded-middle-flat look 1306 is
# fixed-wrong-accepts/loaded-middle-flat-look-5). The random looks' hashes are since session 48's: the carton texture
# no longer draws an upright joint at a face's sides (tests/unit/test_textures.py), which changes carton surfaces
# (loads, clutter) alone (the fixed look, without that texture, keeps the hash it had).
# Each random look has two known renders: its hash as recorded, and the one the machine of session 51 (2026-11-30:
# AMD EPYC without AVX-512, numpy 2.4.6, numba 0.68.1, Python 3.11.7) renders from the same code, whose fixed look
# keeps its hash. The cause was not found: that machine gives its hashes with OpenCV 4.14 and 5.0, with numpy's AVX2
# kernels disabled and with numba compiling for a generic CPU. A change of the renderer matches neither.
# Since session 60 the renderer sub-samples texture steps in that region (fast_render.TEXTURE_CONTRAST): the hashes
# are of its frames with that off (conftest point_sampled_texture), which are the frames before; what the
# sub-sampling adds is held to the reference renderer's frame (the test above).
REGION_HASHES = {
    ("paper/loaded-low-flat", 4): {
        "60eec1bcbb7213992be88f9a73cc34a7329e8a9b", "0d8a92e63fe050a5ff004ecfe9f5d3defaef74ca",
    },
    ("paper/loaded-middle-flat", 1306): {
        "a6752ca7d1cfaa454ddf864956abcf31f97bd23e", "75ea738a0e348e3ec8b63f28e71a7fa752ec3aca",
    },
    ("paper/unloaded-middle-front-up", 1): {
        "eb6490eb32940e17c1eb404319085090cdaf542e", "6f4f814711616f46f685b0acc23862fa10c71991",
    },
    ("paper/loaded-low-flat", None): {"195bde2812b27f7790df2cdb452aa2956317d5a5"},
}


@pytest.mark.parametrize(("key", "seed"), list(REGION_HASHES), ids=lambda v: str(v).replace("/", "-"))
def test_campaign_frames_keep_the_region_the_vision_reads_bit_for_bit(key, seed, point_sampled_texture):
    """Random looks (and the fixed one, None) of the campaign renderer: outside the region the vision
    reads, texture may be traded for time; inside, every pixel stays what it was."""
    from agf.config import ForkGeometry
    from drivers.sim.fast_render import _region

    scene = load_scene(repo_path(f"tests/data/scenes/{key}.yaml"))
    scene = scene if seed is None else dataclasses.replace(scene, look="random", seed=seed)
    camera = load_camera(scene.camera)
    image, _ = render_fast(scene, camera)
    u0, v0, u1, v1 = _region(scene, camera, ForkGeometry())
    crop = np.ascontiguousarray(image[max(v0 + 24, 0) : v1 - 23, max(u0 + 24, 0) : u1 - 23])
    assert hashlib.sha1(crop.tobytes()).hexdigest() in REGION_HASHES[key, seed]


def test_same_seed_same_image_bit_for_bit_and_another_seed_differs():
    a, _ = render(SCENE, SMALL)
    b, _ = render(SCENE, SMALL)
    c, _ = render(dataclasses.replace(SCENE, seed=SCENE.seed + 1), SMALL)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_random_looks_differ_by_seed_and_repeat_by_seed():
    scene = dataclasses.replace(SCENE, look="random")
    a, _ = render(scene, SMALL)
    b, _ = render(scene, SMALL)
    c, _ = render(dataclasses.replace(scene, seed=SCENE.seed + 1), SMALL)
    fixed, _ = render(SCENE, SMALL)
    assert np.array_equal(a, b)
    assert np.abs(a.astype(int) - c).mean() > 10 and np.abs(a.astype(int) - fixed).mean() > 10


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


def test_agf_render_randomize_keeps_the_truth(tmp_path, capsys):
    from agf.cli import main

    scene = repo_path("tests/data/scenes/paper/unloaded-low-flat.yaml")
    runs = {}
    for flags in ([], ["--randomize"]):
        out, gt = tmp_path / f"{len(flags)}.png", tmp_path / f"{len(flags)}.json"
        assert main(["render", str(scene), "--out", str(out), "--truth", str(gt), "--json", *flags]) == 0
        runs[len(flags)] = (cv2.imread(str(out)).astype(int), json.loads(gt.read_text()))
    assert runs[0][1] == runs[1][1]
    assert np.abs(runs[0][0] - runs[1][0]).mean() > 10


def test_scene_look_key_is_validated(tmp_path):
    from agf.errors import ConfigError

    text = repo_path("tests/data/scenes/paper/loaded-low-flat.yaml").read_text()
    good, bad = tmp_path / "good.yaml", tmp_path / "bad.yaml"
    good.write_text(text + "look: random\n")
    bad.write_text(text + "look: sunny\n")
    assert load_scene(good).look == "random"
    with pytest.raises(ConfigError, match="look"):
        load_scene(bad)


def test_agf_render_refuses_a_bad_scene(tmp_path, capsys):
    from agf.cli import main

    bad = tmp_path / "bad.yaml"
    bad.write_text(repo_path("tests/data/scenes/paper/loaded-low-flat.yaml").read_text().replace("seed:", "sed:"))
    assert (
        main(["render", str(bad), "--out", str(tmp_path / "x.png"), "--truth", str(tmp_path / "x.json"), "--json"]) == 2
    )
    assert "unknown key" in json.loads(capsys.readouterr().out)["error"]
    assert render_command is not None
