"""The simulated camera: fisheye frames of a scene file, with exact ground truth (``agf render``).

Geometry comes from the scene file and the pallet catalogue (frame P, DESIGN.md); every pixel's
four sub-samples (a rotated grid) are rays through the camera model, viewpoint shift included, cast
against boxes and planes (:mod:`drivers.sim.raycast`). Shading: diffuse light from two lamps and an
ambient term, darkened inside pallet pockets (ambient occlusion: pockets are dark holes),
procedural wood grain, cardboard with tape seams, concrete, vignetting; then blur, sensor noise and
JPEG. Everything random comes from the scene's seed, so a scene renders bit-identically.

A scene with ``look: random`` gets a look drawn from its seed instead (:mod:`drivers.sim.looks`):
textures, lights with hard shadows, rack and clutter, sensor; shaded by compiled code
(:mod:`drivers.sim.kernels`) that the campaign renderer (:mod:`drivers.sim.fast_render`) shares. This
module is the reference that renderer is checked against.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from agf.camera import CameraModel, load_camera
from agf.config import ForkGeometry
from agf.frames import JpegImage, pixels_sent
from agf.geometry import Transform
from agf.pallets import PalletType, load_pallets, pallet_type
from agf.paths import repo_path
from agf.scene import Scene, load_scene
from drivers.sim.kernels import add_shot_noise, nonzero_spans, pack_lights, pack_objects, shade_look
from drivers.sim.looks import CameraLight, Look, draw_look
from drivers.sim.raycast import Box, Plane, cast, screen_rectangles

Array = NDArray[np.float64]
CATALOGUE = repo_path("configs/pallets.yaml")
BAND_ROWS = 48
GAMMA_ROWS = 8  # image rows the gamma spans at once (the field of view's outline bounds their columns)
NOISE_ROWS = 64  # image rows a random look's sensor draws noise for at once (the rest of the work in cache)
SKY = 0.62  # albedo-like brightness of rays that hit nothing (a bright hall)
VIGNETTING = 0.35  # brightness lost at the edge of the field of view (fixed look)

# material -> (albedo, BGR tint)
MATERIALS = {
    "wood": (0.66, (0.78, 0.93, 1.0)),
    "carton": (0.52, (0.62, 0.82, 1.0)),
    "tape": (0.30, (0.55, 0.75, 0.9)),
    "concrete": (0.42, (1.0, 1.0, 1.0)),
    "truck-bed": (0.22, (0.9, 0.95, 1.0)),
    "steel": (0.16, (1.0, 1.0, 1.0)),
    "wall": (0.62, (0.95, 0.97, 1.0)),
    "upright": (0.30, (1.0, 0.55, 0.35)),
    "panel": (0.86, (1.0, 1.0, 1.0)),
}


@dataclass(frozen=True)
class _Pallet:
    """A pallet in the scene: its type and pose in the camera frame."""

    kind: PalletType
    in_camera: Transform


def render(
    scene: Scene,
    camera: CameraModel | None = None,
    forks: ForkGeometry | None = None,
    samples: int = 4,
    shading: Literal["photo", "geometry"] = "photo",
) -> tuple[NDArray[np.uint8], dict[str, Any]]:
    """A BGR fisheye frame of ``scene`` and its ground truth (see :func:`truth`).

    ``shading="geometry"`` paints pallet front faces bright and everything else dark, with no texture,
    light, noise or blur: a check of where the geometry lands, free of photometric effects.
    """
    camera = camera or load_camera(scene.camera)
    forks = forks or ForkGeometry()
    rng = np.random.default_rng(scene.seed)
    look = draw_look(scene) if scene.look == "random" else None
    objects, pallets = build_objects(scene, forks, rng, look)
    offsets = _subpixel_offsets(samples)
    if shading == "geometry":
        image = _trace(camera, objects, pallets, offsets, 1.0, _shade_geometry, None)
        return np.clip(np.round(image), 0, 255).astype(np.uint8), truth(scene, camera)
    if look is None:
        shade = functools.partial(_shade, lights=_lights(objects))
        image = _trace(camera, objects, pallets, offsets, scene.environment.light, shade, VIGNETTING)
        return pixels_sent(_sensor(image, scene, rng)), truth(scene, camera)
    shade = functools.partial(_shade_look, look_arrays(look, look.camera_lights(scene), objects, pallets))
    image = _trace(camera, objects, pallets, offsets, scene.environment.light * look.exposure, shade, look.vignetting)
    return pixels_sent(_sensor_look(image, look, rng)), truth(scene, camera)


def exposed(scene: Scene, scale: float) -> Scene:
    """``scene`` as a camera sees it with its exposure scaled by ``scale``: the scene's light scaled, to 0.05 at
    least (an Environment holds no less: a dimmer one is not a scene the renderer draws differently)."""
    light = max(scene.environment.light * scale, 0.05)
    return dataclasses.replace(scene, environment=dataclasses.replace(scene.environment, light=light))


def truth(scene: Scene, camera: CameraModel) -> dict[str, Any]:
    """Ground truth: poses (mm, deg), loaded, and pocket-corner pixels of the target pallet."""
    fork_in_camera = scene.camera_in_fork.inverse()
    out: dict[str, Any] = {"loaded": scene.loaded, "camera_in_fork": scene.camera_in_fork.to_dict()}
    if scene.pallet is None:
        return out
    kind = catalogued(scene.pallet.type)
    in_camera = fork_in_camera @ scene.pallet.in_fork
    half = kind.pocket_height / 2
    corners = np.array(
        [[0.0, y, z] for y0, y1 in kind.pockets() for y, z in ((y1, half), (y0, half), (y0, -half), (y1, -half))]
    )
    pixels, valid = camera.project(in_camera.apply(corners))
    out.update(
        pallet_type=kind.name,
        pallet_in_fork=scene.pallet.in_fork.to_dict(),
        pallet_in_camera=in_camera.to_dict(),
        pocket_corners_px=[
            [list(map(float, p)) if v else None for p, v in zip(pixels[i : i + 4], valid[i : i + 4], strict=True)]
            for i in range(0, len(pixels), 4)
        ],
    )
    return out


def catalogued(name: str) -> PalletType:
    """The pallet type ``name`` of the catalogue (:data:`CATALOGUE`), read once per version of the file
    (parsing it took 0.03 s, three times a frame)."""
    return pallet_type(_catalogue(CATALOGUE.stat().st_mtime_ns), name)


@functools.lru_cache(maxsize=1)
def _catalogue(version: int) -> dict[str, PalletType]:
    return load_pallets(CATALOGUE)


def render_command(
    scene_path: Path, out_png: Path, truth_json: Path, randomize: bool = False, reference: bool = False
) -> dict[str, Any]:
    """``agf render SCENE --out PNG --truth JSON [--randomize] [--reference]``: the campaign renderer
    (:mod:`drivers.sim.fast_render`) unless ``reference``."""
    from drivers.sim.fast_render import render_fast  # it builds on this module

    scene = load_scene(scene_path)
    if randomize:
        scene = dataclasses.replace(scene, look="random")
    image, gt = render(scene) if reference else render_fast(scene)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out_png), image):
        raise OSError(f"{out_png}: could not write the image")
    truth_json.write_text(json.dumps(gt, indent=2) + "\n")
    return {"ok": True, "image": str(out_png), "truth": str(truth_json), **gt}


# -- scene geometry -------------------------------------------------------------------------------


def build_objects(
    scene: Scene, forks: ForkGeometry, rng: np.random.Generator, look: Look | None = None
) -> tuple[list, list[_Pallet]]:
    """Boxes and planes of the scene in the camera frame, and the pallets (for pocket shading); a random
    ``look`` adds its rack, clutter and where the support ends."""
    fork_in_camera = scene.camera_in_fork.inverse()
    objects: list[Box | Plane] = []
    pallets: list[_Pallet] = []
    objects += _forks(fork_in_camera, forks)
    if scene.panel is not None:
        width, depth = scene.panel.size
        top = forks.thickness / 2 + scene.panel.thickness
        objects.append(
            _box(fork_in_camera, (-depth, 0.0), (-width / 2, width / 2), (forks.thickness / 2, top), "panel")
        )
        objects.append(_floor(fork_in_camera @ Transform.from_euler(z=-0.35), "concrete"))
        return objects, pallets
    kind = catalogued(scene.pallet.type)
    target = fork_in_camera @ scene.pallet.in_fork
    spacing = kind.width + rng.uniform(0.15, 0.3)
    sides = [0.0] + [s * spacing for s in (1, -1)][: scene.environment.neighbours]
    for i, side in enumerate(sides):
        in_camera = target @ Transform.from_euler(y=side)
        pallets.append(_Pallet(kind, in_camera))
        objects += _pallet_boxes(in_camera, kind, f"pallet{i}")
        if scene.load is not None:
            objects += _load(in_camera, kind, scene.load.size)
    objects += _support(scene, kind, target, fork_in_camera, forks, look)
    objects += _background(scene, kind, fork_in_camera, rng, look)
    if look is not None:
        objects += _look_extras(scene, kind, target, fork_in_camera, look, spacing)
    return objects, pallets


def _box(frame: Transform, x: tuple, y: tuple, z: tuple, material: str, name: str = "") -> Box:
    low, high = np.array([x[0], y[0], z[0]]), np.array([x[1], y[1], z[1]])
    return Box(frame @ Transform(translation=(low + high) / 2), (high - low) / 2, material, name)


def _floor(frame: Transform, material: str) -> Plane:
    return Plane(frame, material, "floor")


def _forks(fork_in_camera: Transform, forks: ForkGeometry) -> list[Box]:
    half_t = forks.thickness / 2
    tines = [
        _box(
            fork_in_camera,
            (-forks.length, 0.0),
            (s * forks.spacing / 2 - forks.width / 2, s * forks.spacing / 2 + forks.width / 2),
            (-half_t, half_t),
            "steel",
            "fork",
        )
        for s in (-1, 1)
    ]
    backrest = _box(
        fork_in_camera, (-forks.length - 0.06, -forks.length), (-0.55, 0.55), (-half_t, 1.2), "steel", "backrest"
    )
    return [*tines, backrest]


def _pallet_boxes(in_camera: Transform, kind: PalletType, name: str) -> list[Box]:
    half = kind.pocket_height / 2
    boxes = [
        _box(
            in_camera,
            (0.0, kind.length),
            (-kind.width / 2, kind.width / 2),
            (half, kind.deck_top),
            "wood",
            f"{name}.top",
        )
    ]
    if kind.bottom > 0:
        boxes.append(
            _box(
                in_camera,
                (0.0, kind.length),
                (-kind.width / 2, kind.width / 2),
                (kind.deck_bottom, -half),
                "wood",
                f"{name}.bottom",
            )
        )
    for j, block in enumerate(kind.blocks):
        depth = block.depth if block.depth is not None else kind.length
        boxes.append(
            _box(
                in_camera,
                (0.0, depth),
                (block.y - block.width / 2, block.y + block.width / 2),
                (-half, half),
                "wood",
                f"{name}.block{j}",
            )
        )
    return boxes


def _load(in_camera: Transform, kind: PalletType, size: tuple[float, float, float]) -> list[Box]:
    length, width, height = size
    return [
        _box(
            in_camera, (0.0, length), (-width / 2, width / 2), (kind.deck_top, kind.deck_top + height), "carton", "load"
        )
    ]


def _support(
    scene: Scene, kind: PalletType, target: Transform, fork_in_camera: Transform, forks: ForkGeometry, look: Look | None
) -> list:
    """What the pallet stands on: a slab (truck bed or dock) inclined with the pallet, its rear edge just in
    front of the pallet (a random look moves it, up to just under the pallet), and the level hall floor
    under the forks."""
    bottom = float(scene.pallet.in_fork.apply([0.0, 0.0, kind.deck_bottom])[2])
    hall = min(bottom, -forks.thickness / 2) - 0.03
    material = "truck-bed" if scene.environment.floor == "truck-bed" else ("concrete" if look is None else "dock")
    (front, left, _), (back, right, top) = support_box(kind, look)
    slab = _box(target, (front, back), (left, right), (kind.deck_bottom - (bottom - hall) - 0.5, top), material,
                "support")
    return [slab, _floor(fork_in_camera @ Transform.from_euler(z=hall), "concrete")]


def support_box(kind: PalletType, look: Look | None) -> Array:
    """The slab the pallet stands on (truck bed or dock, :func:`_support`) as a box in frame P: its low and high
    corner (2, 3), m. Its top is the pallet's underside, its front edge 0.12 m before the pallet's face (a random
    look moves it, from 0.35 m before the face to just under the pallet); it reaches 4 m back, 3 m to either
    side and, for the collision count, 2 m down (the rendered slab stands on the hall floor)."""
    front = -0.12 if look is None else look.bed_edge
    return np.array([[front, -3.0, kind.deck_bottom - 2.0], [4.0, 3.0, kind.deck_bottom]])


def _background(
    scene: Scene, kind: PalletType, fork_in_camera: Transform, rng: np.random.Generator, look: Look | None
) -> list:
    """Back wall and rack uprights (vertical lines: the paper's named failure mode)."""
    px, _, pz = scene.pallet.in_fork.translation
    distance = 5.0 if look is None else kind.length + look.wall_distance
    wall = fork_in_camera @ Transform.from_euler(x=px + distance, pitch=-math.pi / 2)
    objects: list[Box | Plane] = [Plane(wall, "wall", "wall")]
    for _ in range(scene.environment.clutter_verticals):
        near = rng.random() < 0.5  # half of them stand right beside the pallet, where load edges are sought
        y = rng.choice([-1, 1]) * (kind.width / 2 + (rng.uniform(0.05, 0.4) if near else rng.uniform(0.4, 2.5)))
        x = px + kind.length + (rng.uniform(0.05, 0.8) if near else rng.uniform(0.2, 3.0))
        objects.append(
            _box(fork_in_camera, (x, x + 0.08), (y - 0.04, y + 0.04), (pz - 1.5, pz + 3.5), "upright", "upright")
        )
    return objects


def _look_extras(
    scene: Scene, kind: PalletType, target: Transform, fork_in_camera: Transform, look: Look, spacing: float
) -> list[Box]:
    """A random look's rack bay behind the pallet (uprights and beams: long horizontal edges) and its
    clutter on the support (beside the pallet clear of any neighbour, or behind it)."""
    px, py, pz = scene.pallet.in_fork.translation
    boxes = []
    if look.rack:
        x = px + kind.length + look.rack_depth
        for y in (-2.7, 0.0, 2.7):
            for side in (-0.45, 0.45):
                boxes.append(_box(fork_in_camera, (x, x + 0.07), (py + y + side - 0.045, py + y + side + 0.045),
                                  (pz - 1.5, pz + 3.0), "upright", "rack"))
        for height in look.rack:
            boxes.append(_box(fork_in_camera, (x - 0.05, x), (py - 4.0, py + 4.0), (pz + height, pz + height + 0.12),
                              "beam", "beam"))
    beside = {1.0: scene.environment.neighbours >= 1, -1.0: scene.environment.neighbours >= 2}
    for item in look.clutter:
        side = math.copysign(1.0, item.y[0])
        shift = side * spacing if item.x[0] < kind.length and beside[side] else 0.0
        boxes.append(_box(target, item.x, (item.y[0] + shift, item.y[1] + shift),
                          (kind.deck_bottom, kind.deck_bottom + item.height), item.role, "clutter"))
    return boxes


# -- tracing and shading --------------------------------------------------------------------------


def _subpixel_offsets(samples: int) -> Array:
    """Sub-pixel sample offsets (samples, 2) with mean zero, so edges are not shifted: the rotated-grid
    pattern for 4 samples (good on near-horizontal and near-vertical edges alike), a regular grid else."""
    if samples == 4:
        return np.array([[-0.125, -0.375], [0.375, -0.125], [0.125, 0.375], [-0.375, 0.125]])
    side = max(int(round(math.sqrt(samples))), 1)
    return (np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2) + 0.5) / side - 0.5


def _trace(
    camera: CameraModel,
    objects: list,
    pallets: list[_Pallet],
    offsets: Array,
    light: float,
    shade: Callable,
    vignetting: float | None,
) -> Array:
    """Every pixel's colour: the mean over all its sub-sample rays, band by band on one thread per core
    (the array work that dominates releases the GIL). ``vignetting``: brightness lost at the edge of the
    field of view (None: none)."""
    image = np.zeros((camera.height, camera.width, 3))
    rects = screen_rectangles(camera, objects)

    def band(rows: slice, pixels: Array, where: NDArray[np.bool_]) -> None:
        image[rows][where] = _sample(camera, objects, pallets, rects, pixels, offsets, shade, vignetting)

    # One band thread per core this process may use (a simulate job is pinned to one), one BLAS thread
    # per band thread: OpenBLAS's own threads on small products only contend.
    workers = len(os.sched_getaffinity(0))
    with threadpool_limits(1, user_api="blas"), ThreadPoolExecutor(max_workers=workers) as pool:
        for future in [pool.submit(band, *args) for args in _bands(camera)]:
            future.result()
    return image * light


def _bands(camera: CameraModel):
    """(row slice, pixel centres (N, 2) inside the field of view, their mask in the band) per band."""
    us = np.arange(camera.width, dtype=float)
    for row0 in range(0, camera.height, BAND_ROWS):
        rows = slice(row0, min(row0 + BAND_ROWS, camera.height))
        vv, uu = np.meshgrid(np.arange(rows.start, rows.stop, dtype=float), us, indexing="ij")
        centres = np.stack([uu.ravel(), vv.ravel()], 1)
        inside = camera.valid_pixels(centres)
        if inside.any():
            yield rows, centres[inside], inside.reshape(uu.shape)


def _sample(camera, objects, pallets, rects, pixels: Array, offsets: Array, shade, vignetting: float | None) -> Array:
    """Mean colour (N, 3) of pixels over the sub-pixel ``offsets``, vignetting included when given."""
    low, high = pixels.min(axis=0) - 1, pixels.max(axis=0) + 1
    # objects whose rectangle misses these pixels altogether are dropped before any per-ray work
    candidates = [
        i
        for i, r in enumerate(rects)
        if r is None or (r[0] <= high[0] and r[2] >= low[0] and r[1] <= high[1] and r[3] >= low[1])
    ]
    subset = [objects[i] for i in candidates]
    subset_rects = [rects[i] for i in candidates]
    colour = np.zeros((len(pixels), 3))
    for offset in offsets:
        origins, directions = camera.unproject(pixels + offset)
        hits = cast(subset, origins, directions, pixels + offset, subset_rects)
        hits.index = np.where(hits.index >= 0, np.asarray(candidates + [-1])[hits.index], -1).astype(np.int32)
        sample = shade(objects, pallets, hits, origins, directions)
        if vignetting is not None:
            sample *= _vignetting(camera, directions, vignetting)[:, None]
        colour += sample
    return colour / len(offsets)


def _lights(objects: list) -> list[tuple[Array, float]]:
    """Two lamps above the pallet, given in the camera frame (derived from the floor's orientation)."""
    up = next(
        (o.pose.rotation[:, 2] for o in objects if isinstance(o, Plane) and o.name == "floor"),
        np.array([0.0, 0.0, 1.0]),
    )
    forward = np.array([1.0, 0.0, 0.0]) - up * up[0]
    forward /= np.linalg.norm(forward)
    left = np.cross(up, forward)
    first = 0.9 * up - 0.35 * forward + 0.3 * left
    second = 0.8 * up + 0.5 * forward - 0.25 * left
    return [(first / np.linalg.norm(first), 0.6), (second / np.linalg.norm(second), 0.3)]


def _shade(objects, pallets, hits, origins, directions, lights) -> Array:
    """The fixed look: two shadowless lamps and an ambient term, the fixed materials and textures."""
    colour = np.full((len(origins), 3), SKY * 255.0)
    hit = np.isfinite(hits.distance)
    if not hit.any():
        return colour
    idx = hits.index[hit]
    normal = hits.normal[hit]
    points = origins[hit] + hits.distance[hit, None] * directions[hit]
    irradiance = np.full(len(idx), 0.5)
    for direction, power in lights:
        irradiance += power * np.clip(normal @ direction, 0.0, None)
    irradiance *= _pocket_occlusion(points, pallets)
    albedo = np.empty(len(idx))
    tint = np.empty((len(idx), 3))
    local = hits.local[hit]
    order = np.argsort(idx, kind="stable")  # group hits by object in one sort, not one scan per object
    ids, starts = np.unique(idx[order], return_index=True)
    for i, sel in zip(ids, np.split(order, starts[1:]), strict=True):
        obj = objects[i]
        base, tone = MATERIALS[obj.material]
        albedo[sel] = base * _texture(obj, local[sel], i)
        tint[sel] = tone
    colour[hit] = 255.0 * (albedo * irradiance)[:, None] * tint
    return colour


def _shade_geometry(objects, pallets, hits, origins, directions) -> Array:
    """200 on the front faces of pallet parts, 50 everywhere else."""
    colour = np.full((len(origins), 3), 50.0)
    if pallets:
        forward = pallets[0].in_camera.rotation[:, 0]
        is_pallet = np.array([obj.name.startswith("pallet") for obj in objects] + [False])
        front = np.isfinite(hits.distance) & is_pallet[hits.index] & (hits.normal @ forward < -0.99)
        colour[front] = 200.0
    return colour


def _shade_look(packed: tuple, objects, pallets, hits, origins, directions) -> Array:
    """A random look (``packed`` by :func:`look_arrays`): procedural textures, an ambient term and the
    look's lights with hard shadows."""
    colour = np.empty((len(origins), 3))
    shade_look(origins, directions, hits.distance, hits.normal, hits.local, hits.index.astype(np.int64, copy=False),
               *packed, colour)
    return colour


def look_arrays(look: Look, lights: list[CameraLight], objects: list, pallets: list[_Pallet]) -> tuple:
    """The arguments of :func:`drivers.sim.kernels.shade_look` after the hits: objects, lights, pallets."""
    kind, rotation, centre, half, _ = objects_packed = pack_objects(
        objects, [look.style(o.material, i) for i, o in enumerate(objects)]
    )
    packed_pallets = np.array(
        [[*p.in_camera.rotation.ravel(), *p.in_camera.translation, p.kind.length, p.kind.width,
          p.kind.pocket_height, p.kind.deck_bottom] for p in pallets]
    ).reshape(len(pallets), 16)
    return (*objects_packed, *pack_lights(lights, kind, rotation, centre, half), packed_pallets, look.ambient,
            np.asarray(look.sky))


def _pocket_occlusion(points: Array, pallets: list[_Pallet]) -> Array:
    """Ambient occlusion inside pockets: surfaces behind the front face, under the deck, grow dark."""
    factor = np.ones(len(points))
    for pallet in pallets:
        local = (points - pallet.in_camera.translation) @ pallet.in_camera.rotation
        kind = pallet.kind
        inside = (
            (local[:, 0] > 0.002)
            & (local[:, 0] < kind.length)
            & (np.abs(local[:, 1]) < kind.width / 2)
            & (local[:, 2] < kind.pocket_height / 2 - 1e-4)
            & (local[:, 2] > kind.deck_bottom - 0.01)
        )
        factor[inside] *= 0.12 + 0.3 * np.exp(-local[inside, 0] / 0.03)
    return factor


def _texture(obj: Box | Plane, local: Array, index: int) -> Array:
    """Multiplicative albedo variation of a material at local points (N, 3)."""
    phase = (index * 0.618) % 1.0
    if obj.material == "wood":
        along = int(np.argmax(obj.half)) if isinstance(obj, Box) else 0
        a = local[:, along]
        across = np.sum(np.delete(local, along, axis=1), axis=1)
        grain = np.sin(2 * np.pi * (across / 0.0045 + 1.8 * np.sin(2 * np.pi * (a / 0.41 + phase))))
        return 0.94 + 0.12 * phase + 0.05 * grain + 0.03 * np.sin(2 * np.pi * a / 0.13)
    if obj.material == "carton":
        y, z = local[:, 1] + obj.half[1], local[:, 2] + obj.half[2]
        seams = (np.abs(((y + 0.25) % 0.5) - 0.25) > 0.246) | (np.abs(((z + 0.2) % 0.4) - 0.2) > 0.196)
        return np.where(seams, 0.55, 1.0 + 0.03 * np.sin(2 * np.pi * (y / 0.07 + z / 0.11)))
    if obj.material in ("concrete", "truck-bed", "wall"):
        x, y = local[:, 0], local[:, 1]
        value = 0.9 + 0.06 * np.sin(2 * np.pi * x / 0.9) * np.sin(2 * np.pi * y / 0.7)
        if obj.material == "truck-bed":
            value *= np.where(np.abs((y % 0.3) - 0.15) > 0.145, 0.6, 1.0)
        return value
    return np.ones(len(local))


def _vignetting(camera: CameraModel, directions: Array, strength: float) -> Array:
    incidence = np.arccos(np.clip(directions[:, 0], -1.0, 1.0))
    return 1.0 - strength * (incidence / camera.max_incidence) ** 2


def _sensor(image: Array, scene: Scene, rng: np.random.Generator) -> NDArray[np.uint8] | JpegImage:
    noise = scene.noise
    if noise.blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), noise.blur_px)
    if noise.sigma > 0:
        image = image + noise.sigma * rng.standard_normal(image.shape, dtype=np.float32)
    out = np.clip(np.round(image), 0, 255).astype(np.uint8)
    return out if noise.jpeg_quality is None else jpeg_sent(out, noise.jpeg_quality)


def jpeg_sent(pixels: NDArray[np.uint8], quality: int) -> JpegImage:
    """What a camera that compresses at JPEG ``quality`` (1..100) sends of ``pixels``: the JPEG and its decoding."""
    ok, data = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return JpegImage(cv2.imdecode(data, cv2.IMREAD_COLOR), data.tobytes())


def _sensor_look(image: Array, look: Look, rng: np.random.Generator) -> NDArray[np.uint8] | JpegImage:
    """A random look's camera: white balance, then :func:`develop_look`."""
    image = image.astype(np.float32) * white_balance(look)
    return develop_look(np.maximum(image, 0.0, out=image), look, rng)


def white_balance(look: Look) -> NDArray[np.float32]:
    """The gains (3,) a random look's sensor multiplies a float32 image (0..255) by."""
    return (np.asarray(look.white_balance) / 255.0).astype(np.float32)


def develop_look(image: NDArray[np.float32], look: Look, rng: np.random.Generator) -> NDArray[np.uint8] | JpegImage:
    """A random look's camera after the white balance (``image`` (H, W, 3), float32, not negative; it is
    overwritten): gamma, motion blur (vertical: the forks move), optics blur, noise growing with
    brightness (shot noise), 8-bit rounding and JPEG (float32 OpenCV work in place: a frame has 11
    million values). The camera's output: its JPEG where the look compresses, else the pixels."""
    _gamma(image, look.gamma)
    if look.motion_px > 0:
        length = 2 * int(math.ceil(look.motion_px)) + 1
        kernel = np.maximum(0.0, 1.0 - np.abs(np.linspace(-1, 1, length)) * length / (2 * look.motion_px + 1))
        cv2.filter2D(image, -1, (kernel / kernel.sum()).astype(np.float32)[:, None], dst=image)
    if look.blur_px > 0:
        cv2.GaussianBlur(image, (0, 0), look.blur_px, dst=image)
    cv2.setRNGSeed(int(rng.integers(1 << 31)))
    out = np.empty(image.shape, np.uint8)
    noise = np.empty((NOISE_ROWS, *image.shape[1:]), np.float32)
    for top in range(0, len(image), NOISE_ROWS):  # OpenCV's noise stream continues from band to band
        rows = slice(top, min(top + NOISE_ROWS, len(image)))
        band = cv2.randn(noise[: rows.stop - top], 0.0, look.sigma)
        add_shot_noise(image[rows].reshape(-1), band.reshape(-1), out[rows].reshape(-1))
    return out if look.jpeg_quality is None else jpeg_sent(out, look.jpeg_quality)


def _gamma(image: NDArray[np.float32], gamma: float) -> None:
    """255 image ** gamma in place (``image`` not negative, 0..1 but for highlights)."""
    # OpenCV's pow spends 13 ns on a zero (a quarter of a frame lies outside the field of view), 1 on
    # another value, and makes zeros of zeros: it only takes the columns of each band of rows between
    # their first and last non-zero values
    rows = image.reshape(len(image), -1)
    spans = np.empty((-(-len(rows) // GAMMA_ROWS), 2), np.int64)
    nonzero_spans(rows, GAMMA_ROWS, spans)
    for top, (first, stop) in zip(range(0, len(rows), GAMMA_ROWS), spans.tolist(), strict=True):
        band = rows[top : top + GAMMA_ROWS, first:stop]
        cv2.pow(band, gamma, dst=band)
        band *= 255.0
