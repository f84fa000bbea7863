"""Plots that carry a judgement: the side view of the fork path colours contact red."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from agf.config import load_config
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.viz import fork_path_side_view

PALLET = load_pallets(load_config(DEFAULT_CONFIG).vision.pallets)["jis-t11"]


def straight_in(z_centre: float, cycles: int = 50) -> np.ndarray:
    """A 36 mm tine, 1.07 m long, sliding from 0.4 m in front of the pallet to 0.6 m inside, at one height."""
    tips = np.linspace(-0.4, 0.6, cycles)
    outline = np.array([[0.0, 0.3, 0.018], [0.0, 0.3, -0.018], [-1.07, 0.3, -0.018], [-1.07, 0.3, 0.018]])
    return outline[None] + np.stack([tips, np.zeros(cycles), np.full(cycles, z_centre)], 1)[:, None]


def red(image: np.ndarray) -> int:
    return int(((image[..., 2] > 180) & (image[..., 1] < 40) & (image[..., 0] < 40)).sum())


def test_a_clear_path_has_no_red_and_a_contact_has(tmp_path):
    clear = cv2.imread(fork_path_side_view(straight_in(0.0), np.full(50, 0.02), PALLET, tmp_path / "clear.png"))
    touching = np.where(np.arange(50) > 30, -0.002, 0.02)
    hit = cv2.imread(fork_path_side_view(straight_in(0.03), touching, PALLET, tmp_path / "hit.png"))
    assert clear.shape == hit.shape == (560, 1400, 3)
    assert red(clear) == 0 and red(hit) > 50


def test_mismatched_shapes_are_refused(tmp_path):
    with pytest.raises(ValueError, match="outlines"):
        fork_path_side_view(straight_in(0.0), np.zeros(49), PALLET, tmp_path / "x.png")
