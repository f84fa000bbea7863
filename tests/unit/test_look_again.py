"""A refused first measurement with no view level with the pallet to move to: the controller raises the forks by the
planner's look-again move and measures once more (``ControllerConfig.views`` times, three by default); where the planner
has no such move, the vision's refusal ends the pick, refused, with no motion.

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


def test_a_pick_refused_after_its_first_look_again_looks_once_more_from_higher_and_goes_on():
    planner = LookingAgain()
    result, axis, calls = pick_refused_first(2, planner)
    assert result.ok, result.reason
    assert [v.split(":")[0] for v in result.views] == ["refusal 1", "refusal 2"] and planner.asked == [None, None]
    assert len(calls) == 4 and axis.position == 0.05 + 0.05 + 0.1 + 0.1


def test_by_default_a_pick_refused_after_two_looks_again_looks_a_third_time_and_goes_on():
    planner = LookingAgain()
    result, axis, calls = pick_refused_first(3, planner)
    assert result.ok, result.reason
    assert [v.split(":")[0] for v in result.views] == ["refusal 1", "refusal 2", "refusal 3"]
    assert len(calls) == 5 and axis.position == 3 * 0.05 + 0.1 + 0.1


def test_the_refusal_after_the_last_look_again_ends_the_pick_refused_where_the_moves_left_the_forks():
    for views in (1, 2, 3):
        result, axis, _ = pick_refused_first(views + 1, LookingAgain(), ControllerConfig(views=views))
        assert not result.ok and result.refused and result.state == "fault"
        assert result.reason == f"measuring: refusal {views + 1}: a second line runs beside the unloaded edges"
        assert len(result.views) == views and axis.position == 0.05 * views


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


def test_regression_a_hidden_pallet_with_no_room_for_the_viewing_move_ends_the_pick_refused_not_faulted():
    """Seed 7 campaign pick 763 with two views: after the look from higher the forks hid the pallet with their tips
    12 mm from its face; the viewing move's own error (no room to move them out of the view) ended the pick as
    faulted. The vision's refusal is what ends it, with no motion after it."""
    from agf.errors import PalletHiddenError
    from agf.geometry import Transform

    class Cornered(LookingAgain):
        def view_motion(self, axes_now, pallet_in_fork):
            self.asked.append(pallet_in_fork)
            raise AgfError("the forks hide the pallet, and their tips are 12 mm from its front face: no room to move "
                           "them out of the camera's view")

    rough = Transform.from_euler(0.3, 0.0, -0.2, 0.0, 0.0, 0.0)

    def measure(frame, prior):
        raise PalletHiddenError("the forks hide 37% of the pallet's pocket edges from the camera", rough)

    planner, axis = Cornered(), IdealAxis()
    result = PickController({"lift": axis}, BlankCamera(4, 4), measure, planner, ControllerConfig()).run()
    assert not result.ok and result.refused
    assert result.reason == "measuring: the forks hide 37% of the pallet's pocket edges from the camera"
    assert result.views == [] and planner.asked == [rough] and axis.position == 0.0
