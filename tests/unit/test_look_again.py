"""A refused first measurement that no viewing move answers: the forks rise ``insertion.look_lift_mm`` (the lift
alone, within its limits) and the pick measures once more from there.

The controller's logic is the unit in the first tests (its axes follow their setpoints at once, as in
test_fleet_pause); the planner's own move is :meth:`PickPlanner.look_motion`, tested below it."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from agf.axis import AxisLimits
from agf.config import ForkGeometry
from agf.controller import ControllerConfig, PickController
from agf.errors import AgfError, MeasurementError
from agf.kinematics import MastGeometry
from agf.pallets import load_pallets
from agf.paths import repo_path
from agf.planner import PickPlanner, PickSettings, pick_settings_from_mapping
from tests.unit.test_fleet_pause import BlankCamera, IdealAxis, LiftBy


class Looking(LiftBy):
    """LiftBy whose look raises the lift 0.15 m, or refuses when ``room`` is False; a refused measurement's
    rough pose is never worth a view."""

    def __init__(self, room: bool = True) -> None:
        self.room, self.looked_from = room, []

    def view_helps(self, axes_now, pallet_in_fork):
        return False

    def look_motion(self, axes_now):
        if not self.room:
            raise AgfError("no room to raise the forks 150 mm and look again")
        start = axes_now["lift"]
        self.looked_from.append(start)
        return SimpleNamespace(duration=0.05, at=lambda t: {"lift": start + 0.15 * min(t / 0.05, 1.0)})


def pick_refused_first(refusals: int, planner: Looking, config: ControllerConfig | None = None):
    """A pick whose first ``refusals`` measurements are refused and whose later ones are accepted; the lift at
    each measurement."""
    lifts = []

    def measure(frame, prior):
        lifts.append(axis.position)
        if len(lifts) <= refusals:
            raise MeasurementError(f"refusal {len(lifts)}")
        return object()

    axis = IdealAxis()
    result = PickController({"lift": axis}, BlankCamera(4, 4), measure, planner, config or ControllerConfig()).run()
    return result, lifts


def test_a_refused_first_measurement_is_taken_again_from_the_raised_forks_and_the_pick_goes_on():
    planner = Looking()
    result, lifts = pick_refused_first(1, planner)
    assert result.ok, result.reason
    assert result.looks == ["refusal 1"] and result.views == []
    assert planner.looked_from == [0.0]
    assert lifts[:2] == [0.0, 0.15]  # measured again from 150 mm higher, then verified after aligning


def test_one_look_per_pick_the_next_refusal_ends_it_with_its_reason_and_no_further_motion():
    planner = Looking()
    result, lifts = pick_refused_first(2, planner)
    assert not result.ok and result.refused and result.state == "fault"
    assert result.reason == "measuring: refusal 2" and result.looks == ["refusal 1"]
    assert lifts == [0.0, 0.15]


def test_without_room_or_with_no_looks_configured_the_first_refusal_ends_the_pick():
    result, lifts = pick_refused_first(1, Looking(room=False))
    assert result.reason == "measuring: refusal 1" and result.looks == [] and lifts == [0.0]
    result, lifts = pick_refused_first(1, Looking(), ControllerConfig(looks=0))
    assert result.reason == "measuring: refusal 1" and result.looks == [] and lifts == [0.0]


MAST, FORKS = MastGeometry(), ForkGeometry()
PALLET = load_pallets(repo_path("configs/pallets.yaml"))["jis-t11"]
LIMITS = {
    "lift": AxisLimits(0.0, 3.0, 0.4, 0.8, 4.0),
    "reach": AxisLimits(0.0, 1.3, 0.25, 0.5, 2.5),
    "tilt": AxisLimits(-0.1, 0.1, 0.07, 0.14, 0.7),
}


def test_the_look_raises_the_lift_alone_by_look_lift():
    planner = PickPlanner(MAST, FORKS, PALLET, LIMITS)
    axes = {"lift": 0.6, "reach": 0.15, "tilt": 0.02}
    motion = planner.look_motion(axes)
    end = motion.at(motion.duration)
    assert end["lift"] == pytest.approx(0.75) and end["reach"] == pytest.approx(0.15)
    assert end["tilt"] == pytest.approx(0.02)
    assert all(motion.at(t)["lift"] >= 0.6 - 1e-9 for t in (0.0, motion.duration / 3, motion.duration / 2))


def test_a_look_beyond_the_lift_limit_or_configured_off_is_refused_with_the_reason():
    planner = PickPlanner(MAST, FORKS, PALLET, LIMITS)
    with pytest.raises(AgfError, match=r"no room to raise the forks 150 mm.*3050 mm.*\[0, 3000\] mm"):
        planner.look_motion({"lift": 2.9, "reach": 0.15, "tilt": 0.0})
    off = PickPlanner(MAST, FORKS, PALLET, LIMITS, pick_settings_from_mapping({"look_lift_mm": 0}, "insertion"))
    with pytest.raises(AgfError, match="look_lift_mm: 0"):
        off.look_motion({"lift": 0.6, "reach": 0.15, "tilt": 0.0})


def test_a_look_down_is_refused_in_the_configuration():
    with pytest.raises(ValueError, match="look_lift_mm: expected 0 .* got -150"):
        PickSettings(look_lift=-0.15)
