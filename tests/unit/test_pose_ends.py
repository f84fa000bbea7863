"""The face's two ends join the pocket-edge fit only where they keep it near the pocket edges' own."""

from __future__ import annotations

import numpy as np

from agf.pallets import load_pallets
from agf.paths import repo_path
from agf.vision.face_model import face_model_from_pallet
from agf.vision.pallet_pose import _Fit, _Params, _with_ends


def _fit(x: float) -> _Fit:
    return _Fit(_Params(x, 0.0, -0.2, 0.0, 0.0))


def test_ends_that_move_the_fit_further_than_the_agreement_are_dropped():
    alone = _fit(0.200)
    assert _with_ends(_fit(0.203), alone, 0.01).params.x == 0.203
    assert _with_ends(_fit(0.226), alone, 0.01) is alone  # random pick 29: 26 mm with the ends
    assert _with_ends(None, alone, 0.01) is alone


def test_fit_points_are_the_pocket_edges_and_the_two_ends_full_width_apart():
    pallet = load_pallets(repo_path("configs/pallets.yaml"))["jis-t11"]
    face = face_model_from_pallet(pallet)
    points, normals, groups = face.fit_points(0.006)
    pocket = face.edge_points(0.006)[0]
    assert np.array_equal(points[: len(pocket)], pocket)
    ends = points[groups == 5]
    assert set(np.round(ends[:, 1], 6)) == {round(pallet.width / 2, 6), round(-pallet.width / 2, 6)}
    assert np.allclose(np.abs(normals[groups == 5][:, 1]), 1.0)
