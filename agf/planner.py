"""The controller's planner: insertion targets and the Ruckig motions to reach them, from config, and
the viewing move that lets the camera see a pallet the forks hide."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from agf.axis import AxisLimits
from agf.config import ForkGeometry, section_from_mapping, unit
from agf.errors import AgfError, MeasurementError
from agf.geometry import Transform
from agf.insertion import InsertionConfig, InsertionPlan, plan_insertion
from agf.kinematics import MastGeometry, fork_in_truck_from_axes
from agf.measurement import PalletMeasurement
from agf.motion import MoveSequence, Trajectory, plan_move
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
    # A pallet on its support may be pushed along it or turned, not raised or tipped: a verifying measurement that
    # puts it higher or lower, or steeper, than the one the plan was made from by more than these says one of the
    # two is wrong, and the pick is refused instead of re-planned on the later one. Of 395 pairs of consecutive
    # measurements in `agf simulate --random 1000 --seed 7` (session 26) all but two agreed within 1.3 mm in height
    # and 0.28 deg in pitch; pick 386 re-planned on a verifying frame 37.7 mm low and collided, pick 206 on one
    # 2.86 deg from a first measurement 2.88 deg off (and inserted).
    verify_height_change: float = unit("mm", 0.01)
    verify_pitch_change: float = unit("deg", math.radians(0.5))
    # Nor may the two pitches differ by more than this many standard deviations of their difference (the root sum of
    # squares of the two measurements' sigma_pitch): then one of them is further off than it states, and the plan's
    # tilt margins (``sigmas`` of its sigma) do not hold. Of the 459 picks of `agf simulate --random 1000 --seed 7`
    # (session 46) that verified on a measurement of their own, 3 differ so: 122, 435 and 480, each with one of the
    # two outside the bounds (0.10-0.18 deg off), and 1 with both within them; at 2.5 sigmas 3 and 5.
    verify_pitch_sigmas: float = 3.0
    # Plans use this share of each drive's velocity, acceleration and jerk limits, so that a late
    # control cycle never asks a drive for more than it can give (a following-error fault).
    motion_share: float = 0.8
    # A viewing move (the forks hid the pallet) keeps the fork tips this far in front of the pallet's
    # front face as the forks move up or down: the refused measurement's pose is only rough.
    view_clearance: float = unit("mm", 0.1)
    # A measurement refused for any other reason is tried again from level with the pose its search roughly
    # found when that raises the lift at least this far (never lowers it: view_helps): seen from 200-300 mm above
    # or below, the edges of half the refused campaign picks were not found, and level is where the camera sees
    # the pallet best (it verifies from there). Closer than this, the view would hardly change.
    view_min_lift: float = unit("mm", 0.1)
    # A measurement refused with no such view to move to is taken once more with the forks raised this far (lift
    # only, never down: view_helps). The refusals are mostly about the pitch, with a line beside an edge or edges
    # not found, and a view from elsewhere sees other things beside them: of the first frames of `agf simulate
    # --random 200 --seed 7` refused for another reason than clipped highlights, rendered again with the forks
    # 100 mm higher, 17 of 105 measured, all within the bounds (50 mm higher: 12, 50 mm lower: 21; session 40).
    look_again_lift: float = unit("mm", 0.1)
    # A verifying measurement that is refused is taken again after the forks withdraw this far (reach) back
    # along their insertion line: the same view gives the same frame, and away from the pallet is the one way
    # that is clear of it whatever the refusal was about.
    verify_withdraw: float = unit("mm", 0.05)
    # Whatever the pallet stands on reaches its underside: the align move lifts (and tilts) the forks first where
    # moving all axes together would bring the tips forward of where they are below this height over it.
    support_clearance: float = unit("mm", 0.02)

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

    def align_motion(self, axes_now: Mapping[str, float], plan: InsertionPlan) -> Trajectory | MoveSequence:
        """The move to the plan's aligned axes, all axes together; lift and tilt first, then the rest, where moving
        together would carry the tines' tips forward of where they are while below the pallet's underside: whatever
        the pallet stands on (a truck bed, a dock) may reach out there, up to the tips (campaign seed 7, pick 259: a
        dock 0.32 m before the face of a pallet 0.26 m above the forks, their tips 48 mm clear of the dock's edge;
        moving together cut 32 mm into it)."""
        together = plan_move(axes_now, plan.align, self._motion_limits(), "time")
        if not self._passes_under_the_pallet(together, plan):
            return together
        rise = {name: plan.align[name] for name in ("lift", "tilt") if name in plan.align}
        rest = {name: value for name, value in plan.align.items() if name not in rise}
        first = plan_move(axes_now, rise, self._motion_limits(), "time")
        return MoveSequence(axes_now, (first, plan_move({**axes_now, **rise}, rest, self._motion_limits(), "time")))

    def insert_motion(self, axes_now: Mapping[str, float], plan: InsertionPlan) -> Trajectory:
        target = {name: plan.insert[name] for name in ("reach", "lift")}
        return plan_move(axes_now, target, self._motion_limits(), "phase")

    def view_motion(self, axes_now: Mapping[str, float], pallet_in_fork: Transform) -> Trajectory:
        """The move to :func:`viewing_axes` (the forks hid the pallet roughly at ``pallet_in_fork``)."""
        target = viewing_axes(
            pallet_in_fork, axes_now, self.mast, self.forks, self.pallet, self.limits, self.settings.view_clearance
        )
        return plan_move(axes_now, target, self._motion_limits(), "time")

    def view_helps(self, axes_now: Mapping[str, float], pallet_in_fork: Transform) -> bool:
        """Whether a refused measurement that roughly put the pallet at ``pallet_in_fork`` is worth a viewing
        move: one is possible (:func:`viewing_axes`) and raises the lift at least ``view_min_lift``.

        Never down: a rough pose is furthest off in height where the pallet lies far below the camera, and the forks
        lowered onto a pallet that is higher than it says go into what it stands on. Campaign seed 7, pick 379: a
        pallet 226 mm below the forks, pitched -4.4 deg, roughly put 252 mm lower (and 174 mm further) with 70 % of
        its face's edges agreeing; the forks went 127 mm into its dock (counted since session 39). Raised, they pass
        in front of the pallet's face (lift only) with nothing above it. When the forks hide the pallet they are
        still lowered (:meth:`view_motion`): there is no other view."""
        try:
            target = viewing_axes(
                pallet_in_fork, axes_now, self.mast, self.forks, self.pallet, self.limits,
                self.settings.view_clearance,
            )
        except AgfError:
            return False
        return target["lift"] - axes_now["lift"] >= self.settings.view_min_lift

    def look_again_motion(self, axes_now: Mapping[str, float], pallet_in_fork: Transform | None) -> Trajectory:
        """The forks raised by ``look_again_lift`` (lift only) to measure once more from there, after a measurement
        refused where no view level with the pallet is known to help (:meth:`view_helps`).

        The pick starts with the tines' tips in front of the pallet's face, as the truck's approach leaves them, so
        that they rise clear of it; where the refusal roughly placed the pallet (``pallet_in_fork``, or None), its
        face must also be ``view_clearance`` in front of them.

        Raises
        ------
        AgfError
            When the lift would leave its limits or the rough pose puts the face closer than ``view_clearance``.
        """
        lift = axes_now["lift"] + self.settings.look_again_lift
        if not self.limits["lift"].contains(lift):
            raise AgfError(f"no room to raise the forks and look again: the lift would be at {lift * 1e3:.0f} mm, "
                           f"its limit is {self.limits['lift'].maximum * 1e3:.0f} mm")
        if pallet_in_fork is not None:
            gap = tips_gap(pallet_in_fork, axes_now, self.mast, self.forks, self.pallet)
            if gap < self.settings.view_clearance:
                raise AgfError(f"the pallet's face is roughly {gap * 1e3:.0f} mm in front of the tips: too close to "
                               f"raise the forks and look again (at least {self.settings.view_clearance * 1e3:.0f} mm)")
        return plan_move(axes_now, {**axes_now, "lift": lift}, self._motion_limits(), "time")

    def _passes_under_the_pallet(self, motion: Trajectory, plan: InsertionPlan, samples: int = 50) -> bool:
        """Whether ``motion`` brings a corner of the tines' tips forward of the tips' start (pallet frame) while it
        is lower than the pallet's underside plus ``support_clearance``."""
        tips = self.forks.tip_corners()
        truck_in_pallet = plan.pallet_in_truck.inverse()
        path = np.array([(truck_in_pallet @ fork_in_truck_from_axes({**plan.align, **motion.at(t)}, self.mast))
                         .apply(tips) for t in np.linspace(0.0, motion.duration, samples)])
        forward = path[:, :, 0] > path[0, :, 0].max()
        low = path[:, :, 2] < self.pallet.deck_bottom + self.settings.support_clearance
        return bool(np.any(forward & low))

    def _motion_limits(self) -> dict[str, AxisLimits]:
        return {name: a.scaled(self.settings.motion_share) for name, a in self.limits.items()}

    def withdraw_motion(self, axes_now: Mapping[str, float], plan: InsertionPlan) -> Trajectory:
        """The move ``verify_withdraw`` back (reach) along the plan's insertion line from ``axes_now``, so that
        the insertion from there follows the planned line; :class:`AgfError` when it leaves the axis limits."""
        travel = plan.insert["reach"] - plan.align["reach"]
        if travel <= 0:
            raise AgfError(f"the plan inserts by {travel * 1e3:.0f} mm of reach: there is no line to withdraw along")
        share = self.settings.verify_withdraw / travel
        target = {name: axes_now[name] - (plan.insert[name] - plan.align[name]) * share for name in ("reach", "lift")}
        try:
            return plan_move(axes_now, target, self._motion_limits(), "phase")
        except ValueError as exc:
            raise AgfError(f"no room to withdraw the forks and verify again: {exc}") from exc

    def verify(
        self, measurement: PalletMeasurement, plan: InsertionPlan, axes: Mapping[str, float] | None = None
    ) -> str | None:
        """After aligning, the pallet should be where the plan put it relative to the forks at ``axes`` (the
        plan's aligned ones by default): at the stand-off, level with them and, with no side shift to correct
        it, as far to the side as first measured. A pallet bumped since (sideways too) is caught here, before
        inserting: the problem, for a new plan, or None.

        Raises
        ------
        MeasurementError
            When the measurement contradicts the plan's in what a bump cannot change (:func:`check_support_unchanged`).
        """
        fork_in_truck = self._fork_in_truck(plan, axes)
        check_support_unchanged(fork_in_truck @ measurement.pallet_in_fork, plan.pallet_in_truck, self.settings,
                                math.hypot(measurement.sigma_pitch, plan.sigma_pitch))
        expected = fork_in_truck.inverse() @ plan.pallet_in_truck
        d = measurement.pallet_in_fork
        pitch = d.euler[1]
        position_error = float(np.linalg.norm(d.translation - expected.translation))
        if position_error > self.settings.verify_position or abs(pitch) > self.settings.verify_pitch:
            return (
                f"after aligning the pallet is {position_error * 1e3:.1f} mm and {math.degrees(pitch):.2f} deg "
                "from where the forks expect it"
            )
        return None

    def expected(self, plan: InsertionPlan, axes: Mapping[str, float] | None = None) -> Transform:
        """Where ``plan`` puts the pallet (frame P in the fork frame) with the forks at ``axes`` (the plan's aligned
        ones by default)."""
        return self._fork_in_truck(plan, axes).inverse() @ plan.pallet_in_truck

    def _fork_in_truck(self, plan: InsertionPlan, axes: Mapping[str, float] | None) -> Transform:
        return fork_in_truck_from_axes(plan.align if axes is None else {**plan.align, **axes}, self.mast)


def check_support_unchanged(
    measured_in_truck: Transform, planned_in_truck: Transform, settings: PickSettings, sigma_pitch: float
) -> None:
    """Refuse a verifying measurement (pallet in the truck frame) that puts the pallet higher or lower than the
    plan's (``verify_height_change``) or at another pitch (``verify_pitch_change``, or ``verify_pitch_sigmas`` times
    ``sigma_pitch``, the standard deviation (rad) of the two pitches' difference).

    Raises
    ------
    MeasurementError
        Naming both measurements' height and pitch, and the limits.
    """
    rise = float(measured_in_truck.translation[2] - planned_in_truck.translation[2])
    tip = measured_in_truck.euler[1] - planned_in_truck.euler[1]
    if abs(rise) > settings.verify_height_change or abs(tip) > settings.verify_pitch_change:
        raise MeasurementError(
            f"the verifying measurement puts the pallet {abs(rise) * 1e3:.1f} mm {'higher' if rise > 0 else 'lower'} "
            f"and its pitch {math.degrees(tip):+.2f} deg from the one the plan was made from (at most "
            f"{settings.verify_height_change * 1e3:.0f} mm and "
            f"{math.degrees(settings.verify_pitch_change):.1f} deg): a pallet on its support is not raised or tipped, "
            "so one of the two measurements is wrong; refusing rather than guessing"
        )
    if abs(tip) > settings.verify_pitch_sigmas * sigma_pitch:
        raise MeasurementError(
            f"the verifying measurement's pitch is {math.degrees(tip):+.3f} deg from the one the plan was made from, "
            f"{abs(tip) / sigma_pitch if sigma_pitch > 0 else math.inf:.1f} times the +-{math.degrees(sigma_pitch):.3f}"
            f" deg the two state together (at most {settings.verify_pitch_sigmas:g}): one of them is further off than "
            "it says; refusing rather than guessing"
        )


def tips_gap(
    pallet_in_fork: Transform,
    axes_now: Mapping[str, float],
    mast: MastGeometry,
    forks: ForkGeometry,
    pallet: PalletType,
) -> float:
    """How far (m) the pallet's front face lies in front of the tines' tips along the truck: the nearest corner of
    the face (``pallet_in_fork``, at the axes ``axes_now``) less the foremost corner of the tips; negative where
    the tips are past it."""
    fork_in_truck = fork_in_truck_from_axes(axes_now, mast)
    face = np.array([[0.0, y, z] for y in (-pallet.width / 2, pallet.width / 2)
                     for z in (pallet.deck_bottom, pallet.deck_top)])
    return float((fork_in_truck @ pallet_in_fork).apply(face)[:, 0].min()
                 - fork_in_truck.apply(forks.tip_corners())[:, 0].max())


def viewing_axes(
    pallet_in_fork: Transform,
    axes_now: Mapping[str, float],
    mast: MastGeometry,
    forks: ForkGeometry,
    pallet: PalletType,
    limits: Mapping[str, AxisLimits],
    clearance: float,
) -> dict[str, float]:
    """Axis targets from which the camera sees a pallet that the forks hid: the forks level with its
    pockets.

    A pallet well below the forks is seen past the tines' tips; level with the forks, the camera above
    them looks down at the pocket line in front of the tips, as it does when it verifies the aligned
    forks. Only the lift moves: reach and tilt keep the tips where they are along the truck, so they
    pass the pallet's front face at the distance they have now, which must be at least ``clearance``
    (m) from the face's nearest corner.

    Parameters
    ----------
    pallet_in_fork : Transform
        Rough pose of the pallet (frame P in fork frame F) at the axes ``axes_now`` (m, rad).

    Raises
    ------
    AgfError
        If the tips are closer to the pallet than ``clearance`` or the lift would leave its limits.
    """
    gap = tips_gap(pallet_in_fork, axes_now, mast, forks, pallet)
    if gap < clearance:
        raise AgfError(
            f"the forks hide the pallet, and their tips are {gap * 1e3:.0f} mm from its front face: no room to "
            f"move them out of the camera's view (at least {clearance * 1e3:.0f} mm needed)"
        )
    # Lifting by d moves the pallet by -d cos(tilt) along the fork's z axis.
    lift = axes_now["lift"] + pallet_in_fork.translation[2] / math.cos(axes_now.get("tilt", 0.0))
    if not limits["lift"].contains(lift):
        raise AgfError(
            f"the forks hide the pallet, and the lift that would show it ({lift * 1e3:.0f} mm) is outside the "
            f"lift's limits [{limits['lift'].minimum * 1e3:.0f}, {limits['lift'].maximum * 1e3:.0f}] mm"
        )
    return {**axes_now, "lift": lift}
