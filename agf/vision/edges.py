"""Sub-pixel edge search along given normals in an image (the measurement step of model fitting)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from agf.camera.base import CameraModel
from agf.geometry import Transform

Array = NDArray[np.float64]


@dataclass(frozen=True)
class EdgeSearch:
    """Result of :func:`search_edges` for N points.

    Attributes
    ----------
    offset : (N,) array
        Signed distance (px) from each start point along its normal to the strongest edge.
    strength : (N,) array
        Intensity step across that edge (grey levels per px, positive for the expected polarity).
    valid : (N,) bool array
        A usable edge was found inside the search range.
    """

    offset: Array
    strength: Array
    valid: NDArray[np.bool_]


def search_edges(
    image: NDArray[np.float32],
    starts: Array,
    normals: Array,
    radius: float,
    step: float = 0.25,
    *,
    either_polarity: bool = False,
) -> EdgeSearch:
    """Find, along each unit image normal (N, 2), the strongest bright-to-dark step within ``radius`` px
    (with ``either_polarity``, the strongest step of either sign: which side is brighter depends on light).

    The profile is sampled bilinearly (``cv2.remap``) from ``image`` (smooth it first), differentiated,
    and the extremum refined by a parabola through its neighbours.
    """
    t = np.arange(-radius, radius + step / 2, step, dtype=np.float64)
    u = (starts[:, 0:1] + normals[:, 0:1] * t).astype(np.float32)
    v = (starts[:, 1:2] + normals[:, 1:2] * t).astype(np.float32)
    profile = cv2.remap(image, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
    slope = -np.gradient(profile, step, axis=1)  # positive where intensity falls along the normal
    if either_polarity:
        slope = np.abs(slope)
    best = np.argmax(slope[:, 1:-1], axis=1) + 1  # an extremum on the border is no edge
    rows = np.arange(len(best))
    inner = (best > 0) & (best < len(t) - 1)
    left = slope[rows, np.clip(best - 1, 0, None)]
    centre = slope[rows, best]
    right = slope[rows, np.clip(best + 1, None, len(t) - 1)]
    curvature = left - 2 * centre + right
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(inner & (curvature < 0), 0.5 * (left - right) / curvature, 0.0)
    inside = (u >= 0) & (v >= 0) & (u <= image.shape[1] - 1) & (v <= image.shape[0] - 1)
    valid = inner & np.all(inside, axis=1) & (centre > np.maximum(slope[:, 0], slope[:, -1]))
    return EdgeSearch(t[best] + shift * step, np.where(valid, centre, 0.0), valid)


def project_with_normals(
    camera: CameraModel, model_in_camera: Transform, points: Array, normals: Array
) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Pixels (N, 2) of model points (N, 3), the unit image directions (N, 2) of their model normals
    (N, 3), and which points project validly: where and along what to look for each model edge."""
    p0, valid = camera.project(model_in_camera.apply(points))
    p1, _ = camera.project(model_in_camera.apply(points + 0.003 * normals))  # 3 mm along the normal
    direction = p1 - p0
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    return p0, direction, valid
