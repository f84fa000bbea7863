"""The campaign renderer: the reference's scene, look and sensor (:mod:`drivers.sim.render`), traced once
per pixel by compiled code, with the reference's four sub-samples wherever an edge passes.

* Rays: each pixel centre's ray (origin with the viewpoint shift, direction) is computed once per camera
  and kept (:func:`pixel_rays`); a frame only moves the scene.
* Visibility: one compiled ray per pixel centre against the objects whose screen rectangle meets its
  32 x 32 pixel tile (:func:`drivers.sim.kernels.cast_tiled`).
* Edges: a pixel whose centre hit differs (object or face) from one of its 8 neighbours' gets the
  reference's rotated-grid sub-samples, their rays interpolated bilinearly between pixel-centre rays
  (the lens mapping is smooth: the interpolation error is far below 0.01 px). So object outlines, the
  geometry the vision measures, are anti-aliased exactly as by the reference.
* Shading: the same shaders as the reference (the randomised look's is compiled), per sample. Inside
  the region the vision reads (the target pallet and its load, with a margin) every pixel is shaded;
  outside it, a 2 x 2 pixel block that shows one face of one object is shaded once (its texture is
  coarser there; its outline is not, edges are sub-sampled everywhere).

Measured against the reference (tests/integration/test_render.py): pocket corners within 0.05 px of
the reference's, grey levels 0.6 (fixed look) and 1.1-1.7 (random looks) apart on average.
"""

from __future__ import annotations

import functools
import hashlib
import pickle
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numba import njit
from numpy.typing import NDArray

from agf.camera import CameraModel, load_camera
from agf.config import ForkGeometry
from agf.scene import Scene
from drivers.sim import render as reference
from drivers.sim.kernels import cast_tiled, pack_objects, tile_lists
from drivers.sim.looks import draw_look
from drivers.sim.raycast import Hits, screen_rectangles

Array = NDArray[np.float64]
TILE = 32  # px


@dataclass(frozen=True)
class PixelRays:
    """Rays of the pixel centres inside the field of view of one camera (float32)."""

    index: NDArray[np.int32]  # (H, W): row in the arrays below, -1 outside the field of view
    origins: NDArray[np.float32]  # (N, 3), m
    directions: NDArray[np.float32]  # (N, 3), unit
    tile: NDArray[np.int64]  # (N,): the 32 x 32 tile of each pixel, row by row
    incidence: NDArray[np.float32]  # (N,), rad
    flat: NDArray[np.int64]  # (N,): each ray's pixel in the flattened image (row-major)


def pixel_rays(camera: CameraModel) -> PixelRays:
    """The camera's pixel-centre rays, computed once per distinct camera model in a process."""
    return _pixel_rays(hashlib.sha1(pickle.dumps(camera)).hexdigest(), camera)


@functools.lru_cache(maxsize=2)
def _pixel_rays(key: str, camera: CameraModel) -> PixelRays:
    vv, uu = np.mgrid[0 : camera.height, 0 : camera.width]
    centres = np.stack([uu.ravel(), vv.ravel()], 1).astype(float)
    inside = camera.valid_pixels(centres)
    origins, directions = camera.unproject(centres[inside])
    index = np.full(camera.height * camera.width, -1, np.int32)
    index[inside] = np.arange(int(inside.sum()), dtype=np.int32)
    ntx = -(-camera.width // TILE)
    tile = (vv.ravel()[inside] // TILE) * ntx + uu.ravel()[inside] // TILE
    incidence = np.arccos(np.clip(directions[:, 0], -1.0, 1.0))
    return PixelRays(
        index.reshape(camera.height, camera.width),
        origins.astype(np.float32),
        directions.astype(np.float32),
        tile.astype(np.int64),
        incidence.astype(np.float32),
        np.flatnonzero(inside),
    )


def render_fast(
    scene: Scene,
    camera: CameraModel | None = None,
    forks: ForkGeometry | None = None,
    shading: Literal["photo", "geometry"] = "photo",
) -> tuple[NDArray[np.uint8], dict[str, Any]]:
    """The frame :func:`drivers.sim.render.render` draws, at a fraction of its cost (see the module)."""
    camera = camera or load_camera(scene.camera)
    forks = forks or ForkGeometry()
    rng = np.random.default_rng(scene.seed)
    look = draw_look(scene) if scene.look == "random" else None
    objects, pallets = reference.build_objects(scene, forks, rng, look)
    rays = pixel_rays(camera)
    packed = pack_objects(objects)
    start, objs = tile_lists(screen_rectangles(camera, objects), camera.width, camera.height, TILE)
    centre, face = _cast(rays.origins, rays.directions, rays.tile, start, objs, packed)
    edge_pixels = _edge_pixels(rays.index, centre.index.astype(np.int64) * 8 + face)
    sub_o, sub_d = _sub_rays(edge_pixels, reference._subpixel_offsets(4), rays)
    ntx = -(-camera.width // TILE)
    sub_tile = np.repeat((edge_pixels[:, 1] // TILE) * ntx + edge_pixels[:, 0] // TILE, 4)
    sub, _ = _cast(sub_o, sub_d, sub_tile, start, objs, packed)
    if shading == "geometry":
        shade, light, vignetting = reference._shade_geometry, 1.0, None
    elif look is None:
        shade = functools.partial(reference._shade, lights=reference._lights(objects))
        light, vignetting = scene.environment.light, reference.VIGNETTING
    else:
        arrays = reference.look_arrays(look, look.camera_lights(scene), objects, pallets)
        shade = functools.partial(reference._shade_look, arrays)
        light, vignetting = scene.environment.light * look.exposure, look.vignetting
    source = np.empty(len(rays.origins), np.int64)
    _plan(rays.index, centre.index.astype(np.int64) * 8 + face, _region(scene, camera, forks), source)
    shaded = np.flatnonzero(source == np.arange(len(source)))
    at = np.zeros(len(source), np.int64)
    at[shaded] = np.arange(len(shaded))
    subset = Hits(centre.distance[shaded], centre.index[shaded], centre.normal[shaded], centre.local[shaded])
    colour = shade(objects, pallets, subset, rays.origins[shaded].astype(float),
                   rays.directions[shaded].astype(float))[at[source]]
    sub_colour = shade(objects, pallets, sub, sub_o, sub_d).reshape(-1, 4, 3).mean(axis=1)
    colour[rays.index[edge_pixels[:, 1], edge_pixels[:, 0]]] = sub_colour
    if vignetting is not None:
        colour *= (1.0 - vignetting * (rays.incidence / camera.max_incidence) ** 2)[:, None]
    image = np.zeros((camera.height * camera.width, 3))
    image[rays.flat] = colour * light
    image = image.reshape(camera.height, camera.width, 3)
    if shading == "geometry":
        image = np.clip(np.round(image), 0, 255).astype(np.uint8)
    elif look is None:
        image = reference._sensor(image, scene, rng)
    else:
        image = reference._sensor_look(image, look, rng)
    return image, reference.truth(scene, camera)


def _region(scene: Scene, camera: CameraModel, forks: ForkGeometry) -> NDArray[np.int64]:
    """The image rectangle (u0, v0, u1, v1) the vision reads: the target pallet and its load, with a
    margin of a quarter of their size and 64 px (everything for a calibration scene, or when they
    reach behind the lens)."""
    if scene.pallet is None:
        return np.array([0, 0, camera.width, camera.height])
    kind = reference.pallet_type(reference.load_pallets(reference.CATALOGUE), scene.pallet.type)
    top = kind.deck_top + (scene.load.size[2] if scene.load is not None else 0.0)
    target = scene.camera_in_fork.inverse() @ scene.pallet.in_fork
    width = max(kind.width, scene.load.size[1] if scene.load is not None else 0.0)
    outline = reference._box(target, (0.0, kind.length), (-width / 2, width / 2), (kind.deck_bottom, top), "wood")
    (rect,) = screen_rectangles(camera, [outline])
    if rect is None:
        return np.array([0, 0, camera.width, camera.height])
    margin = 0.25 * (rect[2:] - rect[:2]) + 64
    return np.r_[rect[:2] - margin, rect[2:] + margin].astype(np.int64)


@njit(cache=True)
def _plan(index, key, region, source):  # pragma: no cover - compiled
    """For each ray the ray whose colour it takes: itself inside ``region`` and wherever its 2 x 2 pixel
    block is not all one object face; else its block's top-left pixel (the same face: the texture,
    not the geometry, is shared)."""
    h, w = index.shape
    for v in range(h):
        for u in range(w):
            i = index[v, u]
            if i < 0:
                continue
            source[i] = i
            if region[0] <= u <= region[2] and region[1] <= v <= region[3]:
                continue
            u0, v0 = u - u % 2, v - v % 2
            if u0 + 1 >= w or v0 + 1 >= h:
                continue
            a, b, c, d = index[v0, u0], index[v0, u0 + 1], index[v0 + 1, u0], index[v0 + 1, u0 + 1]
            if a >= 0 and b >= 0 and c >= 0 and d >= 0 and key[a] == key[b] == key[c] == key[d]:
                source[i] = a


def _cast(origins, directions, tile, start, objs, packed) -> tuple[Hits, NDArray[np.int8]]:
    n = len(origins)
    distance, index, face = np.empty(n), np.empty(n, np.int32), np.empty(n, np.int8)
    local, normal = np.zeros((n, 3)), np.zeros((n, 3))
    kind, rotation, centre, half, _ = packed
    cast_tiled(origins, directions, tile, start, objs, kind, rotation, centre, half, distance, index, face, local,
               normal)
    return Hits(distance, index, normal, local), face


def _edge_pixels(index: NDArray[np.int32], hit_key: NDArray[np.int64]) -> NDArray[np.int64]:
    """(E, 2) (u, v) of the pixels whose centre's hit key (object and face, (N,)) differs from one of
    its 8 neighbours' (outside the field of view counts as a key of its own)."""
    key = np.full(index.shape, -2, np.int64)
    inside = index >= 0
    key[inside] = hit_key[index[inside]]
    edge = np.zeros(index.shape, bool)
    padded = np.pad(key, 1, mode="edge")
    h, w = index.shape
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            if du or dv:
                edge |= padded[1 + dv : 1 + dv + h, 1 + du : 1 + du + w] != key
    v, u = np.nonzero(edge & inside)
    return np.stack([u, v], 1)


def _sub_rays(pixels: NDArray, offsets: Array, rays: PixelRays) -> tuple[Array, Array]:
    """Origins and directions (E * S, 3) of each pixel's sub-samples, pixel by pixel."""
    n = len(pixels) * len(offsets)
    origins, directions = np.empty((n, 3)), np.empty((n, 3))
    _interpolate_rays(pixels.astype(np.int64), offsets, rays.index, rays.origins, rays.directions, origins, directions)
    return origins, directions


@njit(cache=True)
def _interpolate_rays(pixels, offsets, index, grid_o, grid_d, origins, directions):  # pragma: no cover - compiled
    """Bilinear interpolation of the pixel-centre rays at each pixel's sub-sample positions; where a
    neighbour lies outside the field of view, the centre's ray."""
    h, w = index.shape
    s = offsets.shape[0]
    for e in range(pixels.shape[0]):
        u, v = pixels[e, 0], pixels[e, 1]
        for k in range(s):
            x, y = u + offsets[k, 0], v + offsets[k, 1]
            x0, y0 = int(np.floor(x)), int(np.floor(y))
            fx, fy = x - x0, y - y0
            row = e * s + k
            ok = x0 >= 0 and y0 >= 0 and x0 + 1 < w and y0 + 1 < h
            if ok:
                ok = (index[y0, x0] >= 0 and index[y0, x0 + 1] >= 0 and index[y0 + 1, x0] >= 0
                      and index[y0 + 1, x0 + 1] >= 0)  # fmt: skip
            if not ok:
                c = index[v, u]
                for a in range(3):
                    origins[row, a], directions[row, a] = grid_o[c, a], grid_d[c, a]
                continue
            i00, i10, i01, i11 = index[y0, x0], index[y0, x0 + 1], index[y0 + 1, x0], index[y0 + 1, x0 + 1]
            w00, w10, w01, w11 = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
            norm = 0.0
            for a in range(3):
                origins[row, a] = (w00 * grid_o[i00, a] + w10 * grid_o[i10, a] + w01 * grid_o[i01, a]
                                   + w11 * grid_o[i11, a])  # fmt: skip
                d = w00 * grid_d[i00, a] + w10 * grid_d[i10, a] + w01 * grid_d[i01, a] + w11 * grid_d[i11, a]
                directions[row, a] = d
                norm += d * d
            norm = np.sqrt(norm)
            for a in range(3):
                directions[row, a] /= norm
