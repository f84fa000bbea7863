"""A refused first measurement with no view level with the pallet to move to: the controller raises the forks by the
planner's look-again move and measures once more (``ControllerConfig.views``, one by default); where the planner has
no such move, the vision's refusal ends the pick, refused, with no motion.

The controller's logic is the unit here: its axes follow their setpoints at once (test_fleet_pause's); the planner's
own look-again move is tested in test_viewing_pose."""

from __future__ import annotations

from types import SimpleNamespace

from agf.controller import ControllerConfig, PickController
from agf.errors import AgfError, MeasurementError
from tests.unit.test_fleet_pause import BlankCamera, IdealAxis, LiftBy


class LookingAgain(LiftBy):
    """LiftBy whose look-again move raises the lift 0.05 m (or, ``room=False``, says there is no room); it records
    the rough poses it was asked about."""

    def __init__(self, room: bool = True) -> None:
        self.room, self.asked = room, []

    def view_helps(self, axes_now, pallet_in_fork):
        return False

    def look_again_motion(self, axes_now, pallet_in_fork):
        self.asked.append(pallet_in_fork)
        if not self.room:
            raise AgfError("no room to raise the forks and look again: the lift would be at 3050 mm")
        start = axes_now["lift"]
        return SimpleNamespace(duration=0.05, at=lambda t: {"lift": start + 0.05 * min(t / 0.05, 1.0)})


def pick_refused_first(refusals: int, planner: LookingAgain, config: ControllerConfig | None = None):
    """A pick whose first ``refusals`` measurements are refused (no rough pose) and whose later ones are accepted."""
    calls = []

    def measure(frame, prior):
        calls.append(prior)
        if len(calls) <= refusals:
            raise MeasurementError(f"refusal {len(calls)}: a second line runs beside the unloaded edges")
        return object()

    axis = IdealAxis()
    result = PickController({"lift": axis}, BlankCamera(4, 4), measure, planner, config or ControllerConfig()).run()
    return result, axis, calls


def test_a_refused_first_measurement_is_taken_again_after_the_look_again_move_and_the_pick_goes_on():
    planner = LookingAgain()
    result, axis, calls = pick_refused_first(1, planner)
    assert result.ok, result.reason
    assert result.views == ["refusal 1: a second line runs beside the unloaded edges"] and planner.asked == [None]
    assert len(calls) == 3  # measuring, measuring again from higher, verifying
    assert axis.position == 0.05 + 0.1 + 0.1  # looked again from 0.05 higher, then aligned and inserted


def test_the_refusal_after_the_look_again_ends_the_pick_refused_where_the_move_left_the_forks():
    result, axis, _ = pick_refused_first(2, LookingAgain())
    assert not result.ok and result.refused and result.state == "fault"
    assert result.reason == "measuring: refusal 2: a second line runs beside the unloaded edges"
    assert len(result.views) == 1 and axis.position == 0.05


def test_without_room_to_look_again_the_vision_refusal_ends_the_pick_with_no_motion():
    planner = LookingAgain(room=False)
    result, axis, calls = pick_refused_first(1, planner)
    assert not result.ok and result.refused
    assert result.reason == "measuring: refusal 1: a second line runs beside the unloaded edges"
    assert result.views == [] and planner.asked == [None] and axis.position == 0.0 and len(calls) == 1


def test_with_no_viewing_move_configured_the_first_refusal_ends_the_pick_without_asking_the_planner():
    planner = LookingAgain()
    result, axis, _ = pick_refused_first(1, planner, ControllerConfig(views=0))
    assert result.reason == "measuring: refusal 1: a second line runs beside the unloaded edges"
    assert result.views == [] and planner.asked == [] and axis.position == 0.0
