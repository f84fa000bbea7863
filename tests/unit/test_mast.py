"""Mast kinematics: axes <-> fork pose round trips, the tilt's tip drop, refused poses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agf.geometry import Transform
from agf.kinematics import MastGeometry, axes_from_fork_in_truck, fork_in_truck_from_axes

MAST = MastGeometry()


@settings(max_examples=200, deadline=None)
@given(lift=st.floats(0, 3), reach=st.floats(0, 1.3), tilt=st.floats(-0.1, 0.1), side=st.floats(-0.1, 0.1))
def test_axes_pose_round_trip(lift, reach, tilt, side):
    axes = {"lift": lift, "reach": reach, "tilt": tilt, "side_shift": side}
    back = axes_from_fork_in_truck(fork_in_truck_from_axes(axes, MAST), MAST, side_shift=True)
    assert back == pytest.approx(axes, abs=1e-9)


def test_tilt_drops_the_tips_by_fl_sin_tilt():
    level = fork_in_truck_from_axes({"lift": 1.0, "reach": 0.2, "tilt": 0.0}, MAST)
    tilted = fork_in_truck_from_axes({"lift": 1.0, "reach": 0.2, "tilt": math.radians(2.0)}, MAST)
    drop = level.translation[2] - tilted.translation[2]
    assert drop == pytest.approx(-MAST.pivot[0] * math.sin(math.radians(2.0)), rel=1e-9)
    assert tilted.apply_direction([1.0, 0, 0])[2] < 0  # positive tilt: fork X points down, like pallet pitch


def test_the_mast_cannot_yaw_or_shift_sideways_without_an_axis():
    with pytest.raises(ValueError, match="yaw"):
        axes_from_fork_in_truck(Transform.from_euler(1.0, 0, 0.5, 0, 0, 0.05), MAST)
    with pytest.raises(ValueError, match="side-shift"):
        axes_from_fork_in_truck(Transform.from_euler(1.0, 0.02, 0.5), MAST)
    assert np.isfinite(list(axes_from_fork_in_truck(Transform.from_euler(1.0, 0.02, 0.5), MAST, True).values())).all()
