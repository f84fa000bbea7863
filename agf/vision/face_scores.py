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
def _windows(
    image: NDArray, row: int, first_col: int, height: int, width: int, out: NDArray
) -> None:  # pragma: no cover - compiled
    """The sums of an integral ``image`` over ``height`` x ``width`` pixels from (``row``, ``first_col`` + i) into
    each ``out[i]``: a row of offsets at once, which the compiler vectorises."""
    for i in range(out.shape[0]):
        c = first_col + i
        out[i] = ((image[row + height, c + width] - image[row, c + width]) - image[row + height, c]) + image[row, c]


@njit(cache=True, error_model="numpy")
def correlation_scores(
    sums: NDArray, squares: NDArray, spans: NDArray, sizes: NDArray, corners: NDArray, weights: NDArray,
    centred: NDArray, norms: NDArray, out: NDArray,
) -> None:  # pragma: no cover - compiled
    """The raster's normalised correlation (OpenCV's ``TM_CCOEFF_NORMED``, 0 where the window is flat) at
    every offset of each scale: ``corners`` (S, K, 2) the raster's cell corners with a nonzero mixed second
    difference (row, column in px), ``weights`` (K,) that difference, ``centred`` (S,) the window corner
    cell's value less the raster's mean, ``norms`` (S,) the raster's norm about its mean."""
    widest = spans[:, 3].max() if spans.shape[0] else 0
    total, total_sq, numerator = np.empty(widest), np.empty(widest), np.empty(widest)
    for n in range(spans.shape[0]):
        first_row, first_col, rows, cols = spans[n]
        height, width = sizes[n]
        area = float(height * width)
        norm = max(norms[n], 1e-12)
        for r in range(first_row, first_row + rows):
            _windows(sums, r, first_col, height, width, total[:cols])
            _windows(squares, r, first_col, height, width, total_sq[:cols])
            for i in range(cols):
                numerator[i] = centred[n] * total[i]
            for k in range(weights.shape[0]):
                row, weight = sums[r + corners[n, k, 0]], weights[k]
                shift = first_col + corners[n, k, 1]
                for i in range(cols):
                    numerator[i] = row[shift + i] * weight + numerator[i]
            scores = out[n, r - first_row]
            for i in range(cols):
                variance = total_sq[i] - total[i] * total[i] / area
                score = numerator[i] / (np.sqrt(variance) * norm)
                # no variance beyond rounding: 0, as in OpenCV
                scores[i] = 0.0 if variance <= 1e-9 * total_sq[i] else min(max(score, -1.0), 1.0)


@njit(cache=True, error_model="numpy")
def region_scores(
    sums: NDArray, squares: NDArray, spans: NDArray, sizes: NDArray, bands: NDArray, out: NDArray
) -> None:  # pragma: no cover - compiled
    """The face's regions' ANOVA R^2 (:func:`~agf.vision.pallet_pose.region_match`) at every offset of each
    scale: ``bands`` (S, L, 4) each pocket band's first and past-last row and column in the window (px); an
    empty band is no region."""
    widest = spans[:, 3].max() if spans.shape[0] else 0
    total, total_sq, opened, between = np.empty(widest), np.empty(widest), np.empty(widest), np.empty(widest)
    band = np.empty((bands.shape[1], widest))  # each band's sums along a row of offsets
    inverse = np.empty(bands.shape[1])  # 1 / each band's area, 0 for an empty band
    for n in range(spans.shape[0]):
        first_row, first_col, rows, cols = spans[n]
        height, width = sizes[n]
        size = float(height * width)
        wood = size
        for k in range(bands.shape[1]):
            area = (bands[n, k, 1] - bands[n, k, 0]) * (bands[n, k, 3] - bands[n, k, 2])
            empty = bands[n, k, 1] <= bands[n, k, 0] or bands[n, k, 3] <= bands[n, k, 2]
            inverse[k] = 0.0 if empty else 1.0 / area
            wood -= 0 if empty else area
        for r in range(first_row, first_row + rows):
            _windows(sums, r, first_col, height, width, total[:cols])
            _windows(squares, r, first_col, height, width, total_sq[:cols])
            opened[:cols] = 0.0
            for k in range(bands.shape[1]):
                if inverse[k] > 0.0:
                    top, bottom, left, right = bands[n, k]
                    _windows(sums, r + top, first_col + left, bottom - top, right - left, band[k, :cols])
                    for i in range(cols):
                        opened[i] += band[k, i]
            # the regions' squared sums over their areas, the wood's first (as region_match sums them)
            for i in range(cols):
                region = total[i] - opened[i]
                between[i] = (1.0 / wood) * (region * region)
            for k in range(bands.shape[1]):
                if inverse[k] > 0.0:
                    for i in range(cols):
                        between[i] += inverse[k] * (band[k, i] * band[k, i])
            scores = out[n, r - first_row]
            for i in range(cols):
                mean_sq = total[i] * total[i] / size
                variance = total_sq[i] - mean_sq
                score = min(max((between[i] - mean_sq) / variance, 0.0), 1.0)
                scores[i] = 0.0 if variance <= 1e-9 * max(total_sq[i], 1e-30) else score  # no variance beyond rounding
