"""Clipped highlights: the vision refuses with an OverexposedError, and the controller asks the camera for a
shorter exposure and measures again, a bounded number of times; a camera that cannot change its exposure
keeps the refusal. The controller's logic is the unit here (test_fleet_pause's ideal axis and planner); the
simulated camera's darker frames are exercised by tests/integration/test_clock_pick.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agf.controller import ControllerConfig, PickController
from agf.errors import MeasurementError, NotAvailableError, OverexposedError, PalletHiddenError
from agf.frames import FrameSource
from agf.geometry import Transform
from agf.vision.measure import _refusal
from drivers.camera_source import ImageFile
from tests.unit.test_fleet_pause import BlankCamera, IdealAxis, LiftBy


class ExposedCamera(FrameSource):
    """A grey frame as bright as the exposure: 200 at the configured one."""

    def _set_exposure(self, scale: float) -> None:
        pass

    def _read(self, timeout: float) -> np.ndarray:
        return np.full((4, 4), round(200 * self.exposure), np.uint8)


def clipped_above(level: int, measured: list):
    """A measurement refused for clipped highlights on frames brighter than ``level``; ``measured`` collects
    each frame's level."""

    def measure(frame, prior):
        measured.append(int(frame.image[0, 0]))
        if measured[-1] > level:
            raise OverexposedError(f"the top deck is overexposed at {measured[-1]}")
        return object()

    return measure


def run(camera: FrameSource, measure):
    axis = IdealAxis()
    return PickController({"lift": axis}, camera, measure, LiftBy(), ControllerConfig()).run(), axis


def test_a_clipped_frame_is_measured_again_darker_until_it_measures_and_the_exposure_is_set_back():
    camera, measured = ExposedCamera(4, 4), []
    result, axis = run(camera, clipped_above(100, measured))
    assert result.ok, result.reason
    assert measured == [200, 120, 72, 72]  # 1.0, 0.6, 0.36 of the exposure; verified at the last
    assert result.exposures == ["the top deck is overexposed at 200", "the top deck is overexposed at 120"]
    assert camera.exposure == 1.0 and axis.position == 0.2


def test_with_no_shorter_exposure_left_the_refusal_ends_the_pick_before_any_motion():
    camera, measured = ExposedCamera(4, 4), []
    result, axis = run(camera, clipped_above(50, measured))
    assert not result.ok and result.refused
    assert result.reason == "measuring: the top deck is overexposed at 72"
    assert measured == [200, 120, 72] and len(result.exposures) == 2
    assert camera.exposure == 1.0 and axis.position == 0.0


def test_a_camera_that_cannot_change_its_exposure_keeps_the_first_refusal():
    measured = []
    result, axis = run(BlankCamera(4, 4), clipped_above(100, measured))
    assert result.reason == "measuring: the top deck is overexposed at 128" and result.exposures == []
    assert measured == [128] and axis.position == 0.0


def test_a_clipped_verifying_frame_is_read_again_darker_in_place_without_withdrawing():
    camera, measured = ExposedCamera(4, 4), []

    def measure(frame, prior):
        if len(measured) == 1 and frame.image[0, 0] > 150:  # the first verifying frame only
            measured.append(int(frame.image[0, 0]))
            raise OverexposedError("clipped while verifying")
        measured.append(int(frame.image[0, 0]))
        return object()

    result, axis = run(camera, measure)
    assert result.ok, result.reason
    assert measured == [200, 200, 120] and result.withdrawals == [] and result.exposures == ["clipped while verifying"]
    assert camera.exposure == 1.0 and axis.position == 0.2


def test_a_camera_that_fails_to_set_its_exposure_back_leaves_the_pick_as_it_ended():
    class Stuck(ExposedCamera):
        def _set_exposure(self, scale: float) -> None:
            if scale == 1.0:
                raise NotAvailableError("the device stopped answering")

    camera, measured = Stuck(4, 4), []
    result, axis = run(camera, clipped_above(150, measured))
    assert result.ok, result.reason
    assert camera.exposure == pytest.approx(0.6) and axis.position == 0.2


@pytest.mark.parametrize("step", [0.0, 1.0, 1.5])
def test_an_exposure_step_that_does_not_shorten_is_a_value_error(step):
    with pytest.raises(ValueError, match="exposure_step"):
        ControllerConfig(exposure_step=step)


def test_set_exposure_checks_its_range_and_a_file_cannot_change_its_exposure(tmp_path: Path):
    camera = ExposedCamera(4, 4)
    for scale in (0.0, 1.2):
        with pytest.raises(ValueError, match="exposure scale"):
            camera.set_exposure(scale)
    assert camera.exposure == 1.0
    still = ImageFile(tmp_path / "frame.png", 4, 4)
    with pytest.raises(NotAvailableError, match="cannot change its exposure"):
        still.set_exposure(0.5)
    assert still.exposure == 1.0


def test_a_refusal_is_overexposed_when_any_search_was_clipped_unless_the_forks_hid_the_pallet():
    clipped, other = OverexposedError("clipped"), MeasurementError("no pitch")
    error = _refusal([other, clipped], _volume(), ["face", "regions"], None, None, None)
    assert isinstance(error, OverexposedError) and str(error).startswith("no pitch")
    assert type(_refusal([other, other], _volume(), ["face", "regions"], None, None, None)) is MeasurementError
    hidden = PalletHiddenError("the forks hide 40%", Transform())
    error = _refusal([clipped, hidden], _volume(), ["face", "regions"], None, None, Transform())
    assert type(error) is PalletHiddenError and error.pallet_in_fork is not None


def test_regression_a_hidden_pallet_whose_pose_the_image_does_not_confirm_is_refused_with_no_rough_pose():
    """Campaign seed 7 pick 379: a hidden search's pose 159 mm too low moved the forks into the dock; the refusal
    carries the pose only as the image confirmed it (``hidden_rough``), never the search's own."""
    hidden = PalletHiddenError("the forks hide 40%", Transform())
    error = _refusal([hidden], _volume(), ["face", "regions"], None, None, None)
    assert type(error) is PalletHiddenError and error.pallet_in_fork is None


def _volume():
    from agf.config import SearchVolume

    return SearchVolume()


def _hypothesis(name: str, ratio: float, top_clipped: float = 0.0):
    from agf.vision.pitch import PitchEvidence

    return PitchEvidence(name, ratio, False, float("nan"), np.full(3, np.nan), None, [], [], top_clipped=top_clipped)


@pytest.mark.parametrize("top, load, overexposed", [(0.72, 0.19, True), (0.4, 0.19, False), (0.72, 0.6, False)])
def test_a_clipped_top_deck_is_overexposed_only_where_no_load_edges_were_found(top, load, overexposed):
    """PitchConfig.max_deck_top_clipped: neither edges found under a deck 72 % clipped (campaign seed 7 pick 214)
    asks for a shorter exposure; a load's edges found mean the clipped top is the load's (pick 205 was accepted 0.185
    deg off so), and a deck 40 % clipped is no reason."""
    from agf.vision.measure import _choose
    from agf.vision.pitch import PitchConfig

    evidence = {"unloaded": _hypothesis("unloaded", 0.2, top), "loaded": _hypothesis("loaded", load)}
    with pytest.raises(MeasurementError) as refusal:
        _choose(evidence, PitchConfig())
    assert isinstance(refusal.value, OverexposedError) == overexposed, refusal.value
