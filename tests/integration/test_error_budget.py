"""tools/error_budget: campaign first frames measured in their random look and with parts of it taken out."""

from __future__ import annotations

import numpy as np
import pytest

from agf.camera import load_camera
from agf.paths import repo_path
from agf.scene import load_scene
from drivers.sim.fast_render import render_fast
from drivers.sim.looks import draw_look, simplified
from drivers.sim.vision_bench import rendered_fast
from drivers.sim.world import campaign_scene
from tests.integration.conftest import tool_module

SEED, PICK = 7, 0  # unloaded, measured within the bounds in its full look after a shorter exposure (agf bench)


@pytest.fixture(scope="module")
def tool():
    return tool_module("error_budget")


@pytest.fixture(scope="module")
def scene():
    return campaign_scene(load_scene(repo_path("configs/scenes/pick.yaml")), SEED, PICK)


def test_a_look_given_to_the_renderer_draws_what_the_scene_would(scene):
    """The scene's own look passed in gives the campaign's frame bit for bit; the look without its shadows does
    not (so a budget's looks are the campaign's frames, changed only where a part was taken out)."""
    camera = load_camera(scene.camera)
    drawn = draw_look(scene)
    campaign = rendered_fast(scene, f"seed-{SEED}/pick-{PICK}")
    assert np.array_equal(render_fast(scene, camera, look=drawn)[0], campaign)
    without = render_fast(scene, camera, look=simplified(drawn, ["shadows"]))[0]
    relit = np.abs(without.astype(int) - campaign).max(axis=2) > 8  # pixels a shadow darkened
    assert without.shape == campaign.shape and relit.mean() > 0.002


def test_each_look_of_a_pick_is_measured_and_summarised(tool):
    records = tool.measure_pick(SEED, PICK, [(), ("sensor",)])
    assert [r["look"] for r in records] == ["full look", "without sensor"]
    full = records[0]
    assert full["measured"] and full["within"] and not full["loaded"], full
    assert abs(full["errors"]["pitch_deg"]) <= 0.1
    rows = {r["look"]: r for r in tool.summary(records) if r["hypothesis"] == "unloaded"}
    assert rows["full look"]["frames"] == 1 and rows["full look"]["measured"] == 1
    assert rows["full look"]["pitch_rms_paired_deg"] == pytest.approx(abs(full["errors"]["pitch_deg"]))


def test_a_looks_error_is_compared_with_the_full_looks_on_the_frames_both_measured(tool):
    def record(pick, look, pitch):
        measured = pitch is not None
        return {"pick": pick, "look": look, "loaded": False, "measured": measured, "within": measured,
                "errors": {"pitch_deg": pitch} if measured else None}

    records = [record(0, "full look", 0.03), record(0, "without wood", 0.01),
               record(1, "full look", 0.09), record(1, "without wood", None),
               record(2, "full look", None), record(2, "without wood", 0.05)]
    rows = {r["look"]: r for r in tool.summary(records) if r["hypothesis"] == "unloaded"}
    plain = rows["without wood"]
    assert plain["paired"] == 1 and plain["measured"] == 2
    assert plain["pitch_rms_paired_deg"] == pytest.approx(0.01)
    assert plain["full_look_pitch_rms_paired_deg"] == pytest.approx(0.03)
    full = rows["full look"]
    assert full["paired"] == 2 and full["pitch_rms_paired_deg"] == pytest.approx((0.03**2 / 2 + 0.09**2 / 2) ** 0.5)
    assert full["pitch_p95_deg"] > 0.08
    assert all(r["frames"] == 0 for r in tool.summary(records) if r["hypothesis"] == "loaded")


def test_bad_arguments_are_refused_with_the_reason(tool, capsys):
    for argv in (["--without", "shadow"], ["--picks", "9:3"], ["--picks", "x"], ["--jobs", "0"]):
        with pytest.raises(SystemExit) as exit_info:
            tool.main(argv)
        assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "'shadow': expected look parts" in err and "'9:3'" in err and "--jobs 0" in err


# First frames of campaign seed 7 that the vision accepts outside the bounds in a look with parts taken out (session
# 62, `tools/error_budget --picks 0:100`; texture steps sub-sampled at 0.2), none of them in the full look: pick,
# parts, pitch error (deg). Plain cartons leave a load's pitch to its edges alone, which a steep view (pick 54, 263 mm
# below the forks) magnifies; the unloaded ones have a deck whose shadow no longer hides a line beside its edge.
OPEN_SIMPLIFIED_LOOK_WRONG_ACCEPTS = (
    (12, "textures", -0.110),
    (40, "textures", -0.121),
    (54, "textures", -0.171),
    (65, "shadows", 0.200),
    (69, "shadows", 0.130),
    (82, "optics", -0.114),
)


@pytest.mark.xfail(strict=True, raises=AssertionError,
                   reason="open wrong accepts on simplified looks (session 62): the vision accepts them "
                          "outside the bounds")
@pytest.mark.parametrize(("pick", "parts", "pitch_error"), OPEN_SIMPLIFIED_LOOK_WRONG_ACCEPTS)
def test_open_wrong_accepts_on_a_simplified_look(tool, monkeypatch, pick, parts, pitch_error):
    """Measured as tools/error_budget measures it, the frame is refused or within the bounds (it is not yet)."""
    from drivers.sim import fast_render

    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", 0.2)
    [record] = tool.measure_pick(SEED, pick, [tuple(parts.split("+"))])
    assert not record["measured"] or record["within"], (pitch_error, record["errors"])
