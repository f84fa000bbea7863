"""Plots that carry a judgement: the side view of the fork path colours contact red; the axis plots
show the setpoint on top of the actual position."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from agf.config import load_config
from agf.controller import PickResult
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.viz import fork_path_side_view, pick_plots

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
    assert clear.shape == hit.shape and clear.shape[0] >= 500 and clear.shape[1] >= 1000
    assert red(clear) == 0 and red(hit) > 50


def test_mismatched_shapes_are_refused(tmp_path):
    with pytest.raises(ValueError, match="outlines"):
        fork_path_side_view(straight_in(0.0), np.zeros(49), PALLET, tmp_path / "x.png")


def blue(image: np.ndarray) -> int:
    """Pixels of matplotlib's tab:blue (RGB 31, 119, 180), the setpoint line."""
    b, g, r = (image[..., k].astype(int) for k in range(3))
    return int(((abs(b - 180) < 30) & (abs(g - 119) < 30) & (r < 80)).sum())


def test_the_setpoint_is_drawn_on_top_of_the_actual_position(tmp_path):
    t = np.linspace(0.0, 4.0, 200)
    lift = 0.6 + 0.1 * np.sin(t)
    log = [
        {
            "t": ti,
            "state": "aligning" if ti < 2 else "inserting",
            "setpoint": {"lift": v, "tilt": 0.01},
            "actual": {"lift": v, "tilt": 0.01},
        }
        for ti, v in zip(t, lift, strict=True)
    ]
    (path,) = pick_plots(PickResult(True, "done", None, [], None, {}, log), tmp_path)
    image = cv2.imread(path)
    assert image is not None and image.shape[0] > 400
    assert blue(image) > 1000  # the setpoint, identical to the actual position, still shows
    assert pick_plots(PickResult(False, "fault", "x", [], None, {}, []), tmp_path) == []
