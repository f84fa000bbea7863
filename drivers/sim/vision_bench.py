"""``agf bench`` cases that need rendered frames: pose, measurement, calibration, rendering itself.

Renders are cached under the system temp directory, keyed by the scene file and the renderer's source,
so a second bench run measures the vision and not the renderer.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import statistics
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from agf.bench import bench_case, time_calls, timing_summary
from agf.camera import load_camera
from agf.config import load_calibration, load_config
from agf.controller import ControllerConfig
from agf.geometry import Transform
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG, repo_path
from agf.scene import Load, PalletPlacement, Scene, load_scene
from agf.vision.accuracy import AccuracyTally
from agf.vision.calibration import WITHOUT_SHIFT, Panel, fit_panel
from agf.vision.face_model import face_model_from_pallet
from agf.vision.pallet_pose import estimate_pallet_pose
from drivers.sim import fast_render, kernels, looks, raycast, render, textures
from drivers.sim.render import exposed

SCENES = repo_path("tests/data/scenes")
QUICK = ("paper/unloaded-low-flat", "paper/loaded-middle-front-up", "paper/unloaded-high-rear-up")


def rendered(scene: Scene, key: str) -> np.ndarray:
    """The frame of ``scene``, from the cache when the scene and renderer are unchanged."""
    source = Path(render.__file__).read_bytes() + Path(raycast.__file__).read_bytes() + repr(scene).encode()
    path = (
        Path(tempfile.gettempdir())
        / "agf-renders"
        / f"{key.replace('/', '-')}-{hashlib.sha1(source).hexdigest()[:12]}.png"
    )
    if not path.exists():
        _cache(path, render.render(scene)[0])
    return cv2.imread(str(path), cv2.IMREAD_COLOR)


def rendered_fast(scene: Scene, key: str) -> np.ndarray:
    """The campaign renderer's frame of ``scene`` (random looks), cached like :func:`rendered`."""
    modules = (fast_render, render, raycast, kernels, looks, textures)
    source = b"".join(Path(m.__file__).read_bytes() for m in modules) + repr(scene).encode()
    source += repr(fast_render.TEXTURE_CONTRAST).encode()  # a test may draw the frames as they were (conftest)
    name = f"fast-{key.replace('/', '-')}-{hashlib.sha1(source).hexdigest()[:12]}.png"
    path = Path(tempfile.gettempdir()) / "agf-renders" / name
    if not path.exists():
        _cache(path, fast_render.render_fast(scene)[0])
    return cv2.imread(str(path), cv2.IMREAD_COLOR)


def _cache(path: Path, image: np.ndarray) -> None:
    """Write ``image`` to the render cache at ``path`` whole: written beside it and renamed, since another process
    (an `agf bench` beside a test run) may read the same frame while it is written (libpng: "Read Error")."""
    path.parent.mkdir(parents=True, exist_ok=True)
    part = path.with_name(f"{path.stem}.{os.getpid()}.part.png")
    cv2.imwrite(str(part), image)
    os.replace(part, path)


def _keys(quick: bool) -> list[str]:
    if quick:
        return list(QUICK)
    return [
        f"{p.parent.name}/{p.stem}"
        for d in ("paper", "robust")
        for p in sorted((SCENES / d).glob("*.yaml"))
        if "shared/data" not in p.read_text() or repo_path("../shared/data").is_dir()
    ]


@bench_case("render.frame_s", "vision_ms")
def render_frame(quick: bool) -> dict[str, Any]:
    """Campaign frames, 1920 x 1920: the fast renderer on random looks of a paper scene, pinned to one
    core, its camera's rays already cached (budget 0.5 s); also as CPU seconds (a shared machine's load
    stretches wall time), the first frame of a camera (rays computed, s) and the reference renderer
    (4 rays per pixel, fixed look, all cores)."""
    scene = load_scene(SCENES / "paper/loaded-low-flat.yaml")
    camera = load_camera(scene.camera)
    cold = time.perf_counter()
    fast_render.render_fast(dataclasses.replace(scene, look="random"), camera)  # rays, compiled kernels
    cold = time.perf_counter() - cold
    seeds = iter(range(1, 100))
    cores = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(cores)})
    try:
        frames, cpu = [], []
        for _ in range(2 if quick else 8):
            frame = dataclasses.replace(scene, look="random", seed=next(seeds))
            start, start_cpu = time.perf_counter(), time.process_time()
            fast_render.render_fast(frame, camera)
            frames.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)
    finally:
        os.sched_setaffinity(0, cores)
    reference = time_calls(lambda: render.render(scene, camera), repeats=1 if quick else 2, warmup=0)
    return {
        **timing_summary(frames, scale=1.0),
        "cpu_s": timing_summary(cpu, scale=1.0),
        "first_frame_s": cold,
        "reference": timing_summary(reference, scale=1.0),
    }


@bench_case("pose.ms", "vision_ms")
def pose_ms(quick: bool) -> dict[str, Any]:
    """Pallet pose with a prior (+-300 mm, +-10 deg approach knowledge), 1920 x 1920 (budget 100 ms)."""
    config = load_config(DEFAULT_CONFIG)
    scene = load_scene(SCENES / "paper/unloaded-middle-flat.yaml")
    image = rendered(scene, "paper/unloaded-middle-flat")
    camera = load_camera(scene.camera)
    face = face_model_from_pallet(load_pallets(config.vision.pallets)[scene.pallet.type])
    truth = scene.pallet.in_fork
    # A new prior for every call, as every approach brings: the same one again would time cached maps.
    offsets = iter(np.random.default_rng(0).uniform(-1, 1, (12, 4)) * [0.1, 0.08, 0.06, 0.05])
    samples = time_calls(
        lambda: estimate_pallet_pose(
            image, camera, scene.camera_in_fork, face, config.vision.search, prior=_prior(truth, next(offsets)),
            forks=config.forks,
        ),
        repeats=3 if quick else 10,
    )
    return timing_summary(samples)


def _prior(truth: Transform, offset: np.ndarray) -> Transform:
    """``truth`` moved by ``offset`` (x, y, z in m, yaw in rad)."""
    return Transform.from_euler(*(truth.translation + offset[:3]), 0.0, truth.euler[1], truth.euler[0] + offset[3])


@bench_case("measure", "accuracy")
def measure_accuracy(quick: bool) -> dict[str, Any]:
    """Pose and pitch on the paper and robustness scenes: errors, detection rate, wrong accepts, timing."""
    keys = _keys(quick)
    return measure_scenes([(key, load_scene(SCENES / f"{key}.yaml")) for key in keys], rendered).summary()


# Random looks per paper scene: 18 x 4 = 72 scenes (the issue asks at least 30 with the paper's geometry). Two
# looks each (36 scenes) showed no wrong accept while looks 2-7 of the loaded scenes showed five: a sample of
# 36 is too small for a rate that should be zero.
RANDOM_LOOKS = 4


@bench_case("randomised", "accuracy")
def randomised_accuracy(quick: bool) -> dict[str, Any]:
    """Pose and pitch on the paper's 18 geometries, each under random looks (textures, lights, sensor
    drawn from a seed of its own; campaign renderer): a detector tuned to one look fails here."""
    scenes = []
    for path in sorted((SCENES / "paper").glob("*.yaml"))[: 3 if quick else None]:
        base = load_scene(path)
        for k in range(1 if quick else RANDOM_LOOKS):
            key = f"paper/{path.stem}/look-{k}"
            scenes.append((key, dataclasses.replace(base, look="random", seed=base.seed * 100 + k + 1)))
    return measure_scenes(scenes, rendered_fast, shorter_exposures=True).summary()


# The catalogue's pallets on the paper's geometries, all three under the same random look per geometry (a look
# the randomised case does not draw), so that what differs between them is the pallet: the paper's own (JIS T11,
# the vision's tuning) beside the EUR and GMA stringer pallets.
PALLET_TYPES = ("jis-t11", "epal", "gma-48x40")


@bench_case("pallet_types", "accuracy")
def pallet_types_accuracy(quick: bool) -> dict[str, Any]:
    """Pose and pitch on the paper's 18 geometries with each pallet of the catalogue (a load 50 mm inside the
    pallet's sides) under one random look per geometry, counted per pallet type (``by_pallet_type``)."""
    from drivers.sim.world import load_footprint  # the world's CANopen stack only when this case runs

    scenes = []
    for path in sorted((SCENES / "paper").glob("*.yaml"))[: 2 if quick else None]:
        base = load_scene(path)
        for kind in PALLET_TYPES:
            load = base.load and Load((*load_footprint(kind), base.load.size[2]))
            scene = dataclasses.replace(base, pallet=PalletPlacement(kind, base.pallet.in_fork), load=load,
                                        look="random", seed=base.seed * 100 + RANDOM_LOOKS + 1)
            scenes.append((f"paper/{path.stem}/{kind}", scene))
    tally = measure_scenes(scenes, rendered_fast, shorter_exposures=True)
    return {**tally.summary(), "by_pallet_type": {kind: _count_of(tally, kind) for kind in PALLET_TYPES}}


def _count_of(tally: AccuracyTally, kind: str) -> dict[str, int]:
    """The frames of pallet ``kind`` (named ``.../<kind>``) in :func:`pallet_types_accuracy`'s ``tally``, by verdict."""
    verdicts = [verdict for name, _, verdict in tally.rows if name.endswith(f"/{kind}")]
    return {"scenes": len(verdicts), "within_bounds": verdicts.count("within bounds"),
            "refused": sum(v.startswith("refused") for v in verdicts), "wrong_accepts": verdicts.count("WRONG ACCEPT")}


CAMPAIGN_SEED = 7
CAMPAIGN_PICKS = 40


@bench_case("campaign", "accuracy")
def campaign_accuracy(quick: bool) -> dict[str, Any]:
    """The first frames of the picks of ``agf simulate --random N --seed 7``: random geometry (pitch +-5 deg,
    heights, stand-off, yaw, loads, neighbours) under random looks, as the simulated world renders them. The
    paper's 18 geometries under random looks did not show a face accepted 45 mm too far (pick 29)."""
    from drivers.sim.world import campaign_scene  # the world's CANopen stack only when this case runs

    base = load_scene(repo_path("configs/scenes/pick.yaml"))
    picks = range(4 if quick else CAMPAIGN_PICKS)
    scenes = [(f"seed-{CAMPAIGN_SEED}/pick-{k}", campaign_scene(base, CAMPAIGN_SEED, k)) for k in picks]
    return measure_scenes(scenes, rendered_fast, shorter_exposures=True).summary()


def measure_scenes(scenes: list[tuple[str, Scene]], frame: Any, shorter_exposures: bool = False) -> AccuracyTally:
    """Measure each scene's frame; ``shorter_exposures``: a frame refused as overexposed is taken again with the
    shorter exposures a pick's controller asks the simulated camera for (random looks draw their exposure)."""
    config = load_config(DEFAULT_CONFIG)
    catalogue = load_pallets(config.vision.pallets)
    tally = AccuracyTally()
    for key, scene in scenes:
        pallet = catalogue[scene.pallet.type]
        camera = load_camera(scene.camera)
        shorter = shorter_exposure_frames(scene, key, frame) if shorter_exposures else ()
        tally.measure(
            key, frame(scene, key), camera, scene.camera_in_fork, pallet, config.vision.search, config.forks,
            scene.pallet.in_fork, scene.loaded, shorter,
        )
    return tally


def shorter_exposure_frames(scene: Scene, key: str, frame: Any) -> Iterator[np.ndarray]:
    """The frames (``frame(scene, key)``, drawn as they are asked for) of ``scene`` with the ever shorter exposures a
    pick's controller asks the simulated camera for after an overexposed frame."""
    controller = ControllerConfig()
    for k in range(controller.exposures):
        scale = controller.exposure_step ** (k + 1)
        yield frame(exposed(scene, scale), f"{key}/exposure-{scale:.3f}")


@bench_case("calibrate", "accuracy")
def calibrate_accuracy(quick: bool) -> dict[str, Any]:
    """Panel calibration with mount errors up to 20 mm / 3 deg: worst errors, and the shift-free bias."""
    config = load_config(DEFAULT_CONFIG)
    nominal = load_calibration(config.vision.calibration)
    base = load_scene(SCENES / "panel.yaml")
    camera = load_camera(base.camera)
    panel = Panel(*base.panel.size, base.panel.thickness)
    mm, deg, bias, ms = [], [], [], []
    for seed in range(2 if quick else 6):
        d = np.random.default_rng(seed).uniform(-1, 1, 6) * np.r_[0.02, 0.02, 0.02, np.radians([3, 3, 3])]
        truth = Transform.from_euler(*(nominal.translation + d[:3]), d[3], d[4], d[5])
        scene = dataclasses.replace(base, camera_in_fork=truth, seed=seed)
        image = rendered(scene, f"panel-{seed}")
        start = time.perf_counter()
        fit = fit_panel(image, camera, panel, config.forks, nominal)
        ms.append((time.perf_counter() - start) * 1e3)
        naive = fit_panel(
            image, camera.without_viewpoint_shift(), panel, config.forks, fit.camera_in_fork, WITHOUT_SHIFT
        )
        e, t = fit.camera_in_fork.to_dict(), truth.to_dict()
        mm.append(max(abs(e[k] - t[k]) for k in ("x_mm", "y_mm", "z_mm")))
        deg.append(max(abs(e[k] - t[k]) for k in ("roll_deg", "pitch_deg", "yaw_deg")))
        bias.append(naive.camera_in_fork.to_dict()["z_mm"] - t["z_mm"])
    return {
        "mounts": len(mm),
        "max_error_mm": max(mm),
        "max_error_deg": max(deg),
        "without_shift_z_bias_mm": statistics.median(bias),
        "calibrate_ms": timing_summary([m / 1e3 for m in ms]),
    }
