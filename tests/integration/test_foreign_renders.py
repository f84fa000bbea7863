"""The measurement on frames of an independent renderer (``../shared/data/foreign-renders``): pockets
seen from above show the bottom deck lit and their ceiling in shadow, wood grain and cartons of another
look. Nothing may be accepted outside the bounds, and what the region match recovered must stay."""

from __future__ import annotations

import json

import cv2
import pytest
import yaml

from agf.camera import load_camera
from agf.config import load_config
from agf.geometry import transform_from_dict
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.vision.accuracy import pose_errors, within_bounds
from agf.vision.bench_cases import measure_truthed_frames
from agf.vision.measure import measure_pallet
from tests.integration.conftest import SHARED_DATA

FOREIGN = SHARED_DATA / "foreign-renders"
# Measured within bounds before the region match: 0 of 10; 7 with it; 9 since steep views are scanned finer and
# poses are fitted again along the line of sight where the face's upright edges agree (issue 17 closing notes).
WITHIN_AT_LEAST = 9


@pytest.mark.skipif(not FOREIGN.is_dir(), reason="../shared/data/foreign-renders is not beside this checkout")
def test_foreign_renders_no_wrong_accept_and_most_within_bounds():
    """Regression (foreign renders): the correlation with dark pockets scored the true face near 0 on
    every frame, so all ten were refused as ambiguous or for their pitch."""
    summary = measure_truthed_frames(FOREIGN).summary()
    assert summary["wrong_accepts"] == 0, summary["wrong"]
    assert summary["within_bounds"] >= WITHIN_AT_LEAST, summary["refused"]


@pytest.mark.skipif(not FOREIGN.is_dir(), reason="../shared/data/foreign-renders is not beside this checkout")
def test_regression_foreign_unloaded_below_forks_thin_face_seen_from_above_is_measured_within_bounds():
    """Regression (foreign render unloaded-below-forks, the paper's "high" configuration: the pallet 240 mm below
    the forks, the camera 1.3 m above its face): the face was a band 28 px tall, 3.5 px at the coarse level, where
    the region match found it nowhere near the top; a level finer it did, but the pocket-edge fit then stayed 40-70
    mm too far along the line of sight, where the face's ends agree 0 %, and every search was refused. The steep
    slab of the search box is now scanned a level finer, and a pose whose face edges agree better along the line of
    sight is fitted again from there."""
    config = load_config(DEFAULT_CONFIG)
    scene = yaml.safe_load((FOREIGN / "scenes/unloaded-below-forks.yaml").read_text())
    truth = transform_from_dict(json.loads((FOREIGN / "images/unloaded-below-forks.truth.json").read_text())
                                ["pallet_in_fork"])
    image = cv2.imread(str(FOREIGN / "images/unloaded-below-forks.png"), cv2.IMREAD_COLOR)
    detail = measure_pallet(image, load_camera(FOREIGN / scene["camera"]),
                            transform_from_dict(scene["camera_in_fork"], where="camera_in_fork"),
                            load_pallets(config.vision.pallets)[scene["pallet"]["type"]], config.vision.search,
                            forks=config.forks)
    errors = pose_errors(detail.measurement.pallet_in_fork, truth)
    assert within_bounds(errors), errors
    assert not detail.measurement.loaded
