"""The coarse pose scan in height slabs (:func:`agf.vision.pallet_pose._slabs`, with
``PoseSearchConfig.finer_where_thin``): where the face, seen steeply from above, would be a band too thin to
resolve at the coarse pyramid level, that part of the search box is scanned at a finer level, and the slabs
cover the box's heights without a gap."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agf.camera import load_camera
from agf.config import load_calibration, load_config
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.vision.face_model import face_model_from_pallet
from agf.vision.pallet_pose import PoseSearchConfig, _face_heights_px, _leaders, _Params, _search_box, _slabs


@pytest.fixture(scope="module")
def setting():
    config = load_config(DEFAULT_CONFIG)
    camera = load_camera(config.vision.camera)
    face = face_model_from_pallet(load_pallets(config.vision.pallets)["jis-t11"])
    return camera, load_calibration(config.vision.calibration), face, config.vision.search


@pytest.mark.parametrize("pitch_deg", [0.0, -3.0, 3.0])
def test_slabs_cover_the_box_and_are_finer_where_the_face_is_thinner(setting, pitch_deg):
    camera, camera_in_fork, face, volume = setting
    search = PoseSearchConfig(finer_where_thin=True)
    box = _search_box(volume, None, math.radians(pitch_deg), search)
    slabs = _slabs(box, camera, camera_in_fork, face, search)
    edges = [(slab.low[2], slab.high[2]) for slab, _ in slabs]
    assert edges[0][0] == pytest.approx(box.low[2]) and edges[-1][1] == pytest.approx(box.high[2])
    assert all(high == pytest.approx(low) for (_, high), (low, _) in zip(edges[:-1], edges[1:], strict=True))
    levels = [level for _, level in slabs]
    assert levels == sorted(levels) and len(set(levels)) == len(levels)  # finer below, one slab a level
    assert all(search.fine_level <= level <= search.pyramid_level for level in levels)
    for slab, level in slabs:
        assert np.array_equal(slab.low[:2], box.low[:2]) and np.array_equal(slab.high[:2], box.high[:2])
        heights = np.linspace(slab.low[2], slab.high[2] - search.slab_step / 2, 5)
        tall = _face_heights_px(heights, box, camera, camera_in_fork, face) / 2.0**level
        assert level == search.fine_level or np.all(tall >= search.min_face_px)


def test_a_face_well_below_the_camera_is_scanned_finer_and_one_level_with_it_at_the_coarse_level(setting):
    """The camera 1.05 m above the forks sees a face at the volume's bottom (400 mm below them) from 1.45 m
    above: thinner than the coarse level resolves, so that slab is scanned a level finer; faces at the camera's
    height are not."""
    camera, camera_in_fork, face, volume = setting
    search = PoseSearchConfig(finer_where_thin=True)
    box = _search_box(volume, None, 0.0, search)
    tall = _face_heights_px(np.array([box.low[2], box.high[2]]), box, camera, camera_in_fork, face)
    assert tall[0] < tall[1]
    slabs = _slabs(box, camera, camera_in_fork, face, search)
    assert slabs[0][1] < search.pyramid_level and slabs[-1][1] == search.pyramid_level
    coarse = dataclasses.replace(search, min_face_px=tall.min() / 2.0**search.pyramid_level / 2)
    assert [level for _, level in _slabs(box, camera, camera_in_fork, face, coarse)] == [search.pyramid_level]
    unless = dataclasses.replace(search, finer_where_thin=False)  # the default: every search but the last attempt
    assert [level for _, level in _slabs(box, camera, camera_in_fork, face, unless)] == [search.pyramid_level]


def test_each_slabs_best_place_is_fitted_besides_the_best_three(setting):
    """A slab scanned a level finer scores sharper (0.71 against the coarse level's 0.65 on random look 2 of paper
    scene unloaded-high-flat): its peaks alone must not fill the best three."""
    _, camera_in_fork, face, _ = setting
    eye = camera_in_fork.translation
    at = [_Params(0.2 + 0.01 * k, y, -0.2, 0.0, 0.0) for k, y in enumerate((-0.6, -0.3, 0.0, 0.3, 0.6))]
    fine = [(0.9, at[0]), (0.85, at[1]), (0.8, at[2])]
    coarse = [(0.7, at[3]), (0.6, at[4])]
    again = [(0.75, _Params(at[1].x + 0.05, at[1].y, at[1].z, 0.0, 0.0))]  # the place of a chosen one, deeper
    chosen = _leaders(fine, [fine, coarse, again], face, eye)
    assert chosen == [*fine, coarse[0]]
    assert _leaders(fine, [fine, [], again], face, eye) == fine
