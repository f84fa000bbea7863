"""The pause hook the fleet's startPause / stopPause and a lost broker use: PickController holds at the next
state boundary, sends no setpoint while it holds, continues on resume, and still stops while held.

The controller's logic is the unit here, so its axes follow their setpoints at once and its planner
moves the lift 0.1 m per motion; the whole-truck behaviour is tests/integration/test_fleet.py's."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np

from agf.axis import Axis, AxisFeedback, AxisLimits, AxisState
from agf.controller import ControllerConfig, PickController
from agf.frames import FrameSource


class IdealAxis(Axis):
    """An axis that is where its last setpoint put it."""

    def __init__(self) -> None:
        super().__init__("lift", AxisLimits(0.0, 2.0, 1.0, 1.0, 1.0))
        self.position, self.state, self.setpoints = 0.0, AxisState.DISABLED, 0

    def _enable(self, timeout: float) -> None:
        self.state = AxisState.ENABLED

    def _disable(self) -> None:
        self.state = AxisState.DISABLED

    def _quick_stop(self) -> None:
        self.state = AxisState.QUICK_STOP

    def _fault_reset(self, timeout: float) -> None:
        self.state = AxisState.DISABLED

    def _send_setpoint(self, position: float) -> None:
        self.position, self.setpoints = position, self.setpoints + 1

    def _feedback(self) -> AxisFeedback:
        return AxisFeedback(self.position, 0.0, self.state, time.monotonic())


class BlankCamera(FrameSource):
    """A plain grey frame: neither black nor saturated, so the frame checks pass it on."""

    def _read(self, timeout: float) -> np.ndarray:
        return np.full((4, 4), 128, np.uint8)


class LiftBy:
    """Plans a 0.1 m lift for aligning and for inserting, each lasting 0.05 s."""

    def plan(self, measurement, axes_now):
        return SimpleNamespace(safe=True, reason=None)

    def align_motion(self, axes_now, plan):
        start = axes_now["lift"]
        return SimpleNamespace(duration=0.05, at=lambda t: {"lift": start + 0.1 * min(t / 0.05, 1.0)})

    insert_motion = align_motion

    def verify(self, measurement, plan, axes=None):
        return None


def controller(pause_in: str | None) -> tuple[PickController, IdealAxis, list[str]]:
    """A controller that pauses itself when it reports ``pause_in``; its axis and the states it reported."""
    axis, states = IdealAxis(), []
    pick = PickController(
        {"lift": axis}, BlankCamera(4, 4), lambda frame, prior: object(), LiftBy(), ControllerConfig()
    )

    def progress(state: str) -> None:
        states.append(state)
        if state == pause_in:
            pick.pause()

    pick.progress = progress
    return pick, axis, states


def run_in_thread(pick: PickController) -> tuple[threading.Thread, dict]:
    out: dict = {}
    thread = threading.Thread(target=lambda: out.update(result=pick.run()), daemon=True)
    thread.start()
    return thread, out


def wait_until(test, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not test():
        assert time.monotonic() < deadline
        time.sleep(0.01)


def test_a_pause_holds_between_motions_and_resume_continues():
    pick, axis, states = controller(pause_in="verifying")
    thread, out = run_in_thread(pick)
    wait_until(lambda: states[-1] == "paused")
    held_at, setpoints = axis.position, axis.setpoints
    time.sleep(0.2)
    assert pick._state() == "inserting" and axis.position == held_at == 0.1 and axis.setpoints == setpoints
    pick.resume()
    thread.join(5)
    assert out["result"].ok and axis.position == 0.2
    assert states[states.index("paused") - 1 :] == ["verifying", "paused", "inserting"]


def test_without_a_pause_nothing_holds():
    pick, axis, states = controller(pause_in=None)
    assert pick.run().ok and "paused" not in states and axis.position == 0.2


def test_a_stop_while_held_ends_in_fault_without_motion():
    pick, axis, states = controller(pause_in="planning")
    thread, out = run_in_thread(pick)
    wait_until(lambda: states[-1] == "paused")
    pick.stop("cancelled by the fleet")
    thread.join(5)
    result = out["result"]
    assert result.state == "fault" and result.reason == "aligning: cancelled by the fleet"
    assert axis.position == 0.0 and axis.state is AxisState.QUICK_STOP
