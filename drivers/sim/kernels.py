"""Compiled kernels of the renderers (numba): ray-box and ray-plane hits, nearest hits of many rays with
per-tile object lists, the randomised look's shading (textures, lights, hard shadows, pocket
occlusion) and steps of its sensor (where the gamma has work, shot noise, 8-bit rounding).

Objects are packed once per frame into arrays (:func:`pack_objects`): type (0 box, 1 plane), rotation
and centre (object to camera frame), half extents, and the packed :class:`~drivers.sim.textures.Style`.
The kernels compute what the renderers' numpy code would, bit for bit (no fast-math): where they skip
work, a conservative bound shows the skipped work could not change the result.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from drivers.sim.raycast import CORNERS, Box
from drivers.sim.textures import texel

Array = NDArray[np.float64]
GRID = 32  # cells per side of a light's occluder grid
SHADOW_BIAS = 2e-4  # m along the normal: a shadow ray must not hit its own surface


def pack_objects(objects: list, styles: list | None = None) -> tuple[NDArray, Array, Array, Array, Array]:
    """(type (M,), rotation (M, 3, 3), centre (M, 3), half (M, 3), style (M, 8)) of boxes and planes."""
    m = len(objects)
    kind = np.array([0 if isinstance(o, Box) else 1 for o in objects], np.int64)
    rotation = np.array([o.pose.rotation for o in objects]).reshape(m, 3, 3)
    centre = np.array([o.pose.translation for o in objects]).reshape(m, 3)
    half = np.array([o.half if isinstance(o, Box) else np.zeros(3) for o in objects]).reshape(m, 3)
    style = np.zeros((m, 8)) if styles is None else np.array([s.packed() for s in styles]).reshape(m, 8)
    return kind, rotation, centre, half, style


@njit(cache=True, inline="always")
def hit(k, kind, R, c, half, ox, oy, oz, dx, dy, dz):  # pragma: no cover - compiled
    """Entry distance (inf: none) and face code (2 * axis + (outward normal along +axis)) of one ray
    against object ``k``."""
    px, py, pz = ox - c[k, 0], oy - c[k, 1], oz - c[k, 2]
    lo = (R[k, 0, 0] * px + R[k, 1, 0] * py + R[k, 2, 0] * pz,
          R[k, 0, 1] * px + R[k, 1, 1] * py + R[k, 2, 1] * pz,
          R[k, 0, 2] * px + R[k, 1, 2] * py + R[k, 2, 2] * pz)  # fmt: skip
    ld = (R[k, 0, 0] * dx + R[k, 1, 0] * dy + R[k, 2, 0] * dz,
          R[k, 0, 1] * dx + R[k, 1, 1] * dy + R[k, 2, 1] * dz,
          R[k, 0, 2] * dx + R[k, 1, 2] * dy + R[k, 2, 2] * dz)  # fmt: skip
    if kind[k] == 1:
        if ld[2] == 0.0:
            return math.inf, 0
        t = -lo[2] / ld[2]
        return (t, 5 if lo[2] >= 0 else 4) if t > 1e-6 else (math.inf, 0)
    t_near, t_far, axis = -math.inf, math.inf, 0
    for a in range(3):
        if ld[a] == 0.0:
            if abs(lo[a]) > half[k, a]:
                return math.inf, 0
            continue
        inv = 1.0 / ld[a]
        t0, t1 = (-half[k, a] - lo[a]) * inv, (half[k, a] - lo[a]) * inv
        if t0 > t1:
            t0, t1 = t1, t0
        if t0 > t_near:
            t_near, axis = t0, a
        t_far = min(t_far, t1)
    if t_near <= t_far and t_near > 1e-6:
        return t_near, 2 * axis + (1 if ld[axis] < 0 else 0)
    return math.inf, 0


@njit(cache=True)
def cast_tiled(origins, directions, tile_of, tile_start, tile_objs, tile_near, kind, R, c, half,
               distance, index, face):  # pragma: no cover - compiled
    """Nearest hits of rays (N, 3) against the objects listed for each ray's tile, nearest first by a
    lower bound ``tile_near`` on the distance of any hit of them; fills the outputs (N,) (distance inf and
    index -1 for none; see :func:`hit` for the face code). Of equally near hits the lowest object's wins,
    as when every object is tried in order."""
    for i in range(origins.shape[0]):
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        best, best_k, best_f = math.inf, -1, 0
        tile = tile_of[i]
        for j in range(tile_start[tile], tile_start[tile + 1]):
            if tile_near[j] > best:
                break  # nothing further on can be hit nearer
            k = tile_objs[j]
            t, f = hit(k, kind, R, c, half, ox, oy, oz, dx, dy, dz)
            if t < best or (t == best and k < best_k):
                best, best_k, best_f = t, k, f
        distance[i], index[i], face[i] = best, best_k, best_f


@njit(cache=True)
def gather_hits(rows, origins, directions, distance, index, face, R, c, ray_origins, ray_directions, hit_distance,
                hit_index, local, normal):  # pragma: no cover - compiled
    """The rays ``rows`` (S,) among rays ``origins``, ``directions`` (N, 3) whose nearest hits
    :func:`cast_tiled` found (``distance``, ``index``, ``face`` (N,)), as the shaders take them: fills their
    origins and directions (S, 3), hit distances and objects (S,), the hit points in their object's frame
    ``local`` (S, 3) and the surface normals in the camera's ``normal`` (S, 3) (zero for rays that hit
    nothing)."""
    for j in range(rows.shape[0]):
        i = rows[j]
        k, f, t = index[i], face[i], distance[i]
        for a in range(3):
            ray_origins[j, a], ray_directions[j, a] = origins[i, a], directions[i, a]
        hit_distance[j], hit_index[j] = t, k
        if k < 0:
            for a in range(3):
                local[j, a], normal[j, a] = 0.0, 0.0
            continue
        px = origins[i, 0] + t * directions[i, 0] - c[k, 0]
        py = origins[i, 1] + t * directions[i, 1] - c[k, 1]
        pz = origins[i, 2] + t * directions[i, 2] - c[k, 2]
        for a in range(3):
            local[j, a] = R[k, 0, a] * px + R[k, 1, a] * py + R[k, 2, a] * pz
        sign = 1.0 if f % 2 == 1 else -1.0
        for a in range(3):
            normal[j, a] = sign * R[k, a, f // 2]


def tile_lists(
    rects: list, width: int, height: int, tile: int, reachable: NDArray[np.bool_] | None = None
) -> tuple[NDArray, NDArray]:
    """CSR lists (start (T + 1,), objects) of the objects whose screen rectangle (None: anywhere) meets
    each ``tile`` x ``tile`` pixel tile, tiles row by row, and which the tile's rays can reach at all
    (``reachable`` (T, M); None: all)."""
    ntx, nty = -(-width // tile), -(-height // tile)
    meets = np.zeros((nty, ntx, len(rects)), bool)
    for k, r in enumerate(rects):
        if r is None:
            meets[:, :, k] = True
            continue
        x0, y0 = max(int(r[0] // tile), 0), max(int(r[1] // tile), 0)
        x1, y1 = min(int(r[2] // tile), ntx - 1), min(int(r[3] // tile), nty - 1)
        meets[y0 : max(y1 + 1, 0), x0 : max(x1 + 1, 0), k] = True
    meets = meets.reshape(ntx * nty, len(rects))
    tiles, objs = np.nonzero(meets if reachable is None else meets & reachable)
    start = np.zeros(ntx * nty + 1, np.int64)
    start[1:] = np.cumsum(np.bincount(tiles, minlength=ntx * nty))
    return start, objs.astype(np.int64)


# -- randomised look: lights and shading ----------------------------------------------------------

LIGHT_FIELDS = 28  # type, power, colour 3, direction 3, position 3, reference distance, door, door 12, half 2,
# shadows


def pack_lights(lights: list, kind: NDArray, R: Array, c: Array, half: Array) -> tuple:
    """Packed lights (L, 28), their occluder grids (L, 13: view axis, e1, e2, x0, y0, cell, unused), CSR
    occluder lists (start (L, GRID * GRID + 2), objects) and occluder bounds (L, M, 6). Each box is listed
    in the grid cells its outline seen from the light covers (the last cell holds the boxes the view
    cannot bound) and bounded (see :func:`_bounds`; a plane: nowhere)."""
    packed = np.array([_light_row(light) for light in lights]).reshape(len(lights), LIGHT_FIELDS)
    grids = np.zeros((len(lights), 13))
    starts = np.zeros((len(lights), GRID * GRID + 2), np.int64)
    bounds = np.tile([-math.inf, -math.inf, math.inf, math.inf, 0.0, math.inf], (len(lights), len(kind), 1))
    objs = []
    boxes = np.flatnonzero(kind == 0)
    for n, light in enumerate(lights):
        axis, e1, e2 = _view(light)
        outlines = [_bounds(light, axis, e1, e2, (CORNERS * half[k]) @ R[k].T + c[k]) for k in boxes]
        bounds[n, boxes] = np.array(outlines).reshape(-1, 6)
        rects = np.array([r for r in outlines if np.isfinite(r[0])]).reshape(-1, 6)
        x0, y0 = (rects[:, 0].min(), rects[:, 1].min()) if len(rects) else (0.0, 0.0)
        size = max(rects[:, 2].max() - x0, rects[:, 3].max() - y0, 1e-6) if len(rects) else 1.0
        cell = size / GRID * (1 + 1e-9)
        grids[n] = [*axis, *e1, *e2, x0, y0, cell, 0.0]
        covers = np.zeros((GRID * GRID + 1, len(boxes)), bool)
        for b, r in enumerate(outlines):
            if not np.isfinite(r[0]):
                covers[:, b] = True
                continue
            i0, j0 = int((r[0] - x0) // cell), int((r[1] - y0) // cell)
            i1, j1 = min(int((r[2] - x0) // cell), GRID - 1), min(int((r[3] - y0) // cell), GRID - 1)
            rows = np.arange(max(j0, 0), j1 + 1)[:, None] * GRID + np.arange(max(i0, 0), i1 + 1)
            covers[rows.ravel(), b] = True
        cells, listed = np.nonzero(covers)
        starts[n] = sum(map(len, objs)) + np.r_[0, np.cumsum(np.bincount(cells, minlength=GRID * GRID + 1))]
        objs.append(boxes[listed])
    return packed, grids, starts, np.concatenate(objs) if objs else np.zeros(0, np.int64), bounds


def _light_row(light) -> list[float]:
    """A :class:`~drivers.sim.looks.CameraLight` packed (:data:`LIGHT_FIELDS`)."""
    sun = light.direction is not None
    row = [0.0 if sun else 1.0, light.power, *light.colour]
    row += list(light.direction if sun else np.zeros(3)) + list(light.position if not sun else np.zeros(3))
    row += [light.reference_distance, 1.0 if light.door is not None else 0.0]
    row += [*np.concatenate(light.door[:4]), *light.door[4:]] if light.door is not None else [0.0] * 14
    return [*row, float(light.shadows)]


def _view(light) -> tuple[Array, Array, Array]:
    """The view of a light's occluder grid: its axis (along the sun, or down from the lamp) and two unit
    vectors across it (3,)."""
    axis = np.asarray(light.direction, float) if light.direction is not None else light.down
    axis = axis / np.linalg.norm(axis)
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return axis, e1, np.cross(axis, e1)


def _bounds(light, axis: Array, e1: Array, e2: Array, corners: Array) -> Array:
    """(6,) bounds of a box (corners (8, 3)) in a light's view (see :func:`pack_lights`) for its shadow
    rays: the outline (x0, y0, x1, y1) of its corners, along the sun or projected from the lamp (infinite
    where a corner is not well in front of the lamp); the inverse of their least depth (1 for the sun);
    how high they reach towards the light (m: along the sun, or up from the lamp)."""
    sun = light.direction is not None
    w = corners if sun else corners - light.position
    depth = np.ones(8) if sun else w @ axis
    top = (w @ axis).max() if sun else -depth.min()
    if not (sun or bool(np.all(depth > 0.05 * np.linalg.norm(w, axis=1)))):
        return np.array([-math.inf, -math.inf, math.inf, math.inf, 0.0, top])
    return np.r_[(w @ e1 / depth).min(), (w @ e2 / depth).min(), (w @ e1 / depth).max(), (w @ e2 / depth).max(),
                 1.0 / depth.min(), top]


@njit(cache=True)
def shade_look(origins, directions, distance, normals, local, index, kind, R, c, half, style, lights, grids,
               starts, objs, bounds, pallets, ambient, sky, out):  # pragma: no cover - compiled
    """Colour (N, 3, 0..255 before exposure) of the hits of rays: texture x (ambient + lights, each Lambertian,
    lamps falling off with distance, zero in shadow or outside a door's patch) x pocket occlusion;
    ``sky`` where nothing was hit. ``pallets`` (P, 16): rotation (9), centre (3), length, width, pocket
    height, deck bottom."""
    # The loops over lights' occluders and over pallets stay in this body: around a loop in an inlined
    # helper numba keeps the reference counting of every array argument, two atomic updates per array
    # and call (they took a third of the shading time).
    # Neighbouring points mostly lie in the same box's shadow: the box that last shadowed a point from a
    # light is tried first (a point is in shadow if any listed box is in the way, whatever the order).
    last = np.full(lights.shape[0], -1, np.int64)
    for i in range(origins.shape[0]):
        k = index[i]
        if k < 0:
            out[i, 0], out[i, 1], out[i, 2] = 255.0 * sky[0], 255.0 * sky[1], 255.0 * sky[2]
            continue
        axis = 2
        if kind[k] == 0:
            r0 = abs(local[i, 0]) / max(half[k, 0], 1e-9)
            r1 = abs(local[i, 1]) / max(half[k, 1], 1e-9)
            r2 = abs(local[i, 2]) / max(half[k, 2], 1e-9)
            axis = 0 if r0 >= r1 and r0 >= r2 else (1 if r1 >= r2 else 2)
        b, g, r = texel(style, k, local[i, 0], local[i, 1], local[i, 2], half[k, 0], half[k, 1], half[k, 2], axis)
        t = distance[i]
        px = origins[i, 0] + t * directions[i, 0]
        py = origins[i, 1] + t * directions[i, 1]
        pz = origins[i, 2] + t * directions[i, 2]
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        eb, eg, er = ambient, ambient, ambient
        for n in range(lights.shape[0]):
            e, cell, ox, oy, oz, wx, wy, wz, reach, vx, vy, height = _light(n, px, py, pz, nx, ny, nz, lights, grids)
            shadowed, first = False, last[n]
            if cell >= 0:
                begin, end = starts[n, cell], starts[n, cell + 1]
                for j in range(begin, end):  # the box that shadowed this light's last shadowed point, if listed
                    if objs[j] == first:
                        shadowed = (first != k and not _apart(bounds, n, first, vx, vy, height)
                                    and hit(first, kind, R, c, half, ox, oy, oz, wx, wy, wz)[0] < reach)
                        break
                j = begin
                while not shadowed and j < end:
                    box = objs[j]
                    j += 1
                    if box == k or box == first or _apart(bounds, n, box, vx, vy, height):
                        continue  # the shadow ray leaves the point's own box; it cannot reach this one
                    if hit(box, kind, R, c, half, ox, oy, oz, wx, wy, wz)[0] < reach:
                        shadowed, last[n] = True, box
            if shadowed:
                e = 0.0
            eb += e * lights[n, 2]
            eg += e * lights[n, 3]
            er += e * lights[n, 4]
        occlusion = 1.0
        for m in range(pallets.shape[0]):
            occlusion *= _pocket_occlusion(m, px, py, pz, pallets)
        out[i, 0] = 255.0 * b * eb * occlusion
        out[i, 1] = 255.0 * g * eg * occlusion
        out[i, 2] = 255.0 * r * er * occlusion


@njit(cache=True, inline="always")
def _light(n, px, py, pz, nx, ny, nz, lights, grids):  # pragma: no cover - compiled
    """Irradiance light ``n`` gives a point with a normal unless an occluder is in the way (see
    :func:`shade_look`), and the shadow ray that decides it: the occluder grid cell to search (-1: none
    needed), origin (3), direction (3), reach (m), and the point's place in the grid's view (2; nan where
    the view cannot place it) and height towards the light (m, see :func:`_bounds`; -inf where the view
    cannot place it)."""
    L = lights[n]
    if L[0] == 0.0:
        wx, wy, wz, reach, falloff = L[5], L[6], L[7], math.inf, 1.0
    else:
        wx, wy, wz = L[8] - px, L[9] - py, L[10] - pz
        reach = math.sqrt(wx * wx + wy * wy + wz * wz)
        wx, wy, wz = wx / reach, wy / reach, wz / reach
        falloff = (L[11] / max(reach, 0.3)) ** 2
    cosine = nx * wx + ny * wy + nz * wz
    ox, oy, oz = px + SHADOW_BIAS * nx, py + SHADOW_BIAS * ny, pz + SHADOW_BIAS * nz
    if cosine <= 0:
        return 0.0, -1, ox, oy, oz, wx, wy, wz, reach, math.nan, math.nan, -math.inf
    if L[12] > 0:  # a door the sun shines through: lit only where the ray passes its opening
        denom = wx * L[16] + wy * L[17] + wz * L[18]
        if denom != 0:
            t = ((L[13] - ox) * L[16] + (L[14] - oy) * L[17] + (L[15] - oz) * L[18]) / denom
            if t > 0:
                qx, qy, qz = ox + t * wx - L[13], oy + t * wy - L[14], oz + t * wz - L[15]
                if (abs(qx * L[19] + qy * L[20] + qz * L[21]) >= L[25]
                        or abs(qx * L[22] + qy * L[23] + qz * L[24]) >= L[26]):  # fmt: skip
                    return 0.0, -1, ox, oy, oz, wx, wy, wz, reach, math.nan, math.nan, -math.inf
    if L[27] == 0.0:
        return L[1] * cosine * falloff, -1, ox, oy, oz, wx, wy, wz, reach, math.nan, math.nan, -math.inf
    G = grids[n]
    if L[0] == 0.0:
        vx, vy, depth = px * G[3] + py * G[4] + pz * G[5], px * G[6] + py * G[7] + pz * G[8], 1.0
        height = px * G[0] + py * G[1] + pz * G[2]
    else:
        ax, ay, az = px - L[8], py - L[9], pz - L[10]
        depth = ax * G[0] + ay * G[1] + az * G[2]
        vx, vy = ax * G[3] + ay * G[4] + az * G[5], ax * G[6] + ay * G[7] + az * G[8]
        if depth <= 0.05 * math.sqrt(ax * ax + ay * ay + az * az):
            depth = -1.0
        height = -depth  # up from the lamp
    outside = GRID * GRID  # the cell of the boxes the view cannot bound
    if depth <= 0:
        return L[1] * cosine * falloff, outside, ox, oy, oz, wx, wy, wz, reach, math.nan, math.nan, -math.inf
    ci, cj = math.floor((vx / depth - G[9]) / G[11]), math.floor((vy / depth - G[10]) / G[11])
    cell = cj * GRID + ci if 0 <= ci < GRID and 0 <= cj < GRID else outside
    return L[1] * cosine * falloff, cell, ox, oy, oz, wx, wy, wz, reach, vx / depth, vy / depth, height


@njit(cache=True, inline="always")
def _apart(bounds, n, k, vx, vy, height):  # pragma: no cover - compiled
    """Whether a shadow ray towards light ``n`` from a point at (``vx``, ``vy``) in its view and ``height``
    towards it (see :func:`_light`) certainly misses box ``k`` (``bounds``, see :func:`_bounds`): the ray
    climbs from SHADOW_BIAS below the point's height, and strays from the point's place by at most
    SHADOW_BIAS (1 + max |v|) / depth inside a box; 1e-9 to spare for rounding."""
    if bounds[n, k, 5] <= height - SHADOW_BIAS * (1.0 + 1e-6) - 1e-9:
        return True
    margin = SHADOW_BIAS * (1.0 + max(abs(vx), abs(vy))) * (1.0 + 1e-6) * bounds[n, k, 4] + 1e-9
    return (vx < bounds[n, k, 0] - margin or vx > bounds[n, k, 2] + margin or vy < bounds[n, k, 1] - margin
            or vy > bounds[n, k, 3] + margin)  # fmt: skip


@njit(cache=True, inline="always")
def _pocket_occlusion(m, px, py, pz, pallets):  # pragma: no cover - compiled
    """Ambient occlusion inside pallet ``m``'s pockets: surfaces behind the front face, under the deck,
    grow dark (factor 0.12-0.40; 1 elsewhere)."""
    P = pallets[m]
    dx, dy, dz = px - P[9], py - P[10], pz - P[11]
    x = P[0] * dx + P[3] * dy + P[6] * dz
    y = P[1] * dx + P[4] * dy + P[7] * dz
    z = P[2] * dx + P[5] * dy + P[8] * dz
    if 0.002 < x < P[12] and abs(y) < P[13] / 2 and z < P[14] / 2 - 1e-4 and z > P[15] - 0.01:
        return 0.12 + 0.3 * math.exp(-x / 0.03)
    return 1.0


@njit(cache=True)
def add_shot_noise(image, noise, out):  # pragma: no cover - compiled
    """8-bit ``out`` (N,) of ``image`` (N,) plus ``noise`` (N,) times the shot noise's growth with
    brightness, sqrt(0.3 + 0.7 min(max(image, 0), 255) / 128), rounded half to even and clipped to
    0..255: float32 steps, each rounded as numpy and OpenCV round them on float32 arrays."""
    gain, floor = np.float32(0.7 / 128.0), np.float32(0.3)
    zero, top = np.float32(0.0), np.float32(255.0)
    for i in range(image.shape[0]):
        value = image[i]
        sigma = np.sqrt(min(max(value, zero), top) * gain + floor)
        out[i] = np.uint8(np.rint(min(max(value + sigma * noise[i], zero), top)))


@njit(cache=True)
def nonzero_spans(rows, band, spans):  # pragma: no cover - compiled
    """Fills ``spans`` (B, 2) with the columns [first, last + 1) between which each ``band`` rows of ``rows``
    (H, W) hold their non-zero values (first = last + 1 where there are none)."""
    h, w = rows.shape
    for k in range(spans.shape[0]):
        first, stop = w, 0
        for v in range(k * band, min(k * band + band, h)):
            u = 0
            while u < first and rows[v, u] == 0.0:
                u += 1
            first = u
            u = w
            while u > stop and rows[v, u - 1] == 0.0:
                u -= 1
            stop = u
        spans[k, 0], spans[k, 1] = first, max(first, stop)
