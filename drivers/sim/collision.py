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


def pallet_parts(pallet: PalletType) -> Array:
    """The pallet's solid parts as boxes (K, 2, 3): each part's low and high corner (m) in frame P."""
    half = pallet.pocket_height / 2
    parts = [([0.0, -pallet.width / 2, half], [pallet.length, pallet.width / 2, pallet.deck_top])]
    if pallet.bottom > 0:
        parts.append(([0.0, -pallet.width / 2, pallet.deck_bottom], [pallet.length, pallet.width / 2, -half]))
    for block in pallet.blocks:
        depth = block.depth if block.depth is not None else pallet.length
        parts.append(([0.0, block.y - block.width / 2, -half], [depth, block.y + block.width / 2, half]))
    return np.array(parts, dtype=float)


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


def clearance(points_f: Array, fork_in_pallet: Transform, parts: Array) -> float:
    """Signed clearance (m) between tine points (N, 3, fork frame) and pallet parts (K, 2, 3, frame P,
    :func:`pallet_parts`): negative means the tines cut a part, by the deepest point's depth."""
    points = fork_in_pallet.apply(points_f).T[:, None, :]  # (3, 1, N): the long axis innermost, for speed
    below, above = parts[:, 0].T[:, :, None] - points, points - parts[:, 1].T[:, :, None]  # (3, K, N)
    outside = np.maximum(np.maximum(below, above), 0.0)
    depth = -np.maximum(below, above).max(axis=0)  # > 0 inside the part: the distance to its nearest side
    signed = np.where(depth > 0, -depth, np.sqrt((outside * outside).sum(axis=0)))
    return float(signed.min())
