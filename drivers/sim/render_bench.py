"""``agf bench`` case of the simulated camera (group ``vision_ms``): time to render one frame."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from agf.bench import bench_case, time_calls, timing_summary
from agf.camera import KannalaBrandt, load_camera
from agf.paths import repo_path
from agf.scene import load_scene
from drivers.sim.render import render

SCENE = "tests/data/scenes/paper/loaded-low-flat.yaml"


@bench_case("render.frame_s", "vision_ms")
def render_frame_s(quick: bool) -> dict[str, Any]:
    """One loaded paper scene at 4 samples per pixel (seconds): the scene's 1920 x 1920 camera, or a
    480 x 480 fisheye when ``quick``."""
    scene = load_scene(repo_path(SCENE))
    if quick:
        camera = KannalaBrandt(480, 480, math.radians(95), None, 150.0, 150.0, 239.5, 239.5, (0.0, 0.0, 0.0, 0.0))
    else:
        camera = load_camera(scene.camera)
    scene = dataclasses.replace(scene, seed=1)
    samples = time_calls(lambda: render(scene, camera, samples=4), repeats=1 if quick else 3, warmup=0)
    return {
        **timing_summary(samples, scale=1.0),
        "width": camera.width,
        "height": camera.height,
        "samples_per_pixel": 4,
        "note": "4 stratified samples on surface-boundary pixels, 1 elsewhere",
    }
