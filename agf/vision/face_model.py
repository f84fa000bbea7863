"""The model of a pallet's front face, built from the catalogue: where wood is and where pockets are.

Everything is in frame P (DESIGN.md): the face is the plane x = 0, y left, z up, the origin at the
centre of the face at pocket mid-height. The wood of the face (blocks and deck boards, all facing the
same way) is one surface and shades alike; the pockets are openings through it, darker or lighter
than the wood by viewpoint and light. The region match and the edge refinement look for that, not
for a given brightness.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agf.pallets import PalletType

Array = NDArray[np.float64]

ENDS = 5  # the group of the face's two ends in outline_points and fit_points


@dataclass(frozen=True)
class FaceModel:
    """Front-face geometry (m): extent and pocket rectangles ``(y_min, y_max, z_min, z_max)`` (K, 4)."""

    width: float
    z_top: float
    z_bottom: float
    pockets: Array
    pockets_open_below: bool

    def raster(self, pixel: float, margin: float = 0.0) -> tuple[NDArray[np.float32], Array, Array]:
        """Face image at ``pixel`` m per pixel: 1 wood, 0 pocket; with pixel-centre y and z (m).

        Columns run from left (+y) to right (-y) and rows from top (+z) down, as the face is seen
        from the front. ``margin`` extends the raster beyond the face (filled with 0.5, unknown).
        """
        y = np.arange(self.width / 2 + margin - pixel / 2, -self.width / 2 - margin, -pixel)
        z = np.arange(self.z_top + margin - pixel / 2, self.z_bottom - margin, -pixel)
        yy, zz = np.meshgrid(y, z)
        image = np.ones(yy.shape, np.float32)
        for y0, y1, z0, z1 in self.pockets:
            image[(yy > y0) & (yy < y1) & (zz > z0) & (zz < z1)] = 0.0
        outside = (np.abs(yy) > self.width / 2) | (zz > self.z_top) | (zz < self.z_bottom)
        image[outside] = 0.5
        return image, y, z

    def regions(self, bands: int) -> tuple[Array, Array, NDArray[np.int_]]:
        """The face as constant rectangles, which is all a region match at any scale needs.

        Returns the rectangles' z edges (R + 1,) from the top down and y edges (C + 1,) from the left
        (+y), the order in which :meth:`raster` runs, and each rectangle's region (R, C): 0 wood, then
        ``bands`` horizontal bands per pocket (with 3: 1, 2, 3 the first pocket's from the top, ...).

        A pocket is split into bands because what it shows depends on the viewpoint and the light: its
        shadowed ceiling, the bottom deck's lit top seen from above, the floor seen through it.
        """
        w = self.width / 2
        heights = [np.linspace(z0, z1, bands + 1) for *_, z0, z1 in self.pockets]
        z = np.unique(np.clip(np.r_[self.z_top, self.z_bottom, np.ravel(heights)], self.z_bottom, self.z_top))[::-1]
        y = np.unique(np.clip(np.r_[w, -w, self.pockets[:, :2].ravel()], -w, w))[::-1]
        return z, y, self._region_of((z[:-1] + z[1:]) / 2, (y[:-1] + y[1:]) / 2, bands)

    def region_raster(self, pixel: float, bands: int) -> tuple[NDArray[np.int_], Array, Array]:
        """:meth:`regions` sampled at ``pixel`` m per pixel (rows from the top, columns from +y), with
        the pixel-centre y and z (m)."""
        y = np.arange(self.width / 2 - pixel / 2, -self.width / 2, -pixel)
        z = np.arange(self.z_top - pixel / 2, self.z_bottom, -pixel)
        return self._region_of(z, y, bands), y, z

    def _region_of(self, z: Array, y: Array, bands: int) -> NDArray[np.int_]:
        """Region (len(z), len(y)) of the face points at heights ``z`` and sideways ``y`` (m)."""
        zz, yy = np.meshgrid(z, y, indexing="ij")
        region = np.zeros(zz.shape, int)
        for k, (y0, y1, z0, z1) in enumerate(self.pockets):
            band = np.floor((z1 - zz) / (z1 - z0) * bands).astype(int)
            inside = (yy > y0) & (yy < y1) & (zz > z0) & (zz < z1)
            region[inside] = 1 + k * bands + np.clip(band[inside], 0, bands - 1)
        return region

    def edge_points(self, spacing: float, inset: float = 0.012) -> tuple[Array, Array, NDArray[np.int_]]:
        """Points (N, 3) on the pocket boundaries, unit normals (N, 3) pointing from wood into the pocket,
        and each point's edge group (N,): 0 pocket tops, 1 pocket bottoms, 2 pocket sides.

        Points stay ``inset`` m away from pocket corners, where two edges blur into each other.
        """
        points, normals, groups = [], [], []
        for y0, y1, z0, z1 in self.pockets:
            along_y = _samples(y0 + inset, y1 - inset, spacing)
            along_z = _samples(z0 + inset, z1 - inset, spacing)
            edges = [
                (np.c_[0 * along_y, along_y, 0 * along_y + z1], (0.0, 0.0, -1.0), 0),  # top: wood above
                (np.c_[0 * along_z, 0 * along_z + y0, along_z], (0.0, 1.0, 0.0), 2),  # right: block at lower y
                (np.c_[0 * along_z, 0 * along_z + y1, along_z], (0.0, -1.0, 0.0), 2),  # left
            ]
            if not self.pockets_open_below:
                edges.append((np.c_[0 * along_y, along_y, 0 * along_y + z0], (0.0, 0.0, 1.0), 1))
            for p, n, g in edges:
                points.append(p)
                normals.append(np.tile(n, (len(p), 1)))
                groups.append(np.full(len(p), g))
        return np.concatenate(points), np.concatenate(normals), np.concatenate(groups)

    def outline_points(self, spacing: float, inset: float = 0.012) -> tuple[Array, Array, NDArray[np.int_]]:
        """Points (N, 3) on the face's outer outline, unit outward normals (N, 3), and each point's group
        (N,): 3 the face's top edge, 4 its bottom edge, 5 its two ends (numbered after
        :meth:`edge_points`' groups, so the two sets can be used together).

        Which side of the outline is brighter depends on the load, the floor and the light, so these
        normals only give the direction to search along.
        """
        w = self.width / 2
        along_y = _samples(-w + inset, w - inset, spacing)
        along_z = _samples(self.z_bottom + inset, self.z_top - inset, spacing)
        edges = [
            (np.c_[0 * along_y, along_y, 0 * along_y + self.z_top], (0.0, 0.0, 1.0), 3),
            (np.c_[0 * along_y, along_y, 0 * along_y + self.z_bottom], (0.0, 0.0, -1.0), 4),
            (np.c_[0 * along_z, 0 * along_z + w, along_z], (0.0, 1.0, 0.0), ENDS),
            (np.c_[0 * along_z, 0 * along_z - w, along_z], (0.0, -1.0, 0.0), ENDS),
        ]
        return (
            np.concatenate([e[0] for e in edges]),
            np.concatenate([np.tile(e[1], (len(e[0]), 1)) for e in edges]),
            np.concatenate([np.full(len(e[0]), e[2]) for e in edges]),
        )

    def fit_points(self, spacing: float, inset: float = 0.012) -> tuple[Array, Array, NDArray[np.int_]]:
        """What the pose is fitted to: :meth:`edge_points` and the face's two ends (group 5 of
        :meth:`outline_points`), in the same layout.

        The ends, the face's full width apart, fix its scale, hence its distance. Without them the
        pocket edges alone did, and where the surface behind a pocket edge faces the camera (the pocket's
        floor seen from above) its lit entrance shows, the strongest step lies beyond it (1.15 px into
        the pocket on paper scene unloaded-middle-flat) and the pallet was fitted 2.7 mm too far.
        """
        points, normals, groups = self.edge_points(spacing, inset)
        outline, outward, parts = self.outline_points(spacing, inset)
        ends = parts == ENDS
        return (np.concatenate([points, outline[ends]]), np.concatenate([normals, outward[ends]]),
                np.concatenate([groups, parts[ends]]))

    def corners(self) -> Array:
        """The four corners (4, 3) of the face: top-left, top-right, bottom-right, bottom-left."""
        w = self.width / 2
        return np.array([[0, w, self.z_top], [0, -w, self.z_top], [0, -w, self.z_bottom], [0, w, self.z_bottom]])


def face_model_from_pallet(pallet: PalletType) -> FaceModel:
    """The front-face model of a catalogued pallet type."""
    half = pallet.pocket_height / 2
    pockets = np.array([[y0, y1, -half, half] for y0, y1 in pallet.pockets()])
    return FaceModel(pallet.width, pallet.deck_top, pallet.deck_bottom, pockets, pallet.bottom <= 0)


def _samples(start: float, stop: float, spacing: float) -> Array:
    n = max(int(np.floor((stop - start) / spacing)) + 1, 2)
    return np.linspace(start, stop, n)
