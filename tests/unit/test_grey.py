"""The vision's grey image from a colour frame (agf/vision/grey.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from agf.vision.grey import grey_from_bgr


@pytest.mark.parametrize("seed", range(3))
def test_grey_is_the_png_readers_to_the_level(seed):
    """Regression: the simulated world's colour frames were made grey by cv2.cvtColor, which rounds, while
    agf bench and agf measure read PNG files in grey, which round down: one level apart in a third of the
    pixels, and random look 4 of loaded-middle-flat was accepted 0.11 deg off from the one, refused from the other."""
    colour = np.random.default_rng(seed).integers(0, 256, (64, 96, 3), dtype=np.uint8)
    read = cv2.imdecode(cv2.imencode(".png", colour)[1], cv2.IMREAD_GRAYSCALE)
    assert np.array_equal(grey_from_bgr(colour), read)
    assert not np.array_equal(cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY), read)  # what the world used


def test_grey_is_the_png_readers_for_every_colour():
    b, g, r = (v.ravel() for v in np.meshgrid(*[np.arange(256)] * 3, indexing="ij"))
    colours = np.stack([b, g, r], axis=1).astype(np.uint8).reshape(4096, 4096, 3)
    expected = (9797 * r.astype(np.int64) + 19234 * g + 3737 * b) >> 15  # libpng's fixed point, rounded down
    assert np.array_equal(grey_from_bgr(colours).ravel(), expected)


def test_a_grey_image_is_returned_as_it_is_and_other_shapes_are_refused():
    grey = np.zeros((4, 5), np.float32)
    assert grey_from_bgr(grey) is grey
    with pytest.raises(ValueError, match="uint8"):
        grey_from_bgr(np.zeros((4, 5, 4), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        grey_from_bgr(np.zeros((4, 5, 3), np.uint16))
