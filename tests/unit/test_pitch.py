"""The deck-edge pose: an unloaded pallet's y, z, yaw and pitch from the great circles of its deck edges."""

from __future__ import annotations

import numpy as np
import pytest

from agf.config import load_config
from agf.geometry import Transform
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.vision.hough import SphereLine
from agf.vision.pitch import PitchEvidence, pose_from_deck_edges

PALLET = load_pallets(load_config(DEFAULT_CONFIG).vision.pallets)["jis-t11"]
CAMERA_IN_FORK = Transform.from_euler(-0.705, 0.0, 1.055)


def deck_edge_evidence(pallet_in_fork: Transform, hypothesis: str = "unloaded", valid: bool = True) -> PitchEvidence:
    """The two deck edges as they project exactly, from the camera centre."""
    in_camera = CAMERA_IN_FORK.inverse() @ pallet_in_fork
    forward = in_camera.rotation[:, 0]
    lines = []
    for side in (-1, 1):
        corner = in_camera.apply(np.array([[0.0, side * PALLET.width / 2, PALLET.deck_top]]))[0]
        normal = np.cross(corner, forward)
        lines.append(SphereLine(normal / np.linalg.norm(normal), 1.0, np.ones(1, bool)))
    return PitchEvidence(hypothesis, 1.0, valid, 0.0, forward, None, [], lines, 0.0)


@pytest.mark.parametrize("seed", range(5))
def test_deck_edges_recover_y_z_yaw_and_pitch_but_keep_x(seed):
    rng = np.random.default_rng(seed)
    truth = Transform.from_euler(rng.uniform(0.15, 0.4), rng.uniform(-0.03, 0.03), rng.uniform(-0.3, 0.45), 0.0,
                                 np.radians(rng.uniform(-5, 5)), np.radians(rng.uniform(-3, 3)))
    x, y, z = truth.translation
    yaw, pitch, _ = truth.euler
    start = Transform.from_euler(x + 0.01, y - 0.02, z + 0.03, 0.0, pitch + 0.01, yaw - 0.01)
    found = pose_from_deck_edges(deck_edge_evidence(truth), PALLET, CAMERA_IN_FORK, start)
    np.testing.assert_allclose(found.euler, truth.euler, atol=1e-9)
    # x is only what the start had: the deck edges run along it.
    along = found.translation - truth.translation
    np.testing.assert_allclose(along - (along @ truth.rotation[:, 0]) * truth.rotation[:, 0], 0, atol=1e-9)


def test_deck_edges_need_a_valid_unloaded_hypothesis():
    truth = Transform.from_euler(0.3, 0.0, 0.1)
    with pytest.raises(ValueError, match="valid unloaded"):
        pose_from_deck_edges(deck_edge_evidence(truth, "loaded"), PALLET, CAMERA_IN_FORK, truth)
    with pytest.raises(ValueError, match="valid unloaded"):
        pose_from_deck_edges(deck_edge_evidence(truth, valid=False), PALLET, CAMERA_IN_FORK, truth)
