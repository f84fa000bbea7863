"""``agf bench`` cases of the camera and vision pipeline (speed in ``vision_ms``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from agf.bench import bench_case, time_calls, timing_summary
from agf.camera import load_camera
from agf.geometry import transform_from_dict
from agf.paths import DEFAULT_CONFIG, repo_path
from agf.vision.accuracy import AccuracyTally
from agf.vision.panorama import Panorama, panorama_maps, render_panorama

FOREIGN_RENDERS = repo_path("../shared/data/foreign-renders")


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


@bench_case("foreign", "accuracy")
def foreign_accuracy(quick: bool) -> dict[str, Any]:
    """Pose and pitch on frames of an independent renderer (``../shared/data/foreign-renders``: other
    lenses, textures, shadows): within bounds, refused, wrong accepts, errors. Every frame, also with
    ``--quick``: the set is small and it is the figure that says whether the vision generalises."""
    return measure_truthed_frames(FOREIGN_RENDERS).summary()


def measure_truthed_frames(folder: Path) -> AccuracyTally:
    """Measure every ``scenes/NAME.yaml`` + ``images/NAME.png`` + ``images/NAME.truth.json`` of ``folder``
    (the layout of the foreign renders' README) with the default configuration's search volume."""
    from agf.config import load_config
    from agf.pallets import load_pallets

    if not (folder / "scenes").is_dir():
        raise FileNotFoundError(f"{folder}: no scenes/ folder of truthed frames here")
    config = load_config(DEFAULT_CONFIG)
    catalogue = load_pallets(config.vision.pallets)
    tally = AccuracyTally()
    for scene_path in sorted((folder / "scenes").glob("*.yaml")):
        name = scene_path.stem
        scene = yaml.safe_load(scene_path.read_text())
        truth = json.loads((folder / "images" / f"{name}.truth.json").read_text())
        image = cv2.imread(str(folder / "images" / f"{name}.png"), cv2.IMREAD_COLOR)
        if image is None:
            raise FileNotFoundError(f"{folder / 'images' / name}.png: not an image OpenCV can read")
        truth_pose = transform_from_dict(truth["pallet_in_fork"], where=f"{name}.truth.json: pallet_in_fork")
        tally.measure(
            name,
            image,
            load_camera(folder / scene["camera"]),
            transform_from_dict(scene["camera_in_fork"], where=f"{scene_path}: camera_in_fork"),
            catalogue[scene["pallet"]["type"]],
            config.vision.search,
            config.forks,
            truth_pose,
            truth["loaded"],
        )
    return tally
