"""The grey image the vision works on, from the camera's colour frame.

One conversion for every path a frame takes: the simulated world hands the measurement colour frames,
``agf measure`` and ``agf bench`` read PNG files. OpenCV's PNG reader makes grey as libpng does with
OpenCV's weights, rounding down; ``cv2.cvtColor`` rounds to nearest. The two differ by one grey level
in 30-50 % of the pixels, and that flipped verdicts: the paper scenes' random look 4 of loaded-middle-flat
was accepted 0.11 deg off in pitch from ``cvtColor``'s grey and refused from the reader's, the foreign render
real-lens-unloaded the other way round. The vision was tuned on the reader's grey, so that is the one.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

# B, G, R weights of OpenCV's PNG reader (png_set_rgb_to_gray with 0.299, 0.587, in libpng's 15-bit fixed point), and
# the offset that makes cv2.transform's rounding to nearest a rounding down: the sum is a multiple of 1/32768, so
# half a level less 1/65536 moves every value below its next integer and none below its own (exact for all 2^24
# colours, tests/unit/test_grey.py; 6 ms a 1920 x 1920 frame, the float32 path 20)
_TO_GREY = np.array([[3737.0, 19234.0, 9797.0, 0.0]]) / 32768.0 + np.array([[0.0, 0.0, 0.0, -0.5 + 1.0 / 65536.0]])


def grey_from_bgr(image: NDArray) -> NDArray:
    """Grey (H, W) uint8 of an (H, W, 3) uint8 BGR ``image``, as ``cv2.imread(..., cv2.IMREAD_GRAYSCALE)`` makes
    it from a PNG file: the weighted sum rounded down. An (H, W) image (grey already) is returned as it is.

    Raises
    ------
    ValueError
        When ``image`` is neither (H, W) nor (H, W, 3) uint8.
    """
    if image.ndim == 2:
        return image
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"expected an (H, W) image or an (H, W, 3) uint8 one, got {image.shape} {image.dtype}")
    return cv2.transform(image, _TO_GREY)
