"""The pose scan's two face similarities at every offset of a virtual view, compiled.

Both are a few integral-image lookups per offset (:mod:`agf.vision.pallet_pose` explains each); in numpy
they cost one call per lookup and operation for every scale, and the 20 scales of a yaw hold about 3,000
offsets each, so the calls cost more than their arithmetic (a refused campaign frame matched 15,000
scales). Here one call scores every scale of a yaw, offset by offset, with the numpy version's operations
in the same order.

Shapes: ``sums``, ``squares`` (H + 1, W + 1) float64 integral images of the view and of its squares;
``spans`` (S, 4) int: per scale the first offset (row, column) and how many rows and columns of offsets
are scored; ``sizes`` (S, 2) int: the face raster's height and width at that scale (px); ``out``
(S, R, C) float32, whose first rows and columns of each scale receive the scores.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, inline="always")
def _window(image: NDArray, top: int, left: int, height: int, width: int) -> float:  # pragma: no cover - compiled
    """The sum of an integral ``image`` over ``height`` x ``width`` pixels from (``top``, ``left``)."""
    return ((image[top + height, left + width] - image[top, left + width]) - image[top + height, left]) + image[
        top, left
    ]


@njit(cache=True)
def correlation_scores(
    sums: NDArray, squares: NDArray, spans: NDArray, sizes: NDArray, corners: NDArray, weights: NDArray,
    centred: NDArray, norms: NDArray, out: NDArray,
) -> None:  # pragma: no cover - compiled
    """The raster's normalised correlation (OpenCV's ``TM_CCOEFF_NORMED``, 0 where the window is flat) at
    every offset of each scale: ``corners`` (S, K, 2) the raster's cell corners with a nonzero mixed second
    difference (row, column in px), ``weights`` (K,) that difference, ``centred`` (S,) the window corner
    cell's value less the raster's mean, ``norms`` (S,) the raster's norm about its mean."""
    for n in range(spans.shape[0]):
        first_row, first_col, rows, cols = spans[n]
        height, width = sizes[n]
        area = float(height * width)
        norm = max(norms[n], 1e-12)
        for r in range(first_row, first_row + rows):
            for c in range(first_col, first_col + cols):
                total = _window(sums, r, c, height, width)
                total_sq = _window(squares, r, c, height, width)
                numerator = centred[n] * total
                for k in range(weights.shape[0]):
                    numerator = sums[r + corners[n, k, 0], c + corners[n, k, 1]] * weights[k] + numerator
                variance = total_sq - total * total / area
                if variance <= 1e-9 * total_sq:  # no variance beyond rounding: 0, as in OpenCV
                    out[n, r - first_row, c - first_col] = 0.0
                else:
                    score = numerator / (np.sqrt(variance) * norm)
                    out[n, r - first_row, c - first_col] = min(max(score, -1.0), 1.0)


@njit(cache=True)
def region_scores(
    sums: NDArray, squares: NDArray, spans: NDArray, sizes: NDArray, bands: NDArray, out: NDArray
) -> None:  # pragma: no cover - compiled
    """The face's regions' ANOVA R^2 (:func:`~agf.vision.pallet_pose.region_match`) at every offset of each
    scale: ``bands`` (S, L, 4) each pocket band's first and past-last row and column in the window (px); an
    empty band is no region."""
    inverse = np.zeros(bands.shape[1] + 1)  # 1 / each region's area, the wood's first; 0: an empty band
    region = np.zeros(bands.shape[1] + 1)  # each region's sum at one offset
    for n in range(spans.shape[0]):
        first_row, first_col, rows, cols = spans[n]
        height, width = sizes[n]
        size = float(height * width)
        opened = 0
        for k in range(bands.shape[1]):
            top, bottom, left, right = bands[n, k]
            area = (bottom - top) * (right - left) if bottom > top and right > left else 0
            inverse[k + 1] = 1.0 / area if area > 0 else 0.0
            opened += area
        inverse[0] = 1.0 / (size - opened) if size > opened else 0.0
        for r in range(first_row, first_row + rows):
            for c in range(first_col, first_col + cols):
                total = _window(sums, r, c, height, width)
                total_sq = _window(squares, r, c, height, width)
                in_bands = 0.0
                counted = 0
                for k in range(bands.shape[1]):
                    if inverse[k + 1] > 0.0:
                        top, bottom, left, right = bands[n, k]
                        region[k + 1] = _window(sums, r + top, c + left, bottom - top, right - left)
                        in_bands = region[k + 1] if counted == 0 else in_bands + region[k + 1]
                        counted += 1
                region[0] = total - in_bands
                between = 0.0
                for k in range(bands.shape[1] + 1):
                    if inverse[k] > 0.0:
                        between += inverse[k] * (region[k] * region[k])
                mean_sq = total * total / size
                between -= mean_sq
                variance = total_sq - mean_sq
                if variance <= 1e-9 * max(total_sq, 1e-30):  # no variance beyond rounding
                    out[n, r - first_row, c - first_col] = 0.0
                else:
                    out[n, r - first_row, c - first_col] = min(max(between / variance, 0.0), 1.0)
