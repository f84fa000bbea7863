"""drivers.sim.looks.simplified: a random look with parts taken out, the rest as drawn."""

from __future__ import annotations

import dataclasses

import pytest

from agf.paths import repo_path
from agf.scene import load_scene
from drivers.sim.looks import PARTS, draw_look, simplified

SCENE = load_scene(repo_path("tests/data/scenes/paper/loaded-low-flat.yaml"))


@pytest.fixture(params=range(3))
def look(request):
    return draw_look(dataclasses.replace(SCENE, look="random", seed=request.param))


def test_without_wood_only_the_wood_turns_plain(look):
    plain = simplified(look, ["wood"])
    assert plain.styles["wood"].kind == "plain" and plain.styles["wood"].wear == 0.0
    assert plain.styles["wood"].colour == look.styles["wood"].colour
    assert {k: v for k, v in plain.styles.items() if k != "wood"} == {
        k: v for k, v in look.styles.items() if k != "wood"}
    assert dataclasses.replace(plain, styles=look.styles) == look


def test_without_textures_every_surface_is_plain_of_its_colour(look):
    plain = simplified(look, ["textures"])
    assert all(s.kind == "plain" and s.wear == 0.0 and s.detail == 0.0 for s in plain.styles.values())
    assert {k: s.colour for k, s in plain.styles.items()} == {k: s.colour for k, s in look.styles.items()}


def test_without_shadows_the_lights_stay_and_cast_none(look):
    dark = simplified(look, ["shadows"])
    assert len(dark.lights) == len(look.lights) and not any(light.shadows for light in dark.lights)
    pairs = zip(dark.lights, look.lights, strict=True)
    assert [dataclasses.replace(a, shadows=b.shadows) for a, b in pairs] == list(look.lights)


def test_without_sensor_and_optics_the_exposure_stays(look):
    ideal = simplified(look, ["sensor", "optics"])
    assert (ideal.sigma, ideal.jpeg_quality, ideal.blur_px, ideal.motion_px) == (0.0, None, 0.0, 0.0)
    assert (ideal.vignetting, ideal.gamma) == (0.0, 1.0)
    assert (ideal.exposure, ideal.white_balance, ideal.ambient) == (look.exposure, look.white_balance, look.ambient)


def test_nothing_taken_out_is_the_look_itself(look):
    assert simplified(look, []) == look


def test_an_unknown_part_is_refused_by_name(look):
    with pytest.raises(ValueError, match=r"\['shadow'\].*expected some of"):
        simplified(look, ["shadow", *PARTS])
