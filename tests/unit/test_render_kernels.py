"""The campaign renderer's shortcuts change no value the reference computes: the nearest hit found among
objects tried nearest first, with an early exit, is the one trying every object in order finds; a shadow
ray's pre-tests skip only boxes it misses; the sensor's banded noise and compiled last step give the
frame numpy and OpenCV give on the whole."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from agf.camera import KannalaBrandt
from agf.config import ForkGeometry
from agf.geometry import Transform
from agf.paths import repo_path
from agf.scene import load_scene
from drivers.sim import kernels, render
from drivers.sim.fast_render import _object_bounds
from drivers.sim.looks import draw_look
from drivers.sim.raycast import Box, Plane, cast

SMALL = KannalaBrandt(320, 320, math.radians(97), None, 95.0, 95.0, 159.5, 159.5, (0.0, 0.0, 0.0, 0.0))


def _boxes_and_planes(rng: np.random.Generator) -> list:
    """Twelve boxes ahead, copies of two of them (equally near hits), a floor and a wall."""
    boxes = [Box(Transform.from_euler(rng.uniform(1.0, 4.0), *rng.uniform(-1.5, 1.5, 2), *rng.uniform(-1, 1, 3)),
                 rng.uniform(0.05, 0.6, 3), "wood") for _ in range(12)]  # fmt: skip
    floor, wall = Transform.from_euler(z=-1.2), Transform.from_euler(x=6.0, pitch=math.pi / 2)
    return [*boxes, boxes[3], boxes[3], boxes[7], Plane(floor, "concrete"), Plane(wall, "wall")]


def test_nearest_first_with_an_early_exit_finds_what_trying_every_object_finds():
    rng = np.random.default_rng(5)
    kind, rotation, centre, half, _ = packed = kernels.pack_objects(_boxes_and_planes(rng))
    origins = rng.normal(0.0, 0.01, (20000, 3))
    directions = rng.normal(0.0, 1.0, (20000, 3)) + [2.0, 0.0, 0.0]
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    _, _, near = _object_bounds(packed, np.zeros(3), float(np.linalg.norm(origins, axis=1).max()))
    # nearest first, of equal bounds the higher object first: the tie must still go to the lower
    nearest_first, in_order = np.lexsort((-np.arange(len(kind)), near)), np.arange(len(kind))
    found = []
    for objs, bound in ((nearest_first, near[nearest_first]), (in_order, np.full(len(kind), -np.inf))):
        out = np.empty(len(origins)), np.empty(len(origins), np.int32), np.empty(len(origins), np.int8)
        kernels.cast_tiled(origins, directions, np.zeros(len(origins), np.int64), np.array([0, len(kind)]), objs,
                           bound, kind, rotation, centre, half, *out)  # fmt: skip
        found.append(out)
    (distance, index, face), (every_distance, every_index, every_face) = found
    assert np.isin([3, 7, 15, 16], index).all() and not np.isin([12, 13, 14], index).any()  # twins: the first
    assert np.array_equal(distance, every_distance) and np.array_equal(index, every_index)
    assert np.array_equal(face, every_face)


@pytest.mark.parametrize("seed", [1, 4, 6, 1306])
def test_shadow_pre_tests_skip_only_boxes_the_shadow_ray_misses(seed):
    """A random look's lights (sun through a door, lamps, shadows or not): shading with the occluders'
    bounds equals shading with bounds that exclude nothing."""
    scene = dataclasses.replace(load_scene(repo_path("tests/data/scenes/paper/loaded-low-flat.yaml")), look="random",
                                seed=seed)  # fmt: skip
    look = draw_look(scene)
    objects, pallets = render.build_objects(scene, ForkGeometry(), np.random.default_rng(seed), look)
    arrays = render.look_arrays(look, look.camera_lights(scene), objects, pallets)
    pixels = np.stack(np.meshgrid(np.arange(320.0), np.arange(320.0)), -1).reshape(-1, 2)
    pixels = pixels[SMALL.valid_pixels(pixels)]
    origins, directions = SMALL.unproject(pixels)
    hits = cast(objects, origins, directions, pixels, [None] * len(objects))
    open_bounds = arrays[9].copy()
    open_bounds[..., :2], open_bounds[..., 2:4], open_bounds[..., 5] = -np.inf, np.inf, np.inf
    colours = [render._shade_look((*arrays[:9], bounds, *arrays[10:]), objects, pallets, hits, origins, directions)
               for bounds in (arrays[9], open_bounds)]  # fmt: skip
    assert arrays[5][:, 27].any() and np.array_equal(*colours)


def test_a_shadow_ray_never_meets_the_box_it_leaves():
    """Why the shader skips the box a point lies on: its shadow ray starts SHADOW_BIAS out along the
    face's normal and heads away from the face."""
    rng = np.random.default_rng(2)
    objects = [Box(Transform.from_euler(*rng.uniform(-2, 2, 3), *rng.uniform(-3, 3, 3)), rng.uniform(0.002, 1.0, 3),
                   "wood") for _ in range(40)]  # fmt: skip
    kind, R, c, half, _ = kernels.pack_objects(objects)
    met = 0
    for k, face in zip(rng.integers(0, 40, 5000), rng.integers(0, 6, 5000), strict=True):
        local = rng.uniform(-1, 1, 3) * half[k]
        local[face // 2] = half[k, face // 2] * (1 if face % 2 else -1)
        normal = R[k, :, face // 2] * (1 if face % 2 else -1)
        towards = rng.normal(size=3)
        towards += normal * (abs(towards @ normal) - towards @ normal + 1e-3)  # any direction off the face
        towards /= np.linalg.norm(towards)
        start = R[k] @ local + c[k] + kernels.SHADOW_BIAS * normal
        met += kernels.hit(k, kind, R, c, half, *start, *towards)[0] < math.inf
    assert met == 0


def _develop_whole(image: np.ndarray, look, rng: np.random.Generator) -> np.ndarray:
    """The random look's sensor after the white balance as it was written before, on the whole frame."""
    image = cv2.pow(image, look.gamma) * 255.0
    if look.motion_px > 0:
        length = 2 * int(math.ceil(look.motion_px)) + 1
        kernel = np.maximum(0.0, 1.0 - np.abs(np.linspace(-1, 1, length)) * length / (2 * look.motion_px + 1))
        image = cv2.filter2D(image, -1, (kernel / kernel.sum()).astype(np.float32)[:, None])
    if look.blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), look.blur_px)
    sigma = cv2.sqrt(cv2.min(np.maximum(image, 0.0), 255.0) * np.float32(0.7 / 128.0) + np.float32(0.3))
    noise = np.empty_like(image)
    cv2.setRNGSeed(int(rng.integers(1 << 31)))
    cv2.randn(noise, 0.0, look.sigma)
    return np.rint(np.clip(image + sigma * noise, 0, 255)).astype(np.uint8)


@pytest.mark.parametrize(("motion_px", "blur_px", "sigma"), [(0.0, 0.6, 2.0), (1.8, 1.3, 9.0), (2.5, 0.0, 40.0)])
def test_the_sensor_in_bands_gives_the_whole_frame_s_pixels(motion_px, blur_px, sigma):
    look = dataclasses.replace(draw_look(load_scene(repo_path("tests/data/scenes/paper/loaded-low-flat.yaml"))),
                               motion_px=motion_px, blur_px=blur_px, sigma=sigma, jpeg_quality=None)  # fmt: skip
    rng = np.random.default_rng(7)
    image = (rng.uniform(0.0, 1.3, (150, 203, 3)) ** 2).astype(np.float32)
    image[:20, :50] = 0.0  # outside the field of view
    expected = _develop_whole(image.copy(), look, np.random.default_rng(3))
    assert np.array_equal(render.develop_look(image, look, np.random.default_rng(3)), expected)
    assert 0 < (expected == 0).mean() < 0.5 and (expected == 255).any()


def test_tile_lists_hold_each_object_whose_rectangle_meets_the_tile():
    rng = np.random.default_rng(4)
    rects = [None if rng.random() < 0.2 else np.r_[(a := rng.uniform(-300, 900, 2)), a + rng.uniform(-50, 700, 2)]
             for _ in range(30)]  # fmt: skip
    start, objs = kernels.tile_lists(rects, 700, 500, 32)
    for t in range(len(start) - 1):
        x0, y0 = (t % 22) * 32, (t // 22) * 32  # 22 tiles a row
        meets = [k for k, r in enumerate(rects)
                 if r is None or (r[0] < x0 + 32 and r[2] >= x0 and r[1] < y0 + 32 and r[3] >= y0)]  # fmt: skip
        assert list(objs[start[t] : start[t + 1]]) == meets
    assert len(start) - 1 == 22 * 16


def test_pixel_rays_are_kept_per_camera_model_not_per_camera_object():
    """Every campaign pick loads its camera anew: the rays of an equal model must come from the cache (an
    lru_cache keyed by the model object recomputed them for every pick, 2 s of a 5 s pick)."""
    from drivers.sim.fast_render import pixel_rays

    def lens(k1: float) -> KannalaBrandt:
        return dataclasses.replace(SMALL, k=(k1, 0.0, 0.0, 0.0))

    first = pixel_rays(lens(0.01))
    assert pixel_rays(lens(0.01)) is first
    other = pixel_rays(lens(0.02))
    assert other is not first and not np.array_equal(other.directions, first.directions)
