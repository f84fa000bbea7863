"""The viewpoint shift of a fisheye lens (paper section IV.B).

The entrance pupil of a wide-angle lens moves along the optical axis with the incidence angle: a ray
at 80 deg enters about 10 mm further forward than one at 45 deg. The curve is zero at the reference
angle (45 deg), where the reference viewpoint, the origin of the camera frame, sits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

REFERENCE_ANGLE = math.radians(45.0)


@dataclass(frozen=True, eq=False)
class ViewpointShift:
    """Forward offset of the entrance pupil (m) as a function of the incidence angle (rad).

    Either a table (``angles`` rad, ``offsets`` m, interpolated by a cubic Hermite spline so the
    derivative exists for the projection solver) or a polynomial in ``theta - reference`` (m per
    rad^k, lowest order first).
    """

    angles: NDArray[np.float64] | None = None
    offsets: NDArray[np.float64] | None = None
    poly: NDArray[np.float64] | None = None
    reference: float = REFERENCE_ANGLE
    _slopes: NDArray[np.float64] | None = field(default=None, init=False, repr=False)  # the table's tangents
    # each interval's quadratic and cubic coefficients, made once: the spline is evaluated five times a projection
    _cubic: tuple[NDArray[np.float64], NDArray[np.float64]] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if (self.poly is None) == (self.angles is None):
            raise ValueError("viewpoint shift: give either a table (angles and offsets) or a polynomial")
        if self.poly is not None:
            poly = np.asarray(self.poly, dtype=float).ravel()
            if poly.size == 0 or not np.all(np.isfinite(poly)):
                raise ValueError(f"viewpoint shift: polynomial must be finite numbers, got {self.poly}")
            object.__setattr__(self, "poly", poly)
            return
        angles = np.asarray(self.angles, dtype=float).ravel()
        offsets = np.asarray(self.offsets, dtype=float).ravel()
        if angles.size < 2 or angles.size != offsets.size:
            raise ValueError(
                "viewpoint shift table: need at least 2 angles and as many offsets, "
                f"got {angles.size} and {offsets.size}"
            )
        if not (np.all(np.isfinite(angles)) and np.all(np.isfinite(offsets))):
            raise ValueError("viewpoint shift table: angles and offsets must be finite")
        if np.any(np.diff(angles) <= 0):
            raise ValueError("viewpoint shift table: angles must increase strictly")
        object.__setattr__(self, "angles", angles)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "_slopes", np.gradient(offsets, angles))
        object.__setattr__(self, "_cubic", _hermite_cubic(angles, offsets, self._slopes))

    def offset(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Pupil offset along the optical axis (m, forward positive) at incidence ``theta`` (rad)."""
        return self.offset_and_derivative(theta)[0]

    def derivative(self, theta: ArrayLike) -> NDArray[np.float64]:
        """d offset / d theta (m/rad)."""
        return self.offset_and_derivative(theta)[1]

    def offset_and_derivative(self, theta: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`offset` and :meth:`derivative` in one evaluation (the projection's Newton solve needs both)."""
        theta = np.asarray(theta, dtype=float)
        if self.poly is not None:
            t = theta - self.reference
            value = np.polynomial.polynomial.polyval(t, self.poly)
            slope = np.polynomial.polynomial.polyval(t, np.polynomial.polynomial.polyder(self.poly))
            return value, slope
        return _hermite(self.angles, self.offsets, self._slopes, self._cubic, theta)


def _hermite_cubic(
    x: NDArray[np.float64], y: NDArray[np.float64], slopes: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The quadratic and cubic coefficients (K - 1,) of each interval's cubic Hermite polynomial in
    ``u = t - x[i]`` through the points (``x``, ``y``) (K,) with tangents ``slopes`` (K,)."""
    h = np.diff(x)
    dy = np.diff(y) / h
    return (3 * dy - 2 * slopes[:-1] - slopes[1:]) / h, (slopes[:-1] + slopes[1:] - 2 * dy) / h**2


def _hermite(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    slopes: NDArray[np.float64],
    cubic: tuple[NDArray[np.float64], NDArray[np.float64]],
    t: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Cubic Hermite interpolation with tangents ``slopes`` (finite differences), linear beyond the ends.

    Each interval's cubic (its coefficients ``cubic`` from :func:`_hermite_cubic`) is evaluated in Horner
    form in ``u = t - x[i]`` (the projection's Newton solve calls this five times a projection, the
    Hermite basis in ``s`` took 10 % of a measurement).
    """
    c2, c3 = cubic
    tc = np.clip(t, x[0], x[-1])
    i = np.clip(np.searchsorted(x, tc) - 1, 0, x.size - 2)
    u = tc - x[i]
    a, b, c = c3[i], c2[i], slopes[:-1][i]
    value = ((a * u + b) * u + c) * u + y[i]
    slope = (3 * a * u + 2 * b) * u + c
    below, above = t < x[0], t > x[-1]
    if below.any() or above.any():
        value = np.where(below, y[0] + slopes[0] * (t - x[0]), np.where(above, y[-1] + slopes[-1] * (t - x[-1]), value))
        slope = np.where(below, slopes[0], np.where(above, slopes[-1], slope))
    return value, slope
