"""Ray casting of boxes and planes through a camera model, band by band (the renderer's core).

Each pixel's sub-samples become rays (origins and directions from ``camera.unproject``, so the
viewpoint shift is exact); every object is intersected only by the rays whose pixels lie in its
projected bounding rectangle. The nearest hit per ray keeps the object's index, the surface normal
and the hit point in the object's own frame, from which the shader computes colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agf.camera.base import CameraModel
from agf.geometry import Transform

Array = NDArray[np.float64]
CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)  # of a box, in halves
_EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8)
                   if np.sum(CORNERS[a] != CORNERS[b]) == 1])  # (12, 2): the corners each box edge joins
_ALONG = np.linspace(0.0, 1.0, 9)[:, None]  # (9, 1): where :func:`screen_rectangles` samples an edge


@dataclass(frozen=True)
class Box:
    """An oriented box: ``pose`` maps box coordinates (centred, axis-aligned) to the camera frame."""

    pose: Transform
    half: Array  # half extents (3,), m
    material: str
    name: str = ""


@dataclass(frozen=True)
class Plane:
    """An infinite plane ``{p : normal . p = offset}`` (camera frame), with a frame for its texture."""

    pose: Transform  # plane frame in camera: z is the normal, origin on the plane
    material: str
    name: str = ""


@dataclass
class Hits:
    """Nearest hits of N rays: distance (inf for none), object index, normal and local point."""

    distance: Array
    index: NDArray[np.int32]
    normal: Array
    local: Array


def cast(objects: list[Box | Plane], origins: Array, directions: Array, pixels: Array, rects: list) -> Hits:
    """Nearest hits of rays (N, 3) cast through image positions ``pixels`` (N, 2).

    An object is intersected only by the rays whose pixel lies in its screen rectangle ``rects[i]``
    (None: all rays), so the cost grows with the area objects cover, not with their number.
    """
    # (3, N) layout: the per-object rotation becomes one BLAS product on contiguous rows
    all_o, all_d = np.ascontiguousarray(origins.T, np.float32), np.ascontiguousarray(directions.T, np.float32)
    distance, index, face = nearest(objects, all_o, all_d, pixels, rects)
    return _surface(objects, all_o, all_d, distance, index, face)


def nearest(objects: list[Box | Plane], all_o: NDArray, all_d: NDArray, pixels: Array, rects: list) -> tuple:
    """Distance (N,), object index (N,, -1 for none) and face code (N,) of the nearest hits of rays given
    as (3, N) float32 arrays; ``pixels`` (N, 2) are any 2-D coordinates in which ``rects`` bound the objects."""
    n = all_o.shape[1]
    distance, index, face = np.full(n, np.inf), np.full(n, -1, np.int32), np.zeros(n, np.int8)
    for i, obj in enumerate(objects):
        rect = rects[i]
        if rect is None:
            rows, o, d = slice(None), all_o, all_d
        else:
            u, v = pixels[:, 0], pixels[:, 1]
            rows = np.flatnonzero((u >= rect[0]) & (u <= rect[2]) & (v >= rect[1]) & (v <= rect[3]))
            if not rows.size:
                continue
            o, d = all_o[:, rows], all_d[:, rows]
        R, c = obj.pose.rotation.astype(np.float32), obj.pose.translation.astype(np.float32)
        o = R.T @ (o - c[:, None])
        d = R.T @ d
        t, f = _plane(o, d) if isinstance(obj, Plane) else _box(o, d, obj.half.astype(np.float32))
        closer = t < distance[rows]
        rows = np.flatnonzero(closer) if rect is None else rows[closer]
        distance[rows], index[rows], face[rows] = t[closer], i, f[closer]
    return distance, index, face


def _surface(objects: list, origins: Array, directions: Array, distance: Array, index: NDArray, face: NDArray) -> Hits:
    """Camera-frame normals and object-frame points of the nearest hits of rays given as (3, N) arrays;
    ``face`` = 2 * axis + (sign > 0)."""
    n = origins.shape[1]
    normal, local = np.zeros((n, 3)), np.zeros((n, 3))
    order = np.argsort(index, kind="stable")  # group rays by object in one sort, not one scan per object
    ids, starts = np.unique(index[order], return_index=True)
    for i, rows in zip(ids, np.split(order, starts[1:]), strict=True):
        if i < 0:
            continue
        R, c = objects[i].pose.rotation, objects[i].pose.translation
        local[rows] = (R.T @ (origins[:, rows] - c[:, None] + distance[rows] * directions[:, rows])).T
        axis = face[rows] // 2
        local_normal = np.zeros((len(rows), 3))
        local_normal[np.arange(len(rows)), axis] = np.where(face[rows] % 2 == 1, 1.0, -1.0)
        normal[rows] = local_normal @ R.T
    return Hits(distance, index, normal, local)


def _plane(o: Array, d: Array) -> tuple[Array, NDArray[np.int8]]:
    """Distance along rays (3, N layout, plane frame) to the plane z = 0, and the face code of its normal."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[2]
    t = np.where((t > 1e-6) & np.isfinite(t), t, np.inf)
    return t, np.where(o[2] >= 0, 5, 4).astype(np.int8)


def _box(o: Array, d: Array, half: Array) -> tuple[Array, NDArray[np.int8]]:
    """Slab test of rays (3, N layout, box frame) against the box ``|p| <= half``: entry distance and face."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (-half[:, None] - o) * inv
        t1 = (half[:, None] - o) * inv
    # fmin/fmax drop the NaN of a ray lying exactly in a slab's bounding plane (0 * inf)
    near = np.fmin(t0, t1)
    t_near = near.max(axis=0)
    hit = (t_near <= np.fmax(t0, t1).min(axis=0)) & (t_near > 1e-6)
    cols = np.flatnonzero(hit)
    axis = np.argmax(near[:, cols], axis=0)
    face = np.zeros(o.shape[1], np.int8)
    # the entry face's outward normal opposes the ray
    face[cols] = 2 * axis + (d[axis, cols] < 0)
    return np.where(hit, t_near, np.inf), face


def screen_rectangles(camera: CameraModel, objects: list[Box | Plane], margin: float = 3.0) -> list[Array | None]:
    """Image rectangle (u0, v0, u1, v1) each box can cover, or None for 'anywhere' (planes, boxes
    reaching behind the lens)."""
    rects: list[Array | None] = []
    for obj in objects:
        if isinstance(obj, Plane):
            rects.append(None)
            continue
        c = CORNERS * obj.half
        edges = (c[_EDGES[:, :1]] + _ALONG * (c[_EDGES[:, 1:]] - c[_EDGES[:, :1]])).reshape(-1, 3)
        pixels, valid = camera.project(obj.pose.apply(edges))
        if not valid.all():
            rects.append(None)
            continue
        rects.append(np.r_[pixels.min(axis=0) - margin, pixels.max(axis=0) + margin])
    return rects
