"""The controller's planner: insertion targets and the Ruckig motions to reach them, from config."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from agf.axis import AxisLimits
from agf.config import ForkGeometry, section_from_mapping, unit
from agf.insertion import InsertionConfig, InsertionPlan, plan_insertion
from agf.kinematics import MastGeometry, fork_in_truck_from_axes
from agf.measurement import PalletMeasurement
from agf.motion import Trajectory, plan_move
from agf.pallets import PalletType


@dataclass(frozen=True)
class PickSettings:
    """The ``insertion:`` section of the config (mm and degrees in YAML)."""

    standoff: float = unit("mm", 0.25)
    depth: float = unit("mm", 0.6)
    sigmas: float = 3.0
    max_yaw: float = unit("deg", math.radians(4.0))
    verify_position: float = unit("mm", 0.01)
    verify_pitch: float = unit("deg", math.radians(0.3))
    # Plans use this share of each drive's velocity, acceleration and jerk limits, so that a late
    # control cycle never asks a drive for more than it can give (a following-error fault).
    motion_share: float = 0.8

    def __post_init__(self) -> None:
        if not 0 < self.motion_share <= 1:
            raise ValueError(f"motion_share must be in (0, 1], got {self.motion_share}")


def pick_settings_from_mapping(data: Any, where: str) -> PickSettings:
    return section_from_mapping(PickSettings, data or {}, where)


@dataclass(frozen=True)
class PickPlanner:
    """Implements :class:`agf.controller.Planner` for one pallet type and one truck."""

    mast: MastGeometry
    forks: ForkGeometry
    pallet: PalletType
    limits: Mapping[str, AxisLimits]
    settings: PickSettings = PickSettings()

    def plan(self, measurement: PalletMeasurement, axes_now: Mapping[str, float]) -> InsertionPlan:
        config = InsertionConfig(
            standoff=self.settings.standoff,
            depth=self.settings.depth,
            sigmas=self.settings.sigmas,
            max_yaw=self.settings.max_yaw,
        )
        return plan_insertion(measurement, axes_now, self.mast, self.forks, self.pallet, self.limits, config)

    def align_motion(self, axes_now: Mapping[str, float], plan: InsertionPlan) -> Trajectory:
        return plan_move(axes_now, plan.align, self._motion_limits(), "time")

    def insert_motion(self, axes_now: Mapping[str, float], plan: InsertionPlan) -> Trajectory:
        target = {name: plan.insert[name] for name in ("reach", "lift")}
        return plan_move(axes_now, target, self._motion_limits(), "phase")

    def _motion_limits(self) -> dict[str, AxisLimits]:
        return {name: a.scaled(self.settings.motion_share) for name, a in self.limits.items()}

    def verify(self, measurement: PalletMeasurement, plan: InsertionPlan) -> str | None:
        """After aligning, the pallet should be where the plan put it relative to the aligned forks:
        at the stand-off, level with them and, with no side shift to correct it, as far to the side as
        first measured. A pallet bumped since (sideways too) is caught here, before inserting."""
        expected = fork_in_truck_from_axes(plan.align, self.mast).inverse() @ plan.pallet_in_truck
        d = measurement.pallet_in_fork
        pitch = d.euler[1]
        position_error = float(np.linalg.norm(d.translation - expected.translation))
        if position_error > self.settings.verify_position or abs(pitch) > self.settings.verify_pitch:
            return (
                f"after aligning the pallet is {position_error * 1e3:.1f} mm and {math.degrees(pitch):.2f} deg "
                "from where the forks expect it"
            )
        return None
