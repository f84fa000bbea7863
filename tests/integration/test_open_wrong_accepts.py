"""Wrong accepts found on the project's randomised renders (agf bench accuracy.randomised, and the first frames
of campaign picks, accuracy.campaign).

Each scene in ``fixed-wrong-accepts/`` was once accepted outside the bounds and is now refused or measured
within them; the scene files say where each came from and what fixed it. A wrong accept found and not yet
fixed goes in ``open-wrong-accepts/``, where it is a strict xfail (an unexpected pass fails the suite, so the
scene moves to ``fixed-wrong-accepts/`` the day it is fixed).
"""

from __future__ import annotations

import pytest

from agf.camera import load_camera
from agf.config import load_config
from agf.errors import MeasurementError
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.scene import load_scene
from agf.vision.accuracy import pose_errors, within_bounds
from agf.vision.measure import measure_pallet
from tests.integration.conftest import SCENES

CONFIG = load_config(DEFAULT_CONFIG)
OPEN = pytest.mark.xfail(
    strict=True, raises=AssertionError, reason="accepted outside the bounds under random looks: open, see issue 17"
)
SCENE_FILES = [
    pytest.param(path, id=f"{folder}/{path.stem}", marks=[OPEN] if folder.startswith("open") else [])
    for folder in ("open-wrong-accepts", "fixed-wrong-accepts")
    for path in sorted((SCENES / folder).glob("*.yaml"))
]


# Scenes found on the campaign renderer's frames with texture steps sub-sampled at this contrast (fast_render
# .TEXTURE_CONTRAST); the others on the frames it drew before (point-sampled texture, conftest point_sampled_texture).
SUB_SAMPLED_AT = {
    "unloaded-high-flat-look-2": 0.1,
    "unloaded-low-front-up-look-0-light-0.6": 0.1,
    "campaign-7-pick-19-exposure-0.6": 0.2,
}


@pytest.mark.parametrize("path", SCENE_FILES)
def test_randomised_scene_is_refused_or_within_bounds(path, point_sampled_texture, monkeypatch):
    """loaded-middle-rear-up-look-0: a second pair of load edges 0.57 deg off answered the search from 0.5 deg
    beside the pitch (now refused: the pitch does not settle); loaded-*-front-up: the load edges' pitch 0.2-0.6 deg
    off (now checked against the lines on the load's face); unloaded-high-front-up-look-2: shadows of two uprights
    across the deck taken for its edges, 4.2 deg off (now refused: they meet 2 deg across the pallet's axis)."""
    from drivers.sim import fast_render

    if path.stem in SUB_SAMPLED_AT:
        monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", SUB_SAMPLED_AT[path.stem])
    scene = load_scene(path)
    image = fast_render.render_fast(scene)[0]  # in colour, as agf bench reads it
    pallet = load_pallets(CONFIG.vision.pallets)[scene.pallet.type]
    try:
        detail = measure_pallet(
            image, load_camera(scene.camera), scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks
        )
    except MeasurementError:
        return
    errors = pose_errors(detail.measurement.pallet_in_fork, scene.pallet.in_fork)
    assert within_bounds(errors) and detail.measurement.loaded == scene.loaded, errors


def test_bench_campaign_case_measures_the_first_frames_of_campaign_picks():
    """``agf bench --quick --only campaign``: the first frames of picks 0-3 of campaign seed 7, each measured
    or refused with a reason, none accepted outside the bounds."""
    from agf.bench import run_bench

    figures = run_bench(["drivers.sim.vision_bench"], quick=True, only="campaign")["accuracy"]["campaign"]
    assert figures["scenes"] == 4
    assert figures["wrong_accepts"] == 0, figures["wrong"]
    assert figures["within_bounds"] + len(figures["refused"]) == 4
    assert all(reason.startswith("seed-7/pick-") for reason in figures["refused"])


def test_bench_takes_a_frame_refused_as_overexposed_again_with_the_controllers_shorter_exposures():
    """A random look of a paper scene whose top deck the drawn exposure clips (refused: "the top deck is
    overexposed"): ``agf bench`` takes the view again at the shorter exposures a pick's controller asks for, and
    counts the measurement within the bounds, but not among the first frames measured within them."""
    import dataclasses

    from drivers.sim.vision_bench import SCENES as BENCH_SCENES
    from drivers.sim.vision_bench import measure_scenes, rendered_fast

    base = load_scene(BENCH_SCENES / "paper/unloaded-low-flat.yaml")
    key = "paper/unloaded-low-flat/look-1"
    scene = dataclasses.replace(base, look="random", seed=base.seed * 100 + 2)  # as accuracy.randomised draws it
    figures = measure_scenes([(key, scene)], rendered_fast, shorter_exposures=True).summary()
    assert figures["after_shorter_exposure"] == [key], figures["refused"]
    assert figures["within_bounds"] == 1 and figures["first_frames_within_bounds"] == 0, figures
