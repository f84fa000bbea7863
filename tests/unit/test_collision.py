"""The simulated world's collision check: signed clearance between the tines and a pallet's parts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agf.config import ForkGeometry
from agf.geometry import Transform
from agf.pallets import load_pallets
from agf.paths import repo_path
from drivers.sim.collision import clearance, pallet_parts, signed_distances, tine_surface

FORKS = ForkGeometry()  # 36 mm thick, 120 mm wide, 600 mm apart
PALLET = load_pallets(repo_path("configs/pallets.yaml"))["jis-t11"]  # 90 mm pockets, blocks 0.05..0.45 m
TINES = tine_surface(FORKS)
PARTS = pallet_parts(PALLET)
GAP = PALLET.pocket_height / 2 - FORKS.thickness / 2  # above and below a centred tine: 27 mm


def test_parts_are_the_deck_the_bottom_band_and_each_block():
    assert PARTS.shape == (2 + len(PALLET.blocks), 2, 3)
    assert np.all(PARTS[:, 1] > PARTS[:, 0])


@pytest.mark.parametrize(("x", "z", "expected"), [
    (0.5, 0.0, GAP),  # tips 500 mm in, centred: the gap to the deck and to the bottom band
    (0.5, GAP + 0.003, -0.003),  # 3 mm too high: the tines cut the deck board by 3 mm
    (0.5, -GAP - 0.005, -0.005),  # 5 mm too low: into the bottom band
    (-0.2, 0.0, math.hypot(0.2, GAP)),  # 200 mm in front: the tip's top edge to the deck's front edge
])
def test_clearance_of_tines_in_and_in_front_of_the_pockets(x, z, expected):
    assert clearance(TINES, Transform.from_euler(x, 0.0, z), PARTS) == pytest.approx(expected, abs=1e-9)


def test_a_tine_driven_into_a_block_is_a_collision_as_deep_as_it_goes():
    # the left tine's outer side at y = -0.36 m; the block at y = -0.5 m spans -0.55..-0.45 m
    sideways = Transform.from_euler(0.3, -0.12, 0.0)
    assert clearance(TINES, sideways, PARTS) == pytest.approx(-(0.48 - 0.45), abs=1e-9)


def test_clearance_does_not_depend_on_the_order_of_the_parts():
    pose = Transform.from_euler(0.4, 0.01, 0.012, pitch=math.radians(1.0), yaw=math.radians(0.5))
    rng = np.random.default_rng(5)
    assert clearance(TINES, pose, PARTS[rng.permutation(len(PARTS))]) == clearance(TINES, pose, PARTS)


@pytest.mark.parametrize("seed", range(3))
def test_clearance_equals_the_smallest_signed_distance_over_every_point(seed):
    """The chunks skipped by their lower bound never hold the nearest point: in front of, at and inside the
    pockets, turned and shifted, the result is that of all points."""
    rng = np.random.default_rng(seed)
    points = TINES.chunks.reshape(-1, 3)
    for _ in range(200):
        pose = Transform.from_euler(rng.uniform(-0.6, 1.2), rng.uniform(-0.1, 0.1), rng.uniform(-0.15, 0.25),
                                    0.0, rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1))
        assert clearance(TINES, pose, PARTS) == float(signed_distances(pose.apply(points), PARTS).min())


def test_tine_surface_chunks_hold_every_point_within_their_radius():
    offsets = np.linalg.norm(TINES.chunks - TINES.centres[:, None], axis=2)
    assert np.all(offsets <= TINES.radii[:, None] + 1e-12)
    assert TINES.radii.max() < 0.15  # neighbours: a chunk spans a short stretch of one tine, not two
