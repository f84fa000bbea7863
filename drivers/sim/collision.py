"""Contact between the fork tines and a pallet, for the simulated world's collision count.

The tines are boxes in the fork frame; the pallet is the union of its parts (deck, bottom band,
blocks) as boxes in frame P. Points sampled densely over each tine's surface are tested against each
part: inside any part is a collision; otherwise the smallest distance is the clearance.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agf.config import ForkGeometry
from agf.geometry import Transform
from agf.pallets import PalletType

Array = NDArray[np.float64]


def pallet_parts(pallet: PalletType) -> list[tuple[Array, Array]]:
    """The pallet's solid parts as (low, high) corners (m) in frame P."""
    half = pallet.pocket_height / 2
    parts = [(np.array([0.0, -pallet.width / 2, half]), np.array([pallet.length, pallet.width / 2, pallet.deck_top]))]
    if pallet.bottom > 0:
        parts.append(
            (np.array([0.0, -pallet.width / 2, pallet.deck_bottom]), np.array([pallet.length, pallet.width / 2, -half]))
        )
    for block in pallet.blocks:
        depth = block.depth if block.depth is not None else pallet.length
        parts.append(
            (np.array([0.0, block.y - block.width / 2, -half]), np.array([depth, block.y + block.width / 2, half]))
        )
    return parts


def tine_surface_points(forks: ForkGeometry, spacing: float = 0.01) -> Array:
    """Points (N, 3, fork frame) on the surfaces of both tines (tips at x = 0, heels at x = -length)."""
    x = np.arange(-forks.length, 0.0 + 1e-9, spacing)
    points = []
    for side in (-1.0, 1.0):
        yc = side * forks.spacing / 2
        ys = np.linspace(yc - forks.width / 2, yc + forks.width / 2, 7)
        zs = np.linspace(-forks.thickness / 2, forks.thickness / 2, 4)
        grid_top = np.array([[xi, yi, z] for xi in x for yi in ys for z in (zs[0], zs[-1])])
        grid_side = np.array([[xi, y, zi] for xi in x for y in (ys[0], ys[-1]) for zi in zs])
        tip = np.array([[0.0, yi, zi] for yi in ys for zi in zs])
        points += [grid_top, grid_side, tip]
    return np.concatenate(points)


def clearance(points_f: Array, fork_in_pallet: Transform, parts: list[tuple[Array, Array]]) -> float:
    """Signed clearance (m) between tine points and pallet parts: negative means the tines cut a part."""
    points = fork_in_pallet.apply(points_f)
    best = np.inf
    for low, high in parts:
        outside = np.maximum(np.maximum(low - points, points - high), 0.0)
        distance = np.linalg.norm(outside, axis=1)
        inside = np.all((points > low) & (points < high), axis=1)
        depth = np.min(np.minimum(points - low, high - points), axis=1)
        signed = np.where(inside, -depth, distance)
        best = min(best, float(signed.min()))
    return best
