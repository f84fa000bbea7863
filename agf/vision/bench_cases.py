"""``agf bench`` cases of the camera and vision pipeline (speed in ``vision_ms``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from agf.bench import bench_case, time_calls, timing_summary
from agf.camera import load_camera
from agf.paths import DEFAULT_CONFIG
from agf.vision.panorama import Panorama, panorama_maps, render_panorama


def _default_camera():
    from agf.config import load_config

    return load_camera(load_config(DEFAULT_CONFIG).vision.camera)


@bench_case("camera.panorama_ms", "vision_ms")
def panorama_ms(quick: bool) -> dict[str, Any]:
    """A 2048 x 1024 panorama from a 1920 x 1920 frame, maps cached (budget <= 15 ms median)."""
    camera = _default_camera()
    image = np.random.default_rng(0).integers(0, 255, (camera.height, camera.width), dtype=np.uint8)
    pano = Panorama.around([0, 0, 1], 2048, 1024)
    panorama_maps(camera, pano)  # build the cache outside the timing, as a running controller has it
    samples = time_calls(lambda: render_panorama(image, camera, pano), repeats=5 if quick else 30)
    return {**timing_summary(samples), "size": [2048, 1024], "source": [camera.width, camera.height]}


@bench_case("camera.project_us_per_point", "vision_ms")
def project_us_per_point(quick: bool) -> dict[str, Any]:
    """Projection with the viewpoint-shift solve, per point, in microseconds."""
    camera = _default_camera()
    n = 20_000 if quick else 200_000
    rng = np.random.default_rng(1)
    points = rng.normal(size=(n, 3)) + np.array([1.5, 0.0, 0.0])
    samples = time_calls(lambda: camera.project(points), repeats=3 if quick else 10)
    summary = timing_summary(samples, scale=1e6 / n)
    return {**summary, "points": n, "viewpoint_shift": camera.shift is not None}
