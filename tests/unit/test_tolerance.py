"""The safe-insertion check of paper section V.A and the insertion plan."""

from __future__ import annotations

import math

import pytest

from agf.axis import AxisLimits
from agf.config import ForkGeometry
from agf.geometry import Transform
from agf.insertion import InsertionConfig, plan_insertion, tolerance_margins, tolerance_slacks
from agf.kinematics import MastGeometry, fork_in_truck_from_axes
from agf.measurement import PalletMeasurement
from agf.pallets import load_pallets
from agf.paths import repo_path

FORKS = ForkGeometry()  # FT 36 mm, FL 1070 mm: the paper's forks
PH = 0.090
PALLET = load_pallets(repo_path("configs/pallets.yaml"))["jis-t11"]
LIMITS = {
    "lift": AxisLimits(0.0, 3.0, 0.4, 0.8, 4.0),
    "reach": AxisLimits(0.0, 1.3, 0.25, 0.5, 2.5),
    "tilt": AxisLimits(-0.1, 0.1, 0.07, 0.14, 0.7),
}
MAST = MastGeometry()
SIGMA_PITCH = math.radians(0.02)


@pytest.mark.parametrize(
    ("dz_mm", "dtheta_deg", "failing"),
    [(-27.5, 0.5, 0), (27.5, -0.5, 1), (0.0, -1.5, 2), (0.0, 1.5, 3)],
)
def test_each_inequality_fails_on_its_own(dz_mm, dtheta_deg, failing):
    slacks = tolerance_slacks(dz_mm / 1e3, math.radians(dtheta_deg), PH, FORKS)
    assert [i for i, s in enumerate(slacks) if s <= 0] == [failing]


def test_fourth_inequality_uses_cos_dtheta_not_the_papers_cos_dz_misprint():
    stubby = ForkGeometry(thickness=0.036, length=1e-4, width=0.12, spacing=0.6)
    slacks = tolerance_slacks(0.030, math.radians(60.0), PH, stubby)
    assert slacks[3] > 0  # with cos(dZ) it would be 0.045 - 0.030 - 0.018 < 0


def test_margins_shrink_with_uncertainty_and_go_negative_beyond_the_square():
    small, small_tilt = tolerance_margins(0.002, math.radians(0.05), PH, FORKS)
    large, large_tilt = tolerance_margins(0.020, math.radians(0.5), PH, FORKS)
    assert small > large and small_tilt > large_tilt
    assert tolerance_margins(0.010, math.radians(1.6), PH, FORKS)[0] < 0


def measured(x=0.25, y=0.0, z=0.2, pitch_deg=2.0, yaw_deg=0.0, sigma_z=0.0005, sigma_pitch=SIGMA_PITCH):
    pose = Transform.from_euler(x, y, z, 0.0, math.radians(pitch_deg), math.radians(yaw_deg))
    return PalletMeasurement(pose, pose, False, sigma_z, sigma_pitch)


def test_plan_puts_the_tips_at_the_standoff_with_tilt_equal_to_pitch():
    now = {"lift": 0.6, "reach": 0.3, "tilt": 0.0}
    config = InsertionConfig(standoff=0.25, depth=0.6)
    plan = plan_insertion(measured(), now, MAST, FORKS, PALLET, LIMITS, config)
    assert plan.safe, plan.reason
    assert plan.align["tilt"] == pytest.approx(math.radians(2.0))
    fork = fork_in_truck_from_axes(plan.align, MAST)
    pallet_in_fork = fork.inverse() @ plan.pallet_in_truck
    assert pallet_in_fork.translation == pytest.approx([0.25, 0.0, 0.0], abs=1e-9)
    inserted = fork_in_truck_from_axes(plan.insert, MAST).inverse() @ plan.pallet_in_truck
    assert inserted.translation == pytest.approx([-0.6, 0.0, 0.0], abs=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "reason"),
    [
        ({"z": 3.5}, "outside its limits"),
        ({"yaw_deg": 5.0}, "yaw"),
        ({"y": 0.2}, "lateral"),
        ({"sigma_z": 0.01}, "tolerance exceeded"),
    ],
)
def test_unsafe_or_unreachable_insertions_are_refused_with_the_reason(kwargs, reason):
    plan = plan_insertion(measured(**kwargs), {"lift": 0.6, "reach": 0.3, "tilt": 0.0}, MAST, FORKS, PALLET, LIMITS)
    assert not plan.safe and reason in plan.reason
