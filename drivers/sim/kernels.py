"""Compiled kernels of the renderers (numba): ray-box and ray-plane hits, nearest hits of many rays with
per-tile object lists, and the randomised look's shading (textures, lights, hard shadows, pocket
occlusion).

Objects are packed once per frame into arrays (:func:`pack_objects`): type (0 box, 1 plane), rotation
and centre (object to camera frame), half extents, and the packed :class:`~drivers.sim.textures.Style`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from drivers.sim.raycast import Box
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
def cast_tiled(origins, directions, tile_of, tile_start, tile_objs, kind, R, c, half,
               distance, index, face, local, normal):  # pragma: no cover - compiled
    """Nearest hits of rays (N, 3) against the objects listed for each ray's tile; fills the outputs
    (distance inf and index -1 for none; ``local`` in the object's frame, ``normal`` in the camera's)."""
    for i in range(origins.shape[0]):
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        best, best_k, best_f = math.inf, -1, 0
        tile = tile_of[i]
        for j in range(tile_start[tile], tile_start[tile + 1]):
            k = tile_objs[j]
            t, f = hit(k, kind, R, c, half, ox, oy, oz, dx, dy, dz)
            if t < best:
                best, best_k, best_f = t, k, f
        distance[i], index[i], face[i] = best, best_k, best_f
        if best_k < 0:
            continue
        px, py, pz = ox + best * dx - c[best_k, 0], oy + best * dy - c[best_k, 1], oz + best * dz - c[best_k, 2]
        for a in range(3):
            local[i, a] = R[best_k, 0, a] * px + R[best_k, 1, a] * py + R[best_k, 2, a] * pz
        sign = 1.0 if best_f % 2 == 1 else -1.0
        for a in range(3):
            normal[i, a] = sign * R[best_k, a, best_f // 2]


def tile_lists(rects: list, width: int, height: int, tile: int) -> tuple[NDArray, NDArray]:
    """CSR lists (start (T + 1,), objects) of the objects whose screen rectangle (None: anywhere) meets
    each ``tile`` x ``tile`` pixel tile, tiles row by row."""
    ntx, nty = -(-width // tile), -(-height // tile)
    lists: list[list[int]] = [[] for _ in range(ntx * nty)]
    for k, r in enumerate(rects):
        if r is None:
            x0, y0, x1, y1 = 0, 0, ntx - 1, nty - 1
        else:
            x0, y0 = max(int(r[0] // tile), 0), max(int(r[1] // tile), 0)
            x1, y1 = min(int(r[2] // tile), ntx - 1), min(int(r[3] // tile), nty - 1)
        for ty in range(y0, y1 + 1):
            for tx in range(x0, x1 + 1):
                lists[ty * ntx + tx].append(k)
    start = np.zeros(len(lists) + 1, np.int64)
    start[1:] = np.cumsum([len(v) for v in lists])
    objs = np.array([k for v in lists for k in v], np.int64)
    return start, objs


# -- randomised look: lights and shading ----------------------------------------------------------

LIGHT_FIELDS = 28  # type, power, colour 3, direction 3, position 3, reference distance, door, door 12, half 2,
# shadows


def pack_lights(lights: list, kind: NDArray, R: Array, c: Array, half: Array) -> tuple:
    """Packed lights (L, 27), their occluder grids (L, 13: view axis, e1, e2, x0, y0, cell, unused) and
    CSR occluder lists (start (L, GRID * GRID + 2), objects): each box is listed in the grid cells its
    outline covers seen from the light; the last cell holds boxes the view cannot bound."""
    packed = np.zeros((len(lights), LIGHT_FIELDS))
    grids = np.zeros((len(lights), 13))
    starts = np.zeros((len(lights), GRID * GRID + 2), np.int64)
    objs: list[int] = []
    boxes = np.flatnonzero(kind == 0)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    for n, light in enumerate(lights):
        sun = light.direction is not None
        row = [0.0 if sun else 1.0, light.power, *light.colour]
        row += list(light.direction if sun else np.zeros(3)) + list(light.position if not sun else np.zeros(3))
        row += [light.reference_distance, 1.0 if light.door is not None else 0.0]
        row += [*np.concatenate(light.door[:4]), *light.door[4:]] if light.door is not None else [0.0] * 14
        packed[n] = [*row, float(light.shadows)]
        # the view: along the sun, or down from the lamp
        axis = np.asarray(light.direction, float) if sun else light.down
        axis = axis / np.linalg.norm(axis)
        e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        rects = []
        for k in boxes:
            corners = (signs * half[k]) @ R[k].T + c[k]
            w = corners if sun else corners - light.position
            depth = np.ones(8) if sun else w @ axis
            ok = sun or bool(np.all(depth > 0.05 * np.linalg.norm(w, axis=1)))
            rects.append(np.r_[(w @ e1 / depth).min(), (w @ e2 / depth).min(), (w @ e1 / depth).max(),
                               (w @ e2 / depth).max()] if ok else None)
        finite = np.array([r for r in rects if r is not None]).reshape(-1, 4)
        x0, y0 = (finite[:, 0].min(), finite[:, 1].min()) if len(finite) else (0.0, 0.0)
        size = max(finite[:, 2].max() - x0, finite[:, 3].max() - y0, 1e-6) if len(finite) else 1.0
        cell = size / GRID * (1 + 1e-9)
        grids[n] = [*axis, *e1, *e2, x0, y0, cell, 0.0]
        cells: list[list[int]] = [[] for _ in range(GRID * GRID + 1)]
        for k, r in zip(boxes, rects, strict=True):
            if r is None:
                for v in cells:
                    v.append(int(k))
                continue
            i0, j0 = int((r[0] - x0) // cell), int((r[1] - y0) // cell)
            i1, j1 = min(int((r[2] - x0) // cell), GRID - 1), min(int((r[3] - y0) // cell), GRID - 1)
            for j in range(max(j0, 0), j1 + 1):
                for i in range(max(i0, 0), i1 + 1):
                    cells[j * GRID + i].append(int(k))
        starts[n, 0] = len(objs)
        for m, v in enumerate(cells):
            objs.extend(v)
            starts[n, m + 1] = len(objs)
    return packed, grids, starts, np.array(objs, np.int64)


@njit(cache=True)
def shade_look(origins, directions, distance, normals, local, index, kind, R, c, half, style, lights, grids,
               starts, objs, pallets, ambient, sky, out):  # pragma: no cover - compiled
    """Colour (N, 3, 0..255 before exposure) of the hits of rays: texture x (ambient + lights, each Lambertian,
    lamps falling off with distance, zero in shadow or outside a door's patch) x pocket occlusion;
    ``sky`` where nothing was hit. ``pallets`` (P, 16): rotation (9), centre (3), length, width, pocket
    height, deck bottom."""
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
            e = _light(n, px, py, pz, nx, ny, nz, lights, grids, starts, objs, kind, R, c, half)
            eb += e * lights[n, 2]
            eg += e * lights[n, 3]
            er += e * lights[n, 4]
        occlusion = _pocket_occlusion(px, py, pz, pallets)
        out[i, 0] = 255.0 * b * eb * occlusion
        out[i, 1] = 255.0 * g * eg * occlusion
        out[i, 2] = 255.0 * r * er * occlusion


@njit(cache=True, inline="always")
def _light(n, px, py, pz, nx, ny, nz, lights, grids, starts, objs, kind, R, c, half):  # pragma: no cover
    """Irradiance light ``n`` gives a point with a normal (see :func:`shade_look`)."""
    L = lights[n]  # a view; this function is inlined (array arguments cost reference counting per call)
    if L[0] == 0.0:
        wx, wy, wz, reach, falloff = L[5], L[6], L[7], math.inf, 1.0
    else:
        wx, wy, wz = L[8] - px, L[9] - py, L[10] - pz
        reach = math.sqrt(wx * wx + wy * wy + wz * wz)
        wx, wy, wz = wx / reach, wy / reach, wz / reach
        falloff = (L[11] / max(reach, 0.3)) ** 2
    cosine = nx * wx + ny * wy + nz * wz
    if cosine <= 0:
        return 0.0
    ox, oy, oz = px + SHADOW_BIAS * nx, py + SHADOW_BIAS * ny, pz + SHADOW_BIAS * nz
    if L[12] > 0:  # a door the sun shines through: lit only where the ray passes its opening
        denom = wx * L[16] + wy * L[17] + wz * L[18]
        if denom != 0:
            t = ((L[13] - ox) * L[16] + (L[14] - oy) * L[17] + (L[15] - oz) * L[18]) / denom
            if t > 0:
                qx, qy, qz = ox + t * wx - L[13], oy + t * wy - L[14], oz + t * wz - L[15]
                if abs(qx * L[19] + qy * L[20] + qz * L[21]) >= L[25]:
                    return 0.0
                if abs(qx * L[22] + qy * L[23] + qz * L[24]) >= L[26]:
                    return 0.0
    if L[27] == 0.0:
        return L[1] * cosine * falloff
    G = grids[n]
    if L[0] == 0.0:
        vx, vy, depth = px * G[3] + py * G[4] + pz * G[5], px * G[6] + py * G[7] + pz * G[8], 1.0
    else:
        ax, ay, az = px - L[8], py - L[9], pz - L[10]
        depth = ax * G[0] + ay * G[1] + az * G[2]
        vx, vy = ax * G[3] + ay * G[4] + az * G[5], ax * G[6] + ay * G[7] + az * G[8]
        if depth <= 0.05 * math.sqrt(ax * ax + ay * ay + az * az):
            depth = -1.0
    cell = GRID * GRID  # outside the grid: only the boxes the view cannot bound
    if depth > 0:
        ci, cj = math.floor((vx / depth - G[9]) / G[11]), math.floor((vy / depth - G[10]) / G[11])
        if 0 <= ci < GRID and 0 <= cj < GRID:
            cell = cj * GRID + ci
    for j in range(starts[n, cell], starts[n, cell + 1]):
        t, _ = hit(objs[j], kind, R, c, half, ox, oy, oz, wx, wy, wz)
        if t < reach:
            return 0.0
    return L[1] * cosine * falloff


@njit(cache=True, inline="always")
def _pocket_occlusion(px, py, pz, pallets):  # pragma: no cover - compiled
    """Ambient occlusion inside pockets: surfaces behind the front face, under the deck, grow dark."""
    factor = 1.0
    for m in range(pallets.shape[0]):
        P = pallets[m]
        dx, dy, dz = px - P[9], py - P[10], pz - P[11]
        x = P[0] * dx + P[3] * dy + P[6] * dz
        y = P[1] * dx + P[4] * dy + P[7] * dz
        z = P[2] * dx + P[5] * dy + P[8] * dz
        if 0.002 < x < P[12] and abs(y) < P[13] / 2 and z < P[14] / 2 - 1e-4 and z > P[15] - 0.01:
            factor *= 0.12 + 0.3 * math.exp(-x / 0.03)
    return factor
