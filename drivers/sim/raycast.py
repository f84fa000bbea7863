"""Ray casting of boxes and planes through a camera model, tile by tile (the renderer's core).

Each pixel's sub-samples become rays (origins and directions from ``camera.unproject``, so the
viewpoint shift is exact); every object is intersected only by the rays of the tiles its projected
bounding rectangle touches. The nearest hit per ray keeps the object's index, the surface normal
and the hit point in the object's own frame, from which the shader computes colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agf.camera.base import CameraModel
from agf.geometry import Transform

Array = NDArray[np.float64]


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


def cast(objects: list[Box | Plane], origins: Array, directions: Array, candidates: list[int]) -> Hits:
    """Intersect rays (N, 3) with the objects whose indices are in ``candidates``."""
    n = len(origins)
    hits = Hits(np.full(n, np.inf), np.full(n, -1, np.int32), np.zeros((n, 3)), np.zeros((n, 3)))
    for i in candidates:
        obj = objects[i]
        R, c = obj.pose.rotation, obj.pose.translation
        o = (origins - c) @ R
        d = directions @ R
        if isinstance(obj, Plane):
            t, local_normal = _plane(o, d)
        else:
            t, local_normal = _box(o, d, obj.half)
        closer = t < hits.distance
        if not closer.any():
            continue
        hits.distance[closer] = t[closer]
        hits.index[closer] = i
        hits.normal[closer] = local_normal[closer] @ R.T
        hits.local[closer] = o[closer] + t[closer, None] * d[closer]
    return hits


def _plane(o: Array, d: Array) -> tuple[Array, Array]:
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[:, 2] / d[:, 2]
    t = np.where((t > 1e-6) & np.isfinite(t), t, np.inf)
    normal = np.zeros_like(o)
    normal[:, 2] = np.where(o[:, 2] >= 0, 1.0, -1.0)
    return t, normal


def _box(o: Array, d: Array, half: Array) -> tuple[Array, Array]:
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (-half - o) * inv
        t1 = (half - o) * inv
    near = np.minimum(t0, t1)
    far = np.maximum(t0, t1)
    near = np.where(np.isnan(near), -np.inf, near)
    far = np.where(np.isnan(far), np.inf, far)
    axis = np.argmax(near, axis=1)
    t_near = near[np.arange(len(o)), axis]
    t_far = np.min(far, axis=1)
    hit = (t_near <= t_far) & (t_near > 1e-6)
    normal = np.zeros_like(o)
    normal[np.arange(len(o)), axis] = -np.sign(d[np.arange(len(o)), axis])
    return np.where(hit, t_near, np.inf), normal


def screen_rectangles(camera: CameraModel, objects: list[Box | Plane], margin: float = 3.0) -> list[Array | None]:
    """Image rectangle (u0, v0, u1, v1) each box can cover, or None for 'anywhere' (planes, boxes
    reaching behind the lens)."""
    rects: list[Array | None] = []
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    s = np.linspace(0.0, 1.0, 9)[:, None]
    for obj in objects:
        if isinstance(obj, Plane):
            rects.append(None)
            continue
        c = corners * obj.half
        edges = np.concatenate([c[a] + s * (c[b] - c[a]) for a in range(8) for b in range(a + 1, 8)
                                if np.sum(corners[a] != corners[b]) == 1])
        pixels, valid = camera.project(obj.pose.apply(edges))
        if not valid.all():
            rects.append(None)
            continue
        rects.append(np.r_[pixels.min(axis=0) - margin, pixels.max(axis=0) + margin])
    return rects
