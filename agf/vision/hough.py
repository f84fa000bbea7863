"""Hough transform on the viewing sphere for lines parallel to a panorama's axis (paper section III).

A 3D line seen from the viewpoint images as a great circle; the great circles of lines parallel to
the panorama axis are its meridians, i.e. panorama columns. A line a few degrees off that direction
is a great circle crossing the equator at longitude ``phi`` with inclination ``tau`` to the
meridian there. Each edge point votes, for every ``tau``, for the ``phi`` of the great circle through
it; the peak is the line, refined by a least-squares plane fit through its inlier directions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from agf.vision.panorama import Panorama

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SphereLine:
    """A great circle (the image of a 3D line through the viewpoint) and its support.

    Attributes
    ----------
    normal : (3,) array
        Unit normal of the great circle's plane, camera frame.
    score : float
        Hough score: the summed weights of its inlier edge points (panorama rows they cover).
    inliers : (N,) bool array
        Which of the edge points given lie on it.
    """

    normal: Array
    score: float
    inliers: NDArray[np.bool_]


def circle_normal(panorama: Panorama, phi: float, tau: float) -> Array:
    """Normal (3,) of the great circle crossing the equator at longitude ``phi`` with inclination ``tau``."""
    e1, e2, axis = panorama.basis()
    radial = math.cos(phi) * e1 + math.sin(phi) * e2
    tangent = math.cos(tau) * axis + math.sin(tau) * (-math.sin(phi) * e1 + math.cos(phi) * e2)
    normal = np.cross(radial, tangent)
    return normal / np.linalg.norm(normal)


def hough_line(
    panorama: Panorama,
    directions: Array,
    weights: Array,
    phi_range: tuple[float, float],
    tau_max: float = math.radians(10.0),
    tau_step: float = math.radians(0.1),
    tolerance: float | None = None,
    peaks: int = 3,
) -> SphereLine | None:
    """The dominant great circle through edge ``directions`` (N, 3) near the meridians in ``phi_range``: of the
    fits from ``peaks`` peaks of the accumulator, each taken after the votes of the lines fitted before are
    removed, the one with the most support within ``tolerance``.

    ``tolerance`` (rad) is the inlier distance from the circle, default 1.5 panorama pixels. The accumulator sums
    each bin with its neighbours, so a band of texture a few pixels wide (wood grain, a carton's print) can
    outvote a sharp edge there while its own best fit holds fewer points: a load edge scoring 103 points lost to
    such a band's 79 after the pose moved 1 mm (random look 1 of paper scene loaded-high-flat).
    """
    if len(directions) < 3:
        return None
    tolerance = tolerance if tolerance is not None else 1.5 * panorama.pixel_size()
    local = directions @ panorama.basis().T
    lon = np.arctan2(local[:, 1], local[:, 0])
    lat = np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1]))
    taus = np.arange(-tau_max, tau_max + tau_step / 2, tau_step)
    # The circle of inclination tau through (lon, lat) crosses the equator at lon - atan(tan(s) sin(tau)),
    # s being the arc from the equator: sin(lat) = sin(s) cos(tau).
    # The (taus, N) steps in place, in one buffer: the pitch search calls this 1,400 times over the bench's 34
    # frames, and the temporaries cost a fifth of its time.
    sin_lat = np.sin(lat)
    phis = np.cos(taus)[:, None] ** 2 - sin_lat[None, :] ** 2
    np.sqrt(np.maximum(phis, 1e-12, out=phis), out=phis)
    np.divide(sin_lat[None, :], phis, out=phis)  # tan(s)
    phis *= np.sin(taus)[:, None]
    np.subtract(lon[None, :], np.arctan(phis, out=phis), out=phis)
    bin_width = panorama.pixel_size()
    edges = np.arange(phi_range[0], phi_range[1] + bin_width, bin_width)
    if edges.size < 2:
        return None
    shape = (len(taus), edges.size - 1)
    bins = _accumulator_bins(phis, edges[0], bin_width, shape[1])
    weights = np.asarray(weights, dtype=np.float64)

    def votes(points: NDArray[np.int64]) -> Array:
        """The accumulator (taus, bins) of the edge points ``points`` (indices)."""
        return _votes(bins, weights, points, shape[0] * shape[1]).reshape(shape)

    raw = votes(np.arange(len(directions)))
    fits: list[SphereLine] = []
    for _ in range(peaks):
        summed = raw.copy()  # each bin with its two neighbours: a line's votes straddle bin borders
        summed[:, 1:] += raw[:, :-1]
        summed[:, :-1] += raw[:, 1:]
        t_index, p_index = np.unravel_index(np.argmax(summed), shape)
        # A line's points within the tolerance vote in the three bins around its cell: a peak no stronger than the
        # best fit so far holds no better line (most frames stop here after one fit).
        if summed[t_index, p_index] <= max((fit.score for fit in fits), default=0.0):
            break
        # The circle starts from the middle of the three bins and from the strongest of them, and the better
        # fit is kept: between two lines three bins apart the middle bin may be empty and no point lies near
        # its circle (random look 0 of paper scene loaded-middle-flat lost a load edge), while a line straddling
        # two bins is best fitted from the middle (the real lens's unloaded frame lost a deck edge otherwise).
        window = np.arange(max(p_index - 1, 0), min(p_index + 2, shape[1]))
        starts = sorted({int(p_index), int(window[np.argmax(raw[t_index, window])])})
        found = [refine_line(directions, weights, circle_normal(panorama, 0.5 * (edges[p] + edges[p + 1]),
                                                                taus[t_index]), tolerance) for p in starts]
        found = [fit for fit in found if fit is not None]
        if not found:
            raw[t_index, window] = 0.0
            continue
        best = max(found, key=lambda fit: fit.score)
        fits.append(best)
        # The next peak among the votes of the points not on this line: one line's votes form a ridge of cells
        # (its circle's neighbours in inclination cross the equator beside it), which would be the next peaks.
        raw -= votes(np.flatnonzero(best.inliers))
        np.maximum(raw, 0.0, out=raw)
    return max(fits, key=lambda fit: fit.score) if fits else None


@njit(cache=True)
def _accumulator_bins(phis: Array, start: float, width: float, count: int) -> NDArray[np.int64]:  # pragma: no cover
    """The accumulator cell (tau row * ``count`` + phi bin) of each (tau, point) crossing ``phis`` (taus, N), rad:
    bins ``width`` wide from ``start``; -1 outside the ``count`` bins. numpy's steps (subtract, divide, floor) in
    one pass without their (taus, N) temporaries."""
    out = np.empty(phis.shape, np.int64)
    for i in range(phis.shape[0]):
        for j in range(phis.shape[1]):
            q = (phis[i, j] - start) / width
            out[i, j] = i * count + math.floor(q) if 0.0 <= q < count else -1
    return out


@njit(cache=True)
def _votes(bins: NDArray[np.int64], weights: Array, points: NDArray[np.int64], cells: int) -> Array:  # pragma: no cover
    """The ``weights`` (N,) of ``points`` summed into their ``bins`` (taus, N; -1: none) of ``cells`` accumulator cells,
    tau row by tau row in the order of ``points``: the order, and so the sums, of numpy's bincount over them."""
    out = np.zeros(cells)
    for i in range(bins.shape[0]):
        for j in points:
            if bins[i, j] >= 0:
                out[bins[i, j]] += weights[j]
    return out


def refine_line(directions: Array, weights: Array, normal: Array, tolerance: float) -> SphereLine | None:
    """The great circle near ``normal`` fitted to the edge ``directions`` (N, 3) within ``tolerance`` (rad)
    of it, in three rounds of least squares; None when fewer than 3 points are that close."""
    for _ in range(3):
        inliers = np.abs(directions @ normal) < tolerance
        if inliers.sum() < 3:
            return None
        normal = fit_plane_normal(directions[inliers], weights[inliers], normal)
    inliers = np.abs(directions @ normal) < tolerance
    return SphereLine(normal, float(np.sum(weights[inliers])), inliers)


def fit_plane_normal(directions: Array, weights: Array, reference: Array) -> Array:
    """Least-squares normal of the plane through the origin closest to weighted unit directions."""
    scatter = (directions * weights[:, None]).T @ directions
    _, vectors = np.linalg.eigh(scatter)
    normal = vectors[:, 0]
    return normal if normal @ reference >= 0 else -normal


def common_direction(normal_a: Array, normal_b: Array, predicted: Array) -> Array:
    """The direction shared by two parallel 3D lines: orthogonal to both circle normals, signed like ``predicted``."""
    direction = np.cross(normal_a, normal_b)
    norm = np.linalg.norm(direction)
    if norm < 1e-9:
        raise ValueError("the two lines lie on one great circle; their common direction is undefined")
    direction /= norm
    return direction if direction @ predicted >= 0 else -direction
