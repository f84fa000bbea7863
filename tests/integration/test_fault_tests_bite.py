"""The fault tests catch a broken reaction: rows whose fix has no earlier failing version are run
once more with the reaction sabotaged, and their assertion must fail.

Each sabotage is one monkeypatch of the code that reacts; the test of the row is then expected to
reject the pick (AssertionError from :func:`tests.integration.test_faults.assert_fault_at_rest`).
Sabotaged, each pick still ends in FAULT with the axes at rest, caught by another layer (measured:
the drives' heartbeat watchdog, "heartbeat lost", for the bus; the verification's tolerance on the
stale start frame for the timeout; the vision's own size check for the half-height frame), but not
for the row's reason, which is what its test asserts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agf.frames import FrameSource
from drivers.cia402_axis import Cia402Network
from drivers.sim.fault_bench import SCENARIOS, FaultPick, replay_folder, run_scenario
from tests.integration.test_faults import (  # noqa: F401
    CAMERA_FAULTS,
    _bad_frame,
    assert_fault_at_rest,
    pick_folder,
    rendered,  # noqa: F401 - the session fixture
)


def test_bus_gone_row_fails_when_the_master_ignores_a_failed_send(monkeypatch, pick_folder) -> None:  # noqa: F811
    monkeypatch.setattr(Cia402Network, "_bus_failed", lambda self, exc: None)
    reaction = run_scenario(pick_folder, "can_bus_gone")
    with pytest.raises(AssertionError):
        assert_fault_at_rest(reaction, SCENARIOS["can_bus_gone"][2])


def _replaying_stale_frames(read):
    """A camera driver bug: on a timeout it hands out its last frame again."""
    last: dict[int, np.ndarray] = {}

    def stale(self: FrameSource, timeout: float) -> np.ndarray | None:
        image = read(self, timeout)
        if image is not None:
            last[id(self)] = image
        return last.get(id(self))

    return stale


@pytest.mark.parametrize("kind", ["timeout", "wrong_size"])
def test_camera_rows_fail_when_the_frame_check_is_broken(monkeypatch, rendered, tmp_path: Path,  # noqa: F811
                                                         kind: str) -> None:
    from drivers.camera_source import Folder

    if kind == "timeout":
        monkeypatch.setattr(Folder, "_read", _replaying_stale_frames(Folder._read))
    else:
        original = FrameSource.read

        def any_size(self: FrameSource, timeout: float = 1.0):
            image = self._read(timeout)
            if image is not None:  # adopt the frame's size: the size check can no longer refuse it
                self._read = lambda timeout, image=image: image
                self.width, self.height = image.shape[1], image.shape[0]
            try:
                return original(self, timeout)
            finally:
                self.__dict__.pop("_read", None)

        monkeypatch.setattr(FrameSource, "read", any_size)
    frames = [rendered["start"]]
    if kind != "timeout":
        frames += [_bad_frame(kind, rendered["aligned"], tmp_path)] * 3
    with FaultPick(replay_folder(tmp_path / "frames", frames)) as pick:
        reaction = pick.run()
    with pytest.raises(AssertionError):
        assert_fault_at_rest(reaction, CAMERA_FAULTS[kind])
