"""A refused verifying measurement: the controller withdraws the forks along the planned line (the
planner's move) and measures again, once by default (``ControllerConfig.withdrawals``); after the last, the frame's
face is confirmed where the plan expects it (``confirm``, when the controller has one), else the refusal ends the
pick in FAULT.

The controller's logic is the unit here: its axes follow their setpoints at once (test_fleet_pause's),
the planner's moves are 0.1 m of lift; the planner's own withdrawal is tested in test_viewing_pose."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from agf.controller import ControllerConfig, PickController
from agf.errors import MeasurementError
from tests.unit.test_fleet_pause import BlankCamera, IdealAxis, LiftBy


class Withdrawing(LiftBy):
    """LiftBy whose withdrawal lowers the lift 0.03 m; it records the forks' axes it verified at."""

    def __init__(self) -> None:
        self.verified_at: list = []

    def plan(self, measurement, axes_now):
        return SimpleNamespace(safe=True, reason=None, align={"lift": axes_now["lift"] + 0.1})

    def withdraw_motion(self, axes_now, plan):
        start = axes_now["lift"]
        return SimpleNamespace(duration=0.05, at=lambda t: {"lift": start - 0.03 * min(t / 0.05, 1.0)})

    def verify(self, measurement, plan, axes=None):
        self.verified_at.append(axes)
        return None


def pick_refusing(verifying_refusals: int, config: ControllerConfig | None = None):
    """A pick whose first measurement is accepted and whose next ``verifying_refusals`` are refused."""
    calls = []

    def measure(frame, prior):
        calls.append(prior)
        if 1 < len(calls) <= 1 + verifying_refusals:
            raise MeasurementError(f"refusal {len(calls) - 1} while verifying")
        return object()

    axis, planner = IdealAxis(), Withdrawing()
    result = PickController({"lift": axis}, BlankCamera(4, 4), measure, planner, config or ControllerConfig()).run()
    return result, axis, planner, calls


def test_a_refused_verification_is_measured_again_from_the_withdrawn_forks_and_the_pick_goes_on():
    result, axis, planner, priors = pick_refusing(1)
    assert result.ok, result.reason
    assert result.withdrawals == ["refusal 1 while verifying"]
    assert planner.verified_at == [{"lift": 0.1 - 0.03}]  # verified where the withdrawal ended, not at align
    assert len(priors) == 3  # measuring, verifying refused, verifying again
    assert axis.position == 0.07 + 0.1  # and inserted from there


def test_the_refusal_after_the_last_withdrawal_ends_the_pick_with_its_reason_and_no_further_motion():
    result, axis, planner, _ = pick_refusing(2)
    assert not result.ok and result.state == "fault"
    assert result.reason == "verifying: refusal 2 while verifying"
    assert axis.position == 0.07 and planner.verified_at == []


def test_with_more_withdrawals_configured_each_starts_where_the_last_ended():
    result, axis, planner, priors = pick_refusing(3, ControllerConfig(withdrawals=3))
    assert result.ok, result.reason
    assert len(result.withdrawals) == 3 and len(priors) == 5
    assert planner.verified_at == [{"lift": pytest.approx(0.1 - 0.09)}]
    refused, axis, planner, _ = pick_refusing(4, ControllerConfig(withdrawals=3))
    assert refused.reason == "verifying: refusal 4 while verifying" and len(refused.withdrawals) == 3
    assert planner.verified_at == [] and axis.position == pytest.approx(0.1 - 0.09)


def test_with_no_withdrawals_configured_the_first_refusal_ends_the_pick():
    result, axis, _, _ = pick_refusing(1, ControllerConfig(withdrawals=0))
    assert result.reason == "verifying: refusal 1 while verifying" and result.withdrawals == []
    assert axis.position == 0.1


def test_without_room_to_withdraw_the_refusal_ends_the_pick_as_a_refusal_not_a_fault():
    """Seed 7 campaign picks aligned 10-40 mm from the reach's lower limit: the withdrawal's own error
    (no room) ended them as faulted; the vision's refusal is what ended them."""
    from agf.errors import AgfError

    class Cornered(Withdrawing):
        def withdraw_motion(self, axes_now, plan):
            raise AgfError("no room to withdraw the forks and verify again: target -0.0397 of axis reach ...")

    calls = []

    def measure(frame, prior):
        calls.append(prior)
        if len(calls) > 1:
            raise MeasurementError("a second line runs beside the unloaded edges")
        return object()

    axis = IdealAxis()
    result = PickController({"lift": axis}, BlankCamera(4, 4), measure, Cornered(), ControllerConfig()).run()
    assert result.reason == "verifying: a second line runs beside the unloaded edges"
    assert result.withdrawals == [] and axis.position == 0.1 and len(calls) == 2


class Expecting(Withdrawing):
    """Withdrawing that also says where its plan expects the pallet: a marker naming the axes."""

    def expected(self, plan, axes=None):
        return ("expected at", None if axes is None else dict(axes))


def pick_confirmed(confirm_refuses: bool):
    """A pick whose verifying measurements are all refused and whose ``confirm`` is given; what it was called with."""
    calls, confirmed = [], []

    def measure(frame, prior):
        calls.append(prior)
        if len(calls) > 1:
            raise MeasurementError(f"refusal {len(calls) - 1} while verifying")
        return "first"

    def confirm(frame, expected, measured):
        confirmed.append((expected, measured))
        if confirm_refuses:
            raise MeasurementError("no convincing pallet front face")
        return "confirmed"

    axis, planner = IdealAxis(), Expecting()
    controller = PickController({"lift": axis}, BlankCamera(4, 4), measure, planner, ControllerConfig(withdrawals=1),
                                confirm=confirm)
    return controller.run(), axis, planner, confirmed


def test_the_last_refused_verifying_frame_is_confirmed_where_the_plan_expects_the_pallet_and_the_pick_goes_on():
    result, axis, planner, confirmed = pick_confirmed(confirm_refuses=False)
    assert result.ok, result.reason
    assert result.withdrawals == ["refusal 1 while verifying"]
    assert result.confirmations == ["refusal 2 while verifying"]  # after the last withdrawal, on its frame
    assert confirmed == [(("expected at", {"lift": pytest.approx(0.07)}), "first")]  # at the withdrawn axes
    assert result.measurements == ["first", "confirmed"] and planner.verified_at == [{"lift": pytest.approx(0.07)}]


def test_a_face_not_confirmed_either_ends_the_pick_refused_with_both_reasons():
    result, axis, planner, confirmed = pick_confirmed(confirm_refuses=True)
    assert not result.ok and result.refused and result.confirmations == []
    assert result.reason == ("verifying: refusal 2 while verifying; the face was not confirmed where the plan expects "
                             "it either: no convincing pallet front face")
    assert axis.position == pytest.approx(0.07) and planner.verified_at == [] and len(confirmed) == 1


def test_a_pick_re_planned_on_a_verifying_measurement_is_not_confirmed_at_either_pitch():
    """Campaign pick 647 of seed 7 (session 37): a verifying frame accepted 0.42 deg off re-planned the pick, the next
    verifying frames were refused, and the face was confirmed at the wrong pitch. The measurements disagreed, so
    there is no pitch to keep: the refusal ends the pick."""

    class Replanning(Expecting):
        def verify(self, measurement, plan, axes=None):
            self.verified_at.append(axes)
            moved = "after aligning the pallet is 12.0 mm and 0.42 deg from where the forks expect it"
            return moved if len(self.verified_at) == 1 else None

    calls, confirmed = [], []

    def measure(frame, prior):
        calls.append(prior)
        if len(calls) > 2:
            raise MeasurementError(f"refusal {len(calls) - 2} while verifying")
        return f"measurement {len(calls)}"

    controller = PickController({"lift": IdealAxis()}, BlankCamera(4, 4), measure, Replanning(),
                                ControllerConfig(withdrawals=1), confirm=lambda *args: confirmed.append(args))
    result = controller.run()
    assert not result.ok and result.refused and confirmed == [] and result.confirmations == []
    assert result.reason == ("verifying: refusal 2 while verifying; not confirmed at the pitch measured before, as "
                             "the pick re-planned on a verifying measurement that moved the pallet")
    assert result.measurements == ["measurement 1", "measurement 2"]


class ShortAxis(IdealAxis):
    """Stops 1.5 mm short of every setpoint above its last position, within ControllerConfig.arrive_tolerance."""

    def _send_setpoint(self, position: float) -> None:
        super()._send_setpoint(position - 0.0015 if position > self.position else position)


def test_a_verifying_measurement_is_checked_against_the_forks_where_they_stopped_not_where_they_were_sent():
    """A drive arrives within arrive_tolerance of its target (2 mm, or 0.11 deg of tilt), and the plan's check of a
    verifying measurement's pitch against the first one's would otherwise count a tilt drive's shortfall as the
    pallet's."""
    axis, planner = ShortAxis(), Withdrawing()
    result = PickController({"lift": axis}, BlankCamera(4, 4), lambda frame, prior: object(), planner,
                            ControllerConfig()).run()
    assert result.ok, result.reason
    assert planner.verified_at == [{"lift": pytest.approx(0.1 - 0.0015)}]
