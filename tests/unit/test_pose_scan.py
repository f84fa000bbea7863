"""The pose scan's local maxima, found for all scales at once (:func:`_best_maxima`), equal those found
scale by scale: the padding between the stacked scales keeps every neighbourhood within its own."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from agf.vision.pallet_pose import _NEIGHBOURS, _best_maxima


def one_by_one(stack, inner, count):
    found = []
    for n, (response, mask) in enumerate(zip(stack, inner, strict=True)):
        local_max = response >= cv2.dilate(response, _NEIGHBOURS)
        r, c = np.nonzero(local_max & mask & (response > 0.2))
        order = np.argsort(-response[r, c], kind="stable")[:count]
        found += [(n, int(r[i]), int(c[i]), float(response[r[i], c[i]])) for i in order]
    return found


@pytest.mark.parametrize("seed", range(5))
def test_stacked_maxima_equal_the_maxima_of_each_scale(seed):
    rng = np.random.default_rng(seed)
    slices, rows, cols = 7, 24, 19
    stack = np.full((slices, rows + 2, cols), -2.0, np.float32)
    inner = np.zeros(stack.shape, bool)
    for n in range(slices):
        h, w = rng.integers(6, rows + 1), rng.integers(6, cols + 1)
        # smooth random responses, so maxima are few and some sit on a slice's last row or column
        stack[n, :h, :w] = cv2.GaussianBlur(rng.uniform(-1, 1, (h, w)).astype(np.float32), (0, 0), 1.5) * 3
        inner[n, 2 : h - 2, 2 : w - 2] = True
    stack[1, -3, :] = 0.9  # a ridge on the last computed row, beside the next slice's first row
    stack[2, 0, :] = 0.95
    n, r, c, score = _best_maxima(stack, inner, 4)
    assert list(zip(n.tolist(), r.tolist(), c.tolist(), score.tolist(), strict=True)) == one_by_one(stack, inner, 4)
    assert len(set(n.tolist())) >= slices // 2  # the test saw maxima in many slices
