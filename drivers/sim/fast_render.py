"""The campaign renderer: the reference's scene, look and sensor (:mod:`drivers.sim.render`), traced once
per pixel by compiled code, with the reference's four sub-samples wherever an edge passes.

* Rays: each pixel centre's ray (origin with the viewpoint shift, direction) is computed once per camera
  and kept (:func:`pixel_rays`), with a cone around the rays of each 32 x 32 pixel tile; a frame only
  moves the scene.
* Visibility: one compiled ray per pixel centre against the objects that can show in its tile (screen
  rectangle and cone of directions, :func:`_tile_lists`), nearest first until none can be hit nearer
  (:func:`drivers.sim.kernels.cast_tiled`): the hits of trying every object in order.
* Edges: a pixel whose centre hit differs (object or face) from one of its 8 neighbours' gets the
  reference's rotated-grid sub-samples, their rays interpolated bilinearly between pixel-centre rays
  (the lens mapping is smooth: the interpolation error is far below 0.01 px). So object outlines, the
  geometry the vision measures, are anti-aliased exactly as by the reference.
* Texture steps: inside the region the vision reads, a pixel whose shaded centre differs from a neighbour's by
  more than :data:`TEXTURE_CONTRAST` (carton joints, tape, plank gaps, shadow borders) gets the same four
  sub-samples. Point-sampled, such steps stair-stepped, and the lines on a load's face fitted to them leaned
  0.1-0.2 deg off the reference's frame of the same scene: the vision was measured, and tuned, on that (session 60).
* Shading: the same shaders as the reference (the randomised look's is compiled). Inside the region the
  vision reads (the target pallet and its load, with a margin) every pixel centre and every sub-sample
  is shaded; outside it, the pixels of a 4 x 4 block that show one face of one object share one
  shading, and a sub-sample takes the colour of a pixel within 2 px that shows its face (texture is
  coarser there; outlines are not, edges are sub-sampled everywhere).
* Image: colour, vignetting, exposure and white balance go straight into the float32 image the random
  look's sensor works on, in place (:func:`drivers.sim.render.develop_look`), by numpy's steps on the
  same types (tests/integration/test_render.py holds hashes of the region the vision reads).

Measured on 1920 x 1920 random looks of paper/loaded-low-flat, one core, rays cached: 0.36-0.46 s CPU a
frame (was 1.0-1.5 s): shading 0.18 s (1.3 million rays, 1.0 million of them inside the region), casting
0.05, the sensor 0.08 (noise 0.03, JPEG 0.014), the rest 0.1. On the first frames of 40 campaign picks (seed 7):
0.430 s CPU a frame, median (0.471 before the shadow test began with the last shadowing box, the gamma skipped
the black columns and the vignetting was kept with the rays; the same bytes): shading 0.155 s, most of it the
textures (0.085), the sensor's blur 0.036, noise 0.032, JPEG 0.016. Against the reference renderer
(tests/integration/test_render.py): pocket corners within 0.05 px of the reference's, grey levels 0.8
(fixed look) and 1.2-2.7 (random looks) apart on average (0.6 and 0.9-2.2 with 2 x 2 blocks and every
sub-sample shaded). Sub-sampling the texture steps (session 60) added about 0.14 s a frame (50-220 thousand pixels of
the region at :data:`TEXTURE_CONTRAST` 0.2; 0.09 s at 0.25, 0.3 s at 0.1, which measured the randomised bench alike)
and took the region's difference from the reference from 2.3 to 1.3 grey levels on average, 1.05 % to 0.17 % of its
pixels more than 20 apart (tests/integration/test_render.py; 1.65 and 0.35 % at 0.25).
"""

from __future__ import annotations

import functools
import hashlib
import pickle
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numba import njit
from numpy.typing import NDArray

from agf.camera import CameraModel, load_camera
from agf.config import ForkGeometry
from agf.frames import JpegImage, pixels_sent
from agf.scene import Scene
from drivers.sim import render as reference
from drivers.sim.kernels import cast_tiled, gather_hits, pack_objects, tile_lists
from drivers.sim.looks import Look, draw_look
from drivers.sim.raycast import CORNERS, Hits, screen_rectangles

Array = NDArray[np.float64]
TILE = 32  # px
BLOCK = 4  # px: outside the vision's region, the pixels of a block this size that show one face share a shading
OUTSIDE = -2  # pixel key outside the field of view
CHUNK = 1 << 16  # rays shaded at once
TEXTURE_CONTRAST = 0.2  # inside the vision's region, a pixel whose colour differs from a neighbour's by this share
# of the brighter (channels summed) is sub-sampled as an outline is: 0.1 also took in the floors' fine texture, at
# twice the cost


@dataclass(frozen=True)
class PixelRays:
    """Rays of the pixel centres inside the field of view of one camera (float32), and bounds on them."""

    index: NDArray[np.int32]  # (H, W): row in the arrays below, -1 outside the field of view
    origins: NDArray[np.float32]  # (N, 3), m
    directions: NDArray[np.float32]  # (N, 3), unit
    tile: NDArray[np.int64]  # (N,): the 32 x 32 tile of each pixel, row by row
    falloff: NDArray[np.float32]  # (N,): (incidence / the camera's max incidence)², what vignetting scales
    flat: NDArray[np.int64]  # (N,): each ray's pixel in the flattened image (row-major)
    tile_axis: Array  # (T, 3), unit: a cone around the rays of each tile and of its one-pixel ring ...
    tile_spread: Array  # (T,), rad: ... and its half-angle (pi for a tile outside the field of view)
    centre: Array  # (3,), m: the middle of all origins (they move with the viewpoint shift)
    reach: float  # m: the largest distance of an origin from ``centre``


_RAYS: dict[str, PixelRays] = {}  # by the camera model's pickled form; the last two cameras of a process


def pixel_rays(camera: CameraModel) -> PixelRays:
    """The camera's pixel-centre rays, computed once per distinct camera model in a process.

    Keyed by the model's content alone: an lru_cache on the model object itself (hashed by identity) missed
    for every campaign pick, each of which loads its camera anew, and spent 2 s of a 5 s pick on rays."""
    key = hashlib.sha1(pickle.dumps(camera)).hexdigest()
    if key not in _RAYS:
        if len(_RAYS) >= 2:
            del _RAYS[next(iter(_RAYS))]
        _RAYS[key] = _pixel_rays(camera)
    return _RAYS[key]


def _pixel_rays(camera: CameraModel) -> PixelRays:
    vv, uu = np.mgrid[0 : camera.height, 0 : camera.width]
    centres = np.stack([uu.ravel(), vv.ravel()], 1).astype(float)
    inside = camera.valid_pixels(centres)
    origins, directions = camera.unproject(centres[inside])
    index = np.full(camera.height * camera.width, -1, np.int32)
    index[inside] = np.arange(int(inside.sum()), dtype=np.int32)
    index = index.reshape(camera.height, camera.width)
    ntx, nty = -(-camera.width // TILE), -(-camera.height // TILE)
    tile = (vv.ravel()[inside] // TILE) * ntx + uu.ravel()[inside] // TILE
    # float32 steps, as numpy takes them on float32 incidences
    ratio = np.arccos(np.clip(directions[:, 0], -1.0, 1.0)).astype(np.float32) / np.float32(camera.max_incidence)
    origins, directions = origins.astype(np.float32), directions.astype(np.float32)
    axis, spread = np.zeros((ntx * nty, 3)), np.full(ntx * nty, np.pi)
    _tile_cones(index, directions, TILE, axis, spread)
    centre = (origins.max(axis=0) + origins.min(axis=0)) / 2.0
    reach = float(np.linalg.norm(origins - centre, axis=1).max())
    return PixelRays(index, origins, directions, tile.astype(np.int64), ratio * ratio,
                     np.flatnonzero(inside), axis, spread, centre, reach)


@njit(cache=True)
def _tile_cones(index, directions, tile, axis, spread):  # pragma: no cover - compiled
    """Fills ``axis`` (T, 3) and ``spread`` (T,) (see :class:`PixelRays`) of the tiles that hold rays."""
    h, w = index.shape
    ntx = -(-w // tile)
    for t in range(axis.shape[0]):
        v0, u0 = (t // ntx) * tile - 1, (t % ntx) * tile - 1
        rows, cols = range(max(v0, 0), min(v0 + tile + 2, h)), range(max(u0, 0), min(u0 + tile + 2, w))
        for v in rows:
            for u in cols:
                if index[v, u] >= 0:
                    axis[t] += directions[index[v, u]]
        norm = np.sqrt(np.sum(axis[t] ** 2))
        if norm == 0:
            continue
        axis[t] /= norm
        cosine = 1.0
        for v in rows:
            for u in cols:
                if index[v, u] >= 0:
                    cosine = min(cosine, np.sum(axis[t] * directions[index[v, u]]))
        spread[t] = np.arccos(max(cosine, -1.0))


def render_fast(
    scene: Scene,
    camera: CameraModel | None = None,
    forks: ForkGeometry | None = None,
    shading: Literal["photo", "geometry"] = "photo",
    look: Look | None = None,
) -> tuple[NDArray[np.uint8], dict[str, Any]]:
    """The frame :func:`drivers.sim.render.render` draws, at a fraction of its cost (see the module); ``look`` as for
    :func:`camera_output`."""
    camera = camera or load_camera(scene.camera)
    return pixels_sent(camera_output(scene, camera, forks, shading, look)), reference.truth(scene, camera)


def camera_output(
    scene: Scene,
    camera: CameraModel,
    forks: ForkGeometry | None = None,
    shading: Literal["photo", "geometry"] = "photo",
    look: Look | None = None,
) -> NDArray[np.uint8] | JpegImage:
    """What the simulated camera sends of ``scene`` (:func:`render_fast`'s frame): its JPEG where the scene's
    sensor compresses, else the pixels. ``look``: drawn in this random look instead of the scene's own (the scene's
    look simplified, :func:`drivers.sim.looks.simplified`), whatever the scene's ``look`` key says."""
    forks = forks or ForkGeometry()
    rng = np.random.default_rng(scene.seed)
    if look is None and scene.look == "random":
        look = draw_look(scene)
    objects, pallets = reference.build_objects(scene, forks, rng, look)
    shader = _shader(scene, shading, look, objects, pallets)
    image = _trace(camera, objects, pallets, _region(scene, camera, forks), *shader)
    if shading == "geometry":
        return np.clip(np.round(image), 0, 255).astype(np.uint8)
    if look is None:
        return reference._sensor(image, scene, rng)
    return reference.develop_look(image, look, rng)


def _shader(
    scene: Scene, shading: str, look: Look | None, objects: list, pallets: list
) -> tuple[Callable, float, float, NDArray]:
    """The reference's shader of the frame, its light (exposure), its vignetting strength (0: none) and
    the white balance its sensor begins with (3,), whose type the image takes: the random look's sensor
    casts the reference's float64 image to float32 first."""
    if shading == "geometry":
        return reference._shade_geometry, 1.0, 0.0, np.ones(3)
    if look is None:
        shade = functools.partial(reference._shade, lights=reference._lights(objects))
        return shade, scene.environment.light, reference.VIGNETTING, np.ones(3)
    arrays = reference.look_arrays(look, look.camera_lights(scene), objects, pallets)
    light = scene.environment.light * look.exposure
    return functools.partial(reference._shade_look, arrays), light, look.vignetting, reference.white_balance(look)


def _trace(
    camera: CameraModel, objects: list, pallets: list, region: NDArray[np.int64], shade: Callable, light: float,
    vignetting: float, gain: NDArray
) -> NDArray:
    """The frame (H, W, 3) before the sensor: what the rays hit (:func:`_outlines`), the rays :func:`_plan`
    and :func:`_share_samples` pick shaded, and each pixel's colour times the vignetting and ``light``,
    rounded to ``gain``'s type, times ``gain`` and floored at zero."""
    rays, packed = pixel_rays(camera), pack_objects(objects)
    lists = _tile_lists(camera, objects, rays, packed)
    keys, edge, pixels, centre = _outlines(rays, lists, packed)
    row, shaded = np.empty(len(rays.origins), np.int32), np.empty(len(rays.origins), np.int32)
    shaded = shaded[: _plan(rays.index, keys, edge, region, BLOCK, row, shaded)]
    colour = _shaded(shade, objects, pallets, shaded, rays.origins, rays.directions, centre, packed)
    texture = np.empty((keys.size, 2), np.int64)
    texture = texture[: _texture_edge_pixels(rays.index, row, colour, region, TEXTURE_CONTRAST, texture)]
    row[rays.index[texture[:, 1], texture[:, 0]]] = -1  # their colour is their sub-samples' mean, as at an outline
    pixels = np.concatenate([pixels, texture])
    sub_o, sub_d, sub = _sub_samples(pixels, rays, lists, packed)
    u, v = pixels.T
    source, own = np.empty(len(sub_o), np.int32), np.empty(len(sub_o), np.int32)
    own = own[: _share_samples(u, v, 8 * sub[1] + sub[2], keys, rays.index, row, region, source, own)]
    sub_colour = _shaded(shade, objects, pallets, own, sub_o, sub_d, sub, packed)
    image = np.zeros((camera.height, camera.width, 3), gain.dtype)
    _compose(rays.flat, row, colour, rays.index[v, u], source, sub_colour, rays.falloff, np.float32(vignetting),
             light, gain, image.reshape(-1, 3))
    return image


def _outlines(rays: PixelRays, lists: tuple, packed: tuple) -> tuple:
    """What the pixel centres' rays hit (keys (H, W), see :func:`_pixel_keys`), the edge pixels (mask
    (H, W); (u, v) (E, 2), row by row) and the pixel centres' nearest hits (distance, object, face (N,)); ``lists``
    are :func:`_tile_lists`'."""
    centre = _cast(rays.origins, rays.directions, rays.tile, *lists, packed)
    keys = np.empty(rays.index.shape, np.int32)
    _pixel_keys(rays.index, centre[1], centre[2], keys)
    edge, pixels = np.zeros(keys.shape, bool), np.empty((keys.size, 2), np.int64)
    pixels = pixels[: _edge_pixels(keys, edge, pixels)]
    return keys, edge, pixels, centre


def _sub_samples(pixels: NDArray[np.int64], rays: PixelRays, lists: tuple, packed: tuple) -> tuple:
    """The reference's four sub-samples of each of ``pixels`` ((u, v) (E, 2)): their rays (origins, directions
    (4 E, 3)) and nearest hits."""
    sub_o, sub_d = _sub_rays(pixels, reference._subpixel_offsets(4), rays)
    sub = _cast(sub_o, sub_d, np.repeat(rays.tile[rays.index[pixels[:, 1], pixels[:, 0]]], 4), *lists, packed)
    return sub_o, sub_d, sub


def _tile_lists(camera: CameraModel, objects: list, rays: PixelRays, packed: tuple) -> tuple[NDArray, NDArray, Array]:
    """CSR lists (start (T + 1,), objects, near) of the objects each tile's rays (pixel centres and
    sub-samples, whose directions lie in the tile's cone) can hit: those whose screen rectangle meets the
    tile, but not where the tile's cone and the object's (:func:`_object_bounds`) are more than 1e-6 rad
    apart; each tile's nearest first by ``near``, a lower bound (m) on the distance of any hit."""
    axis, spread, near = _object_bounds(packed, rays.centre, rays.reach)
    apart = np.arccos(np.clip(rays.tile_axis @ axis.T, -1.0, 1.0))
    reachable = apart <= rays.tile_spread[:, None] + spread + 1e-6
    start, objs = tile_lists(screen_rectangles(camera, objects), camera.width, camera.height, TILE, reachable)
    objs = objs[np.lexsort((near[objs], np.repeat(np.arange(len(start) - 1), np.diff(start))))]
    return start, objs, near[objs]


def _object_bounds(packed: tuple, centre: Array, reach: float) -> tuple[Array, Array, Array]:
    """For the rays from within ``reach`` (m) of ``centre`` (3,) that can hit each object: the axis (M, 3)
    and half-angle (M,, rad; pi: any) of a cone holding their directions (the directions to a box's
    corners seen from ``centre``, a cap under 90 deg holds those to all its points, widened by what
    ``reach`` can turn them; the half-space a plane's far side lies in) and a lower bound (M,, m) on the
    distance of their hits (directions of unit length to 1e-6)."""
    kind, rotation, middle, half, _ = packed
    axis, spread, gap = np.zeros((len(kind), 3)), np.full(len(kind), np.pi), np.zeros(len(kind))
    for k in range(len(kind)):
        offset = centre - middle[k]
        if kind[k] == 1:
            normal = rotation[k, :, 2]
            gap[k] = abs(normal @ offset)
            if gap[k] > reach + 1e-6:
                axis[k], spread[k] = -np.sign(normal @ offset) * normal, np.pi / 2
            continue
        gap[k] = float(np.linalg.norm(np.maximum(np.abs(offset @ rotation[k]) - half[k], 0.0)))
        corners = (CORNERS * half[k]) @ rotation[k].T - offset
        corners /= np.linalg.norm(corners, axis=1)[:, None]
        axis[k] = corners.mean(axis=0) / np.linalg.norm(corners.mean(axis=0))
        cap = float(np.arccos(np.clip(corners @ axis[k], -1.0, 1.0).min()))
        if gap[k] > reach + 1e-6 and cap < np.pi / 2:
            spread[k] = cap + np.arcsin(reach / gap[k])
    return axis, spread, (gap - reach) * (1.0 - 1e-6) - 1e-9


def _region(scene: Scene, camera: CameraModel, forks: ForkGeometry) -> NDArray[np.int64]:
    """The image rectangle (u0, v0, u1, v1) the vision reads: the target pallet and its load, with a
    margin of a quarter of their size and 64 px (everything for a calibration scene, or when they
    reach behind the lens)."""
    if scene.pallet is None:
        return np.array([0, 0, camera.width, camera.height])
    kind = reference.catalogued(scene.pallet.type)
    top = kind.deck_top + (scene.load.size[2] if scene.load is not None else 0.0)
    target = scene.camera_in_fork.inverse() @ scene.pallet.in_fork
    width = max(kind.width, scene.load.size[1] if scene.load is not None else 0.0)
    outline = reference._box(target, (0.0, kind.length), (-width / 2, width / 2), (kind.deck_bottom, top), "wood")
    (rect,) = screen_rectangles(camera, [outline])
    if rect is None:
        return np.array([0, 0, camera.width, camera.height])
    margin = 0.25 * (rect[2:] - rect[:2]) + 64
    return np.r_[rect[:2] - margin, rect[2:] + margin].astype(np.int64)


def _cast(origins, directions, tile, start, objs, near, packed) -> tuple[Array, NDArray[np.int32], NDArray[np.int8]]:
    """Distance (N,, m), object (N,) and face (N,) of the nearest hits of rays (N, 3) (see
    :func:`drivers.sim.kernels.cast_tiled`)."""
    n = len(origins)
    distance, index, face = np.empty(n), np.empty(n, np.int32), np.empty(n, np.int8)
    kind, rotation, centre, half, _ = packed
    cast_tiled(origins, directions, tile, start, objs, near, kind, rotation, centre, half, distance, index, face)
    return distance, index, face


def _shaded(shade: Callable, objects: list, pallets: list, rows, origins, directions, nearest, packed) -> Array:
    """Colours (S, 3) of the rays ``rows`` (S,) among rays (N, 3) whose ``nearest`` hits were cast, shaded
    :data:`CHUNK` at a time: the allocator reuses small arrays, while large ones are fresh memory the
    system zeroes first (that cost 20 ms a frame)."""
    colour = np.empty((len(rows), 3))
    for start in range(0, len(rows), CHUNK):
        part = rows[start : start + CHUNK]
        colour[start : start + len(part)] = shade(objects, pallets, *_hits(part, origins, directions, nearest, packed))
    return colour


def _hits(rows, origins, directions, nearest, packed) -> tuple[Hits, NDArray, NDArray]:
    """The :class:`Hits` (objects int64) of the rays ``rows`` (S,) among rays (N, 3) whose ``nearest`` hits
    were cast, and their origins and directions (S, 3)."""
    n = len(rows)
    ray_o, ray_d = np.empty((n, 3), origins.dtype), np.empty((n, 3), directions.dtype)
    distance, index, local, normal = np.empty(n), np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3))
    gather_hits(rows, origins, directions, *nearest, packed[1], packed[2], ray_o, ray_d, distance, index, local,
                normal)
    return Hits(distance, index, normal, local), ray_o, ray_d


# The compiled passes over the image take their outputs from numpy: its large arrays get transparent
# huge pages, numba's do not, and faulting in 4 kB pages cost these passes more than their work.


@njit(cache=True)
def _pixel_keys(index, hit_index, face, keys):  # pragma: no cover - compiled
    """Fills ``keys`` (H, W) with what each pixel centre's ray hit: object and face (8 * object + face;
    -8 for nothing), :data:`OUTSIDE` outside the field of view."""
    h, w = index.shape
    for v in range(h):
        for u in range(w):
            i = index[v, u]
            keys[v, u] = OUTSIDE if i < 0 else 8 * hit_index[i] + face[i]


@njit(cache=True)
def _edge_pixels(keys, edge, found):  # pragma: no cover - compiled
    """Marks in ``edge`` (H, W, all False) the pixels in the field of view whose key (see
    :func:`_pixel_keys`) differs from one of their 8 neighbours', lists them (u, v) row by row in
    ``found`` (H * W, 2) and returns their number."""
    h, w = keys.shape
    e = 0
    for v in range(h):  # each neighbouring pair once: right, and the three below
        for u in range(w):
            key = keys[v, u]
            for nv, nu in ((v, u + 1), (v + 1, u - 1), (v + 1, u), (v + 1, u + 1)):
                if nv < h and 0 <= nu < w and keys[nv, nu] != key:
                    edge[v, u] |= key != OUTSIDE
                    edge[nv, nu] |= keys[nv, nu] != OUTSIDE
        for u in range(w):  # row v is complete
            if edge[v, u]:
                found[e, 0], found[e, 1] = u, v
                e += 1
    return e


@njit(cache=True)
def _texture_edge_pixels(index, row, colour, region, contrast, found):  # pragma: no cover - compiled
    """Lists (u, v) row by row in ``found`` (H * W, 2) the pixels inside ``region`` (u0, v0, u1, v1) that are not
    outlines (``row`` >= 0, see :func:`_plan`) and whose ``colour`` (channels summed) differs from an 8-neighbour's
    by more than ``contrast`` of the brighter; returns their number."""
    h, w = index.shape
    e = 0
    for v in range(max(region[1], 1), min(region[3] + 1, h - 1)):
        for u in range(max(region[0], 1), min(region[2] + 1, w - 1)):
            i = index[v, u]
            if i < 0 or row[i] < 0:
                continue
            a = colour[row[i], 0] + colour[row[i], 1] + colour[row[i], 2]
            differs = False
            for nv in range(v - 1, v + 2):
                for nu in range(u - 1, u + 2):
                    j = index[nv, nu]
                    if not differs and j >= 0 and row[j] >= 0:
                        b = colour[row[j], 0] + colour[row[j], 1] + colour[row[j], 2]
                        differs = abs(a - b) > contrast * max(a, b)
            if differs:
                found[e, 0], found[e, 1] = u, v
                e += 1
    return e


@njit(cache=True)
def _plan(index, keys, edge, region, block, row, shaded):  # pragma: no cover - compiled
    """Picks the rays to shade: fills ``shaded`` (N,) with them and returns their number S, and fills
    ``row`` (N,) with the one among them whose colour each ray takes (-1: an edge pixel's, the mean of its
    sub-samples'). Inside ``region`` (u0, v0, u1, v1, px) a ray takes its own colour; outside, the first
    ray's of its ``block`` x ``block`` pixel block to show the same object face (``keys`` (H, W)): the
    texture, not the geometry, is shared."""
    h, w = index.shape
    faces, rows = np.empty(block * block, keys.dtype), np.empty(block * block, row.dtype)
    s = 0
    for v0 in range(0, h, block):
        for u0 in range(0, w, block):
            v1, u1 = min(v0 + block, h), min(u0 + block, w)
            within = region[0] <= u0 and u1 - 1 <= region[2] and region[1] <= v0 and v1 - 1 <= region[3]
            seen = 0  # faces shaded in this block so far
            for v in range(v0, v1):
                for u in range(u0, u1):
                    i = index[v, u]
                    if i < 0:
                        continue
                    if edge[v, u]:
                        row[i] = -1
                        continue
                    if not (within or (region[0] <= u <= region[2] and region[1] <= v <= region[3])):
                        j = 0
                        while j < seen and faces[j] != keys[v, u]:
                            j += 1
                        if j < seen:
                            row[i] = rows[j]
                            continue
                        faces[seen], rows[seen] = keys[v, u], s
                        seen += 1
                    row[i], shaded[s] = s, i
                    s += 1
    return s


@njit(cache=True)
def _share_samples(u, v, sample_keys, keys, index, row, region, source, own):  # pragma: no cover - compiled
    """Where the colours of the sub-samples (faces ``sample_keys`` (4 E,), see :func:`_pixel_keys`) of the
    edge pixels (``u``, ``v``) (E,) come from: fills ``source`` (4 E,) and returns the number S of
    sub-samples to shade, listed in ``own`` (4 E,). Outside ``region``, a sub-sample takes the colour of
    the first pixel within 2 px that shows the same face (its row among the shaded rays, the texture,
    not the geometry, is shared); where there is none, and inside, its own (-1 - its place in ``own``)."""
    h, w = keys.shape
    n = 0
    for k in range(sample_keys.shape[0]):
        e = k // 4
        source[k] = -1
        if not (region[0] <= u[e] <= region[2] and region[1] <= v[e] <= region[3]):
            for nv in range(max(v[e] - 2, 0), min(v[e] + 3, h)):
                for nu in range(max(u[e] - 2, 0), min(u[e] + 3, w)):
                    if source[k] < 0 and keys[nv, nu] == sample_keys[k] and row[index[nv, nu]] >= 0:
                        source[k] = row[index[nv, nu]]
        if source[k] < 0:
            source[k], own[n] = -1 - n, k
            n += 1
    return n


@njit(cache=True)
def _compose(flat, row, colour, edges, source, sub_colour, falloff, vignetting, light, gain,
             image):  # pragma: no cover - compiled
    """Writes each ray's colour into its pixel ``flat`` (N,) of ``image`` (H * W, 3): the row ``row`` (N,)
    of ``colour`` (S, 3), or for the rays ``edges`` (E,) the mean of their four sub-samples' (``source``
    (4 E,), see :func:`_share_samples`; ``sub_colour`` (S', 3)), times the vignetting (1 - ``vignetting``
    ``falloff`` (N,), float32: see :class:`PixelRays`) and ``light``, rounded to the image's type, times
    ``gain`` (3,) and floored at zero: numpy's steps on these types (its mean over four sums them in order)."""
    zero = image.dtype.type(0.0)
    for i in range(flat.shape[0]):
        if row[i] >= 0:
            factor = np.float32(1.0) - vignetting * falloff[i]
            for c in range(3):
                image[flat[i], c] = max(image.dtype.type(colour[row[i], c] * factor * light) * gain[c], zero)
    for e in range(edges.shape[0]):
        i = edges[e]
        factor = np.float32(1.0) - vignetting * falloff[i]
        for c in range(3):
            # -0.0 + x is x: the sum starts with the first sample, as numpy's does. (No helper picks the
            # sample: an inlined helper choosing between two arrays costs reference counting per call.)
            total = -0.0
            for k in range(4 * e, 4 * e + 4):
                total += colour[source[k], c] if source[k] >= 0 else sub_colour[-1 - source[k], c]
            image[flat[i], c] = max(image.dtype.type(total / 4 * factor * light) * gain[c], zero)


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
