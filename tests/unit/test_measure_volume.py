"""A measured pose must lie in the volume it was searched in (:func:`agf.vision.measure.check_in_volume`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agf.config import SearchVolume
from agf.errors import MeasurementError
from agf.geometry import Transform
from agf.vision.measure import check_in_volume

VOLUME = SearchVolume()


def pose(x=0.3, y=0.0, z=0.1, yaw_deg=0.0, pitch_deg=0.0) -> Transform:
    return Transform.from_euler(x, y, z, 0.0, math.radians(pitch_deg), math.radians(yaw_deg))


def test_poses_inside_the_volume_and_on_its_faces_pass():
    rng = np.random.default_rng(5)
    for _ in range(50):
        check_in_volume(pose(rng.uniform(VOLUME.x_min, VOLUME.x_max), rng.uniform(VOLUME.y_min, VOLUME.y_max),
                             rng.uniform(VOLUME.z_min, VOLUME.z_max), rng.uniform(-9.9, 9.9), rng.uniform(-5.9, 5.9)),
                        VOLUME)
    check_in_volume(pose(x=VOLUME.x_max, z=VOLUME.z_min), VOLUME)


@pytest.mark.parametrize(
    ("moved", "named"),
    [
        ({"z": 0.577}, "z 577.0 mm"),
        ({"z": -0.401}, "z -401.0 mm"),
        ({"x": 0.05}, "x 50.0 mm"),
        ({"y": 0.31}, "y 310.0 mm"),
        ({"yaw_deg": -10.5}, "yaw -10.5 deg"),
        ({"pitch_deg": 6.2}, "pitch 6.2 deg"),
    ],
)
def test_a_pose_outside_the_volume_is_refused_naming_the_coordinate_and_the_limits(moved, named):
    with pytest.raises(MeasurementError, match="outside the search volume") as refused:
        check_in_volume(pose(**moved), VOLUME)
    assert named in str(refused.value)
    assert "vision.search" in str(refused.value)
