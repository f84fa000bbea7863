"""Pallet pose and pitch on rendered scenes: the paper's 18 configurations and a robustness set.

Bounds (issues 5 and 9): x and z within 5 mm, yaw within 0.3 deg, pitch within 0.1 deg; a scene is
either measured within them or refused with a reason, never wrong and accepted.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import pytest

from agf.camera import load_camera
from agf.config import load_config
from agf.errors import MeasurementError, OverexposedError
from agf.geometry import Transform
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.scene import load_scene
from agf.vision import measure as measure_module
from agf.vision.measure import measure_pallet
from tests.integration.conftest import SCENES, campaign_first_frame, scene_files

pytestmark = pytest.mark.usefixtures("point_sampled_texture")  # the frames these tests were written on

CONFIG = load_config(DEFAULT_CONFIG)
CATALOGUE = load_pallets(CONFIG.vision.pallets)
PAPER = [f"paper/{p.stem}" for p in sorted((SCENES / "paper").glob("*.yaml"))]
ROBUST = [f"{p.parent.name}/{p.stem}" for p in scene_files() if p.parent.name == "robust"]


def measure(key: str, rendered, pallet_type: str | None = None):
    """Measure the rendered frame of scene ``key`` in colour, as ``agf bench`` and ``agf measure`` read it."""
    scene = load_scene(SCENES / f"{key}.yaml")
    image = cv2.imread(str(rendered[key]), cv2.IMREAD_COLOR)
    pallet = CATALOGUE[pallet_type or scene.pallet.type]
    detail = measure_pallet(image, load_camera(scene.camera), scene.camera_in_fork, pallet, CONFIG.vision.search,
                            forks=CONFIG.forks)
    return scene, detail.measurement


def measure_random_look(key: str, look: int | None = None):
    """Measure a random-look scene from the campaign renderer, in colour as ``agf bench`` reads it; with
    ``look``, random look ``look`` of scene ``key`` as ``agf bench`` and its look hunts draw it."""
    from drivers.sim.fast_render import render_fast

    scene = load_scene(SCENES / f"{key}.yaml")
    if look is not None:
        scene = dataclasses.replace(scene, look="random", seed=scene.seed * 100 + look + 1)
    image = render_fast(scene)[0]
    detail = measure_pallet(image, load_camera(scene.camera), scene.camera_in_fork, CATALOGUE[scene.pallet.type],
                            CONFIG.vision.search, forks=CONFIG.forks)
    return scene, detail.measurement


def errors(scene, measurement) -> dict[str, float]:
    est, gt = measurement.pallet_in_fork.to_dict(), scene.pallet.in_fork.to_dict()
    return {key: est[key] - gt[key] for key in ("x_mm", "y_mm", "z_mm", "pitch_deg", "yaw_deg")}


def within_bounds(e: dict[str, float]) -> bool:
    return (abs(e["x_mm"]) <= 5 and abs(e["z_mm"]) <= 5 and abs(e["y_mm"]) <= 5 and abs(e["yaw_deg"]) <= 0.3
            and abs(e["pitch_deg"]) <= 0.1)


@pytest.mark.parametrize("key", PAPER)
def test_paper_scene_is_measured_within_bounds(key, rendered):
    scene, measurement = measure(key, rendered)
    e = errors(scene, measurement)
    assert within_bounds(e), e
    assert measurement.loaded == scene.loaded


@pytest.mark.parametrize("key", ROBUST)
def test_robust_scene_is_within_bounds_or_refused(key, rendered):
    try:
        scene, measurement = measure(key, rendered)
    except MeasurementError as exc:
        assert str(exc)  # a refusal must say why
        return
    e = errors(scene, measurement)
    assert within_bounds(e), e
    assert measurement.loaded == scene.loaded


def test_regression_epal_second_line_giving_the_same_pitch_is_measured(rendered):
    """Regression: a second line beside an edge refused the EUR pallet's measurement although, parallel
    in 3D, it gave the same pitch; it now only keeps the edges from moving the pose."""
    scene, measurement = measure("robust/epal", rendered)
    e = errors(scene, measurement)
    assert within_bounds(e), e


def test_wrong_pallet_type_is_refused_not_measured(rendered):
    """An EUR pallet measured as a JIS one must not pass as a pose."""
    with pytest.raises(MeasurementError):
        measure("robust/epal", rendered, pallet_type="jis-t11")


def test_pose_with_prior_agrees_with_the_search(rendered):
    scene, searched = measure("paper/unloaded-middle-flat", rendered)
    image = cv2.imread(str(rendered["paper/unloaded-middle-flat"]), cv2.IMREAD_GRAYSCALE)
    prior = scene.pallet.in_fork.__class__.from_euler(
        *(scene.pallet.in_fork.translation + [0.2, -0.15, 0.1]), 0.0, 0.0, math.radians(6.0)
    )
    detail = measure_pallet(image, load_camera(scene.camera), scene.camera_in_fork, CATALOGUE["jis-t11"],
                            CONFIG.vision.search, forks=CONFIG.forks, prior=prior)
    assert within_bounds(errors(scene, detail.measurement))


def test_a_start_pose_replaces_the_search(rendered):
    """``start`` (tools/refusal_diagnosis: what a perfect search would leave refused): from the true pose the frame
    measures within the bounds; from a pose 250 mm aside, where the search from a prior that far off still finds the
    pallet, there is no search to find it, and the measurement is refused."""
    key = "paper/unloaded-middle-flat"
    scene = load_scene(SCENES / f"{key}.yaml")
    image = cv2.imread(str(rendered[key]), cv2.IMREAD_COLOR)
    truth = scene.pallet.in_fork
    aside = Transform(truth.rotation, truth.translation + [0.0, 0.25, 0.0])

    def measured(**known):
        return measure_pallet(image, load_camera(scene.camera), scene.camera_in_fork, CATALOGUE["jis-t11"],
                              CONFIG.vision.search, forks=CONFIG.forks, **known).measurement

    assert within_bounds(errors(scene, measured(start=truth)))
    assert within_bounds(errors(scene, measured(prior=aside)))
    with pytest.raises(MeasurementError):
        measured(start=aside)


def test_agf_measure_cli_prints_the_contract_and_writes_the_overlay(rendered, tmp_path, capsys):
    import json

    from agf.cli import main

    overlay = tmp_path / "overlay.png"
    code = main(["measure", str(rendered["paper/loaded-low-flat"]), "--json", "--overlay", str(overlay)])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and result["ok"] is True and result["loaded"] is True
    assert set(result["pallet_in_fork"]) == {"x_mm", "y_mm", "z_mm", "pitch_deg", "yaw_deg"}
    assert abs(result["pallet_in_fork"]["z_mm"] - 355) <= 5
    assert set(result["scores"]) == {"loaded", "unloaded"} and result["timing_ms"]["total"] > 0
    assert result["insertion"]["safe"] is True and result["insertion"]["margin_mm"] > 0
    assert cv2.imread(str(overlay)) is not None


def test_agf_measure_refuses_an_image_without_a_pallet(tmp_path, capsys):
    import json

    import numpy as np

    from agf.cli import main

    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((1920, 1920), 128, np.uint8))
    code = main(["measure", str(blank), "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 1 and result["ok"] is False and result["error"]


def test_bed_seam_beside_a_deck_edge_is_not_a_rival_once_the_corner_decides(rendered):
    """Regression: a plank seam of the truck bed beside a deck edge made every such pick a refusal."""
    scene, measurement = measure("robust/bed-seam-beside-deck", rendered)
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert not measurement.loaded


def test_loaded_neighbours_side_face_beside_the_load_edge_does_not_lean_it(rendered):
    """Regression: a loaded neighbour's side face just beside the load's right edge pulled the edge fit
    (1.5 px inliers) and the pitch was accepted 0.24 deg off."""
    scene, measurement = measure("robust/loaded-neighbour-side-face", rendered)
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert measurement.loaded


def test_faint_load_edge_counts_its_weak_maxima_towards_the_ratio(rendered):
    """Regression: a load edge before a grey wall scored 0.49 of its length with only the strong gradient
    maxima counted, below the ratio test's 0.5, and the pick was refused."""
    scene, measurement = measure("robust/load-edge-before-grey-wall", rendered)
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert measurement.loaded


def test_steeply_seen_pitched_pallet_is_searched_again_at_another_pitch(rendered):
    """Regression: searched at pitch 0 only, a pallet pitched 4.3 deg below the forks matched 83 mm off
    and the measurement was refused."""
    scene, measurement = measure("robust/pitched-down-below-the-forks", rendered)
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert measurement.loaded


def test_load_edges_are_followed_up_the_whole_load(rendered):
    """Regression: fitted over the lowest 0.4 m of a 0.92 m load only, the two load edges leaned 0.13 deg
    under sensor noise and the pitch was accepted that far off."""
    scene, measurement = measure("robust/tall-load-pitched-up", rendered)
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert measurement.loaded


@pytest.mark.parametrize("key", ["robust/unloaded-below-the-forks-turned", "robust/unloaded-below-the-forks-close"])
def test_steeply_seen_unloaded_pallet_is_pinned_by_its_deck_edges(key, rendered):
    """Regression: seen from 250-300 mm above, the face match was accepted 7 mm high and 0.75 deg off in
    yaw (random pick 30), or 21 mm far and 29 mm low (pick 195)."""
    scene, measurement = measure(key, rendered)
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert not measurement.loaded


def test_pose_pitch_two_cycle_is_split_at_its_midpoint(rendered):
    """Regression: on the colour frame the simulated world hands over (its grey conversion differs from
    imread's), the load edges' pitch swung 0.07 deg with the pose's pitch and never agreed (random pick 73),
    and the pick was refused. The split itself: tests/unit/test_measure_iteration.py."""
    scene, measurement = measure("robust/short-load-pose-pitch-cycle", rendered)
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert measurement.loaded


def test_load_edges_disagreeing_with_the_face_lines_are_searched_again_at_the_face_pitch():
    """Regression: searched around 3 deg, the load's edges gave 3.71 deg and the 24 lines on its face
    4.14 deg (truth 4.19); the measurement was refused. Searched again at the face's pitch, the edges agree
    with it (random look 1 of paper scene loaded-low-front-up, as ``agf bench`` reads it)."""
    scene, measurement = measure_random_look("fixed-wrong-accepts/loaded-low-front-up-look-1")
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert measurement.loaded


def test_many_tight_lines_on_the_load_face_give_the_pitch_where_the_load_edges_disagree():
    """Regression: the load's edges gave -1.55 deg, the 15 lines on its face -1.00 deg within 0.02 deg
    (truth -0.99), also when searched again at the face's pitch; the measurement was refused. Many tight
    lines now give the pitch alone (random look 0 of paper scene loaded-middle-rear-up, as ``agf bench`` reads it)."""
    scene, measurement = measure_random_look("fixed-wrong-accepts/loaded-middle-rear-up-look-0")
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert measurement.loaded


def test_regression_uprights_behind_an_unloaded_pallet_are_not_taken_for_a_load():
    """Rack uprights behind the back corners of an unloaded pallet pitched 2.4 deg were taken for a load's edges
    and accepted as its pitch, the world's vertical, 2.36 deg off; the top deck's side edges showed over 42 % of
    their length, which a load hides (campaign seed 7, pick 35, the forks 150 mm lower)."""
    with pytest.raises(MeasurementError, match="so were the top deck's side edges over"):
        measure_random_look("fixed-wrong-accepts/campaign-7-pick-35-forks-150-lower")


def test_deck_edges_on_other_lines_do_not_give_the_pitch_of_the_face_pose_kept_without_them():
    """The deck edges, found on other lines, put the pallet 18 mm from its face's match, which was 1 mm from
    the truth; the image confirms the face's pose (its edges agree) and not theirs (1%). Their pitch was right
    because one line, 10.5 px from the deck's corner, ran parallel to its edge; a shadow's edge running past the
    corner gave campaign seed 7 pick 386 a pitch 1.58 deg off the same way (check_deck_corners). The face's
    pose is kept only with deck edges through its corners (random look 8 of paper scene unloaded-low-rear-up,
    measured within the bounds until session 27)."""
    with pytest.raises(MeasurementError, match=r"pass 0\.\d and 1\d\.\d px from its front corners"):
        measure_random_look("paper/unloaded-low-rear-up", look=8)


@pytest.mark.parametrize("key", ["paper/unloaded-middle-flat", "paper/loaded-middle-flat", "paper/unloaded-high-flat"])
def test_regression_lit_pocket_entrances_do_not_push_the_face_away(key, rendered):
    """The pocket edges alone fitted these faces 2.7-2.9 mm too far: where the pocket's floor faces the
    camera its lit entrance shows, and the strongest step lies 1.15 px into the pocket. The face's two
    ends fix the scale; on the geometry-only shading the depth was right within 0.1 mm."""
    scene, measurement = measure(key, rendered)
    assert abs(errors(scene, measurement)["x_mm"]) <= 1.5, errors(scene, measurement)


@pytest.mark.parametrize(("pick", "confirmed"), [(60, True), (34, False)])
def test_a_refusal_carries_its_rough_pose_only_when_the_image_confirms_it(pick, confirmed):
    """The controller moves the forks level with a refusal's rough pose to look again. Campaign seed 7, first
    frames: pick 60's pose was within 2 mm and its face edges agreed 95 % (refused for its pitch); pick 34's
    was 223 mm off along the line of sight, agreeing 18 %, and a move by it is a move on a guess."""
    scene, image = campaign_first_frame(7, pick)
    pallet = CATALOGUE[scene.pallet.type]
    with pytest.raises(MeasurementError) as refused:
        measure_pallet(image, load_camera(CONFIG.vision.camera), scene.camera_in_fork, pallet, CONFIG.vision.search,
                       forks=CONFIG.forks)
    rough = refused.value.pallet_in_fork
    if not confirmed:
        assert rough is None
        return
    assert rough is not None
    assert math.dist(rough.translation, scene.pallet.in_fork.translation) < 0.01


def test_a_face_its_similarity_leaves_ambiguous_is_measured_where_its_edges_agree():
    """Campaign seed 7, pick 176 (unloaded, 1.7 deg): the face's similarity 0.60 led a rival elsewhere by 0.01 (a
    lead of 0.10 is asked for), and every search was refused so; its face edges agreed 82 %. The similarity measures
    brightness, the edges geometry: where they agree at least ``similarity_excused_by_edges`` the pose is taken on
    and checked as any other, and the frame measures within the bounds. With the similarity deciding alone it is
    refused as before."""
    scene, image = campaign_first_frame(7, 176)
    args = (image, load_camera(scene.camera), scene.camera_in_fork, CATALOGUE[scene.pallet.type], CONFIG.vision.search)
    detail = measure_pallet(*args, forks=CONFIG.forks)
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)
    alone = dataclasses.replace(measure_module.MeasureConfig(), similarity_excused_by_edges=None)
    with pytest.raises(MeasurementError, match="ambiguous pallet"):
        measure_pallet(*args, forks=CONFIG.forks, config=alone)


def test_regression_a_face_matched_with_a_deck_board_nearer_along_the_line_of_sight_is_measured_at_its_depth():
    """Seen steeply from above, the face plus the deck board behind it matched better (0.70) 190 mm nearer along
    the same line of sight than the face alone at its depth (0.62); the pitch searched there found no deck edges
    and the frame was refused (campaign seed 7, pick 39). The search now returns the other depths it fitted, and
    the face's edges decide: 70 % agreed at the true depth, 26 % at the nearer one."""
    from agf.vision.face_model import face_model_from_pallet
    from agf.vision.pallet_pose import estimate_pallet_pose

    scene, image = campaign_first_frame(7, 39)
    pallet, camera, truth = CATALOGUE[scene.pallet.type], load_camera(scene.camera), scene.pallet.in_fork.translation
    estimate = estimate_pallet_pose(image, camera, scene.camera_in_fork, face_model_from_pallet(pallet),
                                    CONFIG.vision.search, forks=CONFIG.forks, check=False)
    assert math.dist(estimate.pallet_in_fork.translation, truth) > 0.1  # the similarity alone is wrong here
    assert min(math.dist(d.pallet_in_fork.translation, truth) for d in estimate.depths) < 0.01
    detail = measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks)
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)


@pytest.mark.parametrize("pick", (13, 27))
def test_regression_a_rival_pairing_that_runs_across_the_pallets_axis_does_not_make_the_deck_edges_ambiguous(pick):
    """Campaign seed 7, first frames of picks 13 and 27 (unloaded, pitched -4.01 and 0.69 deg): a line beside one
    deck edge, paired with the other edge, gave a pitch 3.7 and 6.9 deg from the pair's, a direction 1.57 and 3.2 deg
    across the pallet's axis (the pair's: 0.01 and 0.04), and the pair was refused as ambiguous ("a second line runs
    beside the unloaded edges"). Two lines whose common direction leaves the pallet's axis that far are not its two
    edges (PitchConfig.max_across, which already refused such a pair), so that pairing offers no other pitch."""
    scene, image = campaign_first_frame(7, pick)
    pallet, camera = CATALOGUE[scene.pallet.type], load_camera(scene.camera)
    detail = measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks)
    assert not detail.measurement.loaded
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)


@pytest.mark.parametrize("pick", (3, 65, 258))
def test_regression_a_face_edge_without_a_step_does_not_refuse_the_pose_the_deck_edges_placed(pick):
    """Campaign seed 7, first frames of picks 3, 65 and 258 (unloaded, seen from 0.6-1.1 m above the deck): the face
    and the deck's edges were found within 2 mm and 0.06 deg, and the pose was refused as its face edges agreed
    38-47 % (need 50 %), one group at 0 %: a face top or bottom with no step beside it (the face top lit as the deck
    behind it, the face bottom as dark as the floor) counted against the pose. The deck's edges already placed it;
    since session 49 its face edges count where the image shows a step (MeasureConfig.placed_blank_disagrees), and
    no other place may explain them better, as before. Not in a verifying frame, which is confirmed at the plan's
    pitch instead where it is refused (campaign pick 268's verifying frame came through 0.115 deg off)."""
    from agf.vision.measure import MeasureConfig

    scene, image = campaign_first_frame(7, pick)
    pallet, camera = CATALOGUE[scene.pallet.type], load_camera(scene.camera)
    detail = measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks)
    assert not detail.measurement.loaded
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)
    blank_disagrees = MeasureConfig(placed_blank_disagrees=True)
    with pytest.raises(MeasurementError, match="its face edges agree"):
        measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks,
                       config=blank_disagrees)
    with pytest.raises(MeasurementError, match="its face edges agree"):
        measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks,
                       verifying=True)


@pytest.mark.parametrize("pick", (72, 117))
def test_regression_a_loads_edges_at_its_true_pose_give_its_pitch_in_campaign_frames(pick):
    """Campaign seed 7, first frames of picks 72 and 117 (loaded, pitched 2.54 and 4.25 deg): at the true pose the
    load's edges gave a pitch 0.47-0.70 and 1.43 deg off, its left edge's line leaning 6 and 8 px over the load's
    height, because the renderer drew a carton joint along that edge in every other row (tests/unit/
    test_textures.py); the frames were refused, the edges disagreeing with the load's face. Along the outline
    itself the edges give the pitch: within 0.025 deg, every pairing."""
    from agf.vision.grey import grey_from_bgr
    from agf.vision.measure import MeasureConfig
    from agf.vision.pitch import loaded_evidence

    scene, image = campaign_first_frame(7, pick)
    truth = scene.pallet.in_fork
    evidence = loaded_evidence(grey_from_bgr(image), load_camera(scene.camera), scene.camera_in_fork,
                               CATALOGUE[scene.pallet.type], truth, MeasureConfig().pitch, colour=image)
    off = [math.degrees(c - truth.euler[1]) for c in evidence.candidates]
    assert off and max(abs(o) for o in off) < 0.05, off


@pytest.mark.parametrize("pick", (4, 605))
def test_regression_a_load_face_whose_lines_fix_the_pitch_loosely_does_not_refuse_the_load_edges_it_agrees_with(pick):
    """Campaign seed 7, first frames of picks 4 and 605 (loaded, pitched 0.18 and -2.68 deg): the load's edges gave
    the pitch 0.01 and 0.003 deg off, the 8-11 lines on its face agreed within 0.06 deg but fixed it only to
    +-0.07-0.13 deg (at most 0.065), and the frame was refused for that ("the N lines on the load's face give its
    pitch only to ..."). Such a face cannot check the edges; since session 50 it counts as no face (pitch.py
    _without_vague_face), its miss widening the edges' sigma."""
    scene, image = campaign_first_frame(7, pick)
    pallet, camera = CATALOGUE[scene.pallet.type], load_camera(scene.camera)
    detail = measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks)
    assert detail.measurement.loaded
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)


def test_regression_a_load_face_whose_lines_fix_the_pitch_to_0_02_deg_gives_it_despite_a_second_load_edge():
    """Campaign seed 7, pick 173 (loaded, pitch -1.84 deg): a second line beside a load edge made the edges give two
    pitches, and 12 lines on the load's face, fewer than the 15 that counted alone, gave it to +-0.02 deg: refused.
    Lines that fix the pitch to PitchConfig.face_alone_tight now count alone, however many. Since session 48's
    renderer change (no carton joint along a load's side) the frame's load edges agree with its face by themselves,
    and it no longer needs that rule (which no other frame shows yet): it must stay measured within the bounds."""
    scene, image = campaign_first_frame(7, 173)
    pallet, camera = CATALOGUE[scene.pallet.type], load_camera(scene.camera)
    detail = measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks)
    assert detail.measurement.loaded
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)


def test_regression_deck_edges_found_from_one_side_only_settle_on_their_pitch():
    """Paper scene unloaded-middle-rear-up under random look 0: the deck edges gave -0.97 deg (truth -0.99), and
    searched again from 0.3 deg below they gave it again, from 0.3 deg above no pair at all: refused as "do not
    settle". Finding nothing from one side says nothing against the pitch; another pitch from either side does."""
    scene, measurement = measure_random_look("paper/unloaded-middle-rear-up", 0)
    assert not measurement.loaded
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)


def test_regression_a_pose_fitted_out_of_the_search_volume_is_refused(rendered):
    """Campaign seed 7, pick 35 seen from forks 150 mm lower: a face match at the volume's top was fitted on to
    z 577 mm, 77 mm above the volume, and accepted (2.4 deg off in pitch). Here the volume ends 2 mm below the
    pallet, which the fit finds all the same: the pose is refused, though it is right."""
    key = "paper/loaded-middle-flat"
    scene = load_scene(SCENES / f"{key}.yaml")
    image = cv2.imread(str(rendered[key]), cv2.IMREAD_COLOR)
    volume = dataclasses.replace(CONFIG.vision.search, z_max=scene.pallet.in_fork.translation[2] - 0.002)
    with pytest.raises(MeasurementError, match=r"measured at z [\d.]+ mm, outside the search volume"):
        measure_pallet(image, load_camera(scene.camera), scene.camera_in_fork, CATALOGUE[scene.pallet.type], volume,
                       forks=CONFIG.forks)


def test_regression_a_face_whose_deck_edges_disagree_with_it_by_32_mm_is_refused():
    """Campaign seed 7, pick 386 (unloaded, pitch 2.28 deg, truck bed, two neighbours) collided in a 1000-pick
    campaign with depth probes: a probe moved its first frame's face to a depth whose edges agreed better, and the
    deck edges measured there gave a pitch 1.58 deg low, stated to 0.03 deg. Rendered as here, that frame's front face
    and deck edges disagree by 32 mm and it is refused; any search that comes back must refuse it or measure it within
    bounds. The pick itself still collides without the probes: the world's first frame, rendered once the drives have
    settled, is accepted 1.58 deg off (test_clock_pick.py, OPEN_CAMPAIGN_WRONG_ACCEPTS)."""
    scene, image = campaign_first_frame(7, 386)
    pallet = CATALOGUE[scene.pallet.type]
    try:
        detail = measure_pallet(image, load_camera(scene.camera), scene.camera_in_fork, pallet, CONFIG.vision.search,
                                forks=CONFIG.forks)
    except MeasurementError as exc:
        assert str(exc)  # refused, with a reason: the safe side
        return
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)


def test_a_load_seen_from_above_is_measured_where_its_top_face_agrees_with_its_face_lines():
    """Campaign seed 7, pick 10 (loaded, camera 0.2 m above the load): a line beside a load edge gave the edges two
    pitches 0.17 and 0.27 deg off, and the face's lines alone were not sure enough: refused. The side edges of the
    load's top face (PitchConfig.top_*) agree with the face's lines, and the two together give the pitch. Since
    session 48's renderer change (no carton joint along a load's side) the frame is measured without its top face
    too (which no other frame shows yet): it must stay measured within the bounds."""
    scene, image = campaign_first_frame(7, 10)
    pallet, camera = CATALOGUE[scene.pallet.type], load_camera(scene.camera)
    detail = measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks)
    assert detail.measurement.loaded
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)


def test_regression_a_load_top_agreeing_with_a_rival_pairing_is_not_taken():
    """Campaign seed 7, pick 134: the load's top face gave -0.17 deg, its edges 0.00 and, paired with a line beside
    one of them, -0.13; offered every pairing, the top agreed with the rival's and the pallet was accepted 0.16 deg
    off. Only the edges' own pair and the face's lines may confirm the top."""
    scene, image = campaign_first_frame(7, 134)
    try:
        detail = measure_pallet(image, load_camera(scene.camera), scene.camera_in_fork, CATALOGUE[scene.pallet.type],
                                CONFIG.vision.search, forks=CONFIG.forks)
    except MeasurementError as exc:
        assert str(exc)
        return
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)


def test_a_load_top_seen_from_above_gives_the_pitch_at_the_true_pose():
    """Campaign seed 4242, pick 21 (a 0.85 m load, the camera 0.35 m above it): at the true pose the side edges of
    the load's top face, its height unknown and searched for, give the pitch within 0.05 deg."""
    from agf.vision.grey import grey_from_bgr
    from agf.vision.pitch import load_top_evidence

    scene, image = campaign_first_frame(4242, 21)
    top = load_top_evidence(grey_from_bgr(image), load_camera(scene.camera), scene.camera_in_fork,
                            CATALOGUE[scene.pallet.type], scene.pallet.in_fork, colour=image)
    assert top is not None and top.valid
    assert abs(math.degrees(top.pitch - scene.pallet.in_fork.euler[1])) < 0.05


def test_the_top_decks_front_edge_gives_the_yaw_from_a_pose_half_a_degree_off():
    """Campaign seed 7, pick 82 (unloaded, first frame): its deck edges turn the pallet 0.13 deg in yaw at the true
    pose; the top deck's front edge alone, searched from a pose turned 0.5 deg, gives the yaw within 0.02 deg."""
    from agf.geometry import Transform
    from agf.vision.grey import grey_from_bgr
    from agf.vision.pitch import deck_front_yaw

    scene, image = campaign_first_frame(7, 82)
    truth = scene.pallet.in_fork
    yaw, pitch, roll = truth.euler
    turned = Transform.from_euler(*truth.translation, roll, pitch, yaw + math.radians(0.5))
    found = deck_front_yaw(grey_from_bgr(image), load_camera(scene.camera), scene.camera_in_fork,
                           CATALOGUE[scene.pallet.type], turned, colour=image)
    assert found is not None and abs(math.degrees(found - yaw)) < 0.02


def test_a_pitch_kept_that_the_frames_deck_edges_contradict_is_not_confirmed():
    """check_kept_pitch (confirm_pallet, unloaded), on the first frame of campaign seed 7 pick 5, whose deck edges give
    the pitch within 0.01 deg at the true pose: a face confirmed at the true pitch passes, one at a pitch kept 0.3 deg
    off is refused. Until session 53 pick 674 tested it in a whole pick (its first measurement accepted 0.298 deg off,
    the verifying frame's face then not confirmed at that pitch); since deck edges turned from the front edge's yaw are
    refused, that pick no longer accepts its first measurement, and inserts within the bounds."""
    from agf.geometry import Transform
    from agf.vision.grey import grey_from_bgr
    from agf.vision.measure import check_kept_pitch

    scene, image = campaign_first_frame(7, 5)
    truth = scene.pallet.in_fork
    frame = (grey_from_bgr(image), image, load_camera(scene.camera), scene.camera_in_fork,
             CATALOGUE[scene.pallet.type])
    check_kept_pitch(*frame, truth)
    yaw, pitch, roll = truth.euler
    off = Transform.from_euler(*truth.translation, roll, pitch + math.radians(0.3), yaw)
    with pytest.raises(MeasurementError, match="none within 0.10 deg"):
        check_kept_pitch(*frame, off)


def test_regression_campaign_pick_28_of_seed_7_verifying_a_deck_line_inside_the_edge_is_not_taken_for_it():
    """One deck edge's strongest line ran 70 mm inside the edge; the deck edges' pose was 73 mm from the face's and
    the pick was refused at verifying. The line through the deck's front corner, as strong, is the edge."""
    scene, measurement = measure_random_look("campaign-frames/campaign-7-pick-28-verifying")
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert not measurement.loaded


def test_regression_campaign_pick_206_of_seed_7_load_edges_are_not_accepted_against_a_face_leaning_further():
    """A loaded pallet pitched 3.6 deg whose load edges were found on lines at 0.72 deg, the face's lines showing no
    direction within 1.5 deg of that: the edges alone were accepted 2.88 deg off. The face, scanned further, leads
    the search to its own pitch."""
    scene, measurement = measure_random_look("campaign-frames/campaign-7-pick-206-level-view")
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)
    assert measurement.loaded


def test_a_face_is_confirmed_where_a_plan_expects_it_at_the_measured_pitch_and_refused_where_there_is_none(rendered):
    """confirm_pallet, a verifying frame's last resort: near the true pose it finds the face within the bounds and
    keeps the pitch, hypothesis and pitch sigma it is given; at a pitch 0.3 deg off, its deck edges contradict it and
    it refuses; 150 mm to the side, where the fine fit reaches the face from, it refuses (a pallet moved since it was
    measured is measured again, not confirmed)."""
    from agf.geometry import Transform
    from agf.vision.measure import confirm_pallet

    key = "paper/unloaded-middle-flat"
    scene = load_scene(SCENES / f"{key}.yaml")
    image = cv2.imread(str(rendered[key]), cv2.IMREAD_COLOR)
    truth = scene.pallet.in_fork
    args = (image, load_camera(scene.camera), scene.camera_in_fork, CATALOGUE["jis-t11"], CONFIG.vision.search)
    near = Transform(truth.rotation, truth.translation + [0.015, -0.02, 0.01])
    confirmed = confirm_pallet(*args, near, loaded=True, sigma_pitch=0.0007, forks=CONFIG.forks).measurement
    assert within_bounds(errors(scene, confirmed))
    assert confirmed.pallet_in_fork.euler[1] == pytest.approx(truth.euler[1], abs=1e-9)
    assert confirmed.loaded and confirmed.sigma_pitch == 0.0007
    yaw, pitch, roll = truth.euler
    steeper = Transform.from_euler(*truth.translation, roll, pitch + math.radians(0.3), yaw)
    with pytest.raises(MeasurementError, match=r"unloaded edges of this frame give a pitch of .* none within 0\.10"):
        confirm_pallet(*args, steeper, loaded=False, sigma_pitch=0.0007, forks=CONFIG.forks)
    aside = Transform(truth.rotation, truth.translation + [0.0, 0.15, 0.0])
    with pytest.raises(MeasurementError, match="from where the plan expects it|no convincing pallet front face"):
        confirm_pallet(*args, aside, loaded=False, sigma_pitch=0.0007, forks=CONFIG.forks)


def test_regression_face_lines_leaning_together_against_the_load_top_are_refused():
    """Campaign seed 7, pick 23 (loaded, pitch 4.98 deg, camera above the load): at the true pose the 22 lines on the
    load's face agree to +-0.021 deg on a pitch 0.114 deg low, enough to count alone, while the side edges of the
    load's top face give it 0.068 deg high. Measured from a prior at the true pose, it was accepted 0.133 deg off. A
    settled loaded pitch must not disagree with a top face fitted to +-0.035 deg by more than 0.12 deg
    (measure.py _Frame.check_load_top)."""
    scene, image = campaign_first_frame(7, 23)
    pallet, camera = CATALOGUE[scene.pallet.type], load_camera(scene.camera)
    with pytest.raises(MeasurementError, match="its top face"):
        measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks,
                       prior=scene.pallet.in_fork)
    try:
        detail = measure_pallet(image, camera, scene.camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks)
    except MeasurementError as exc:
        assert str(exc)
        return
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)


def test_regression_a_face_match_turned_from_deck_edges_that_cannot_place_it_is_refused(monkeypatch):
    """Paper scene unloaded-high-flat under random look 2 (tests/data/scenes/fixed-wrong-accepts), as the campaign
    renderer drew it with texture steps sub-sampled at a contrast of 0.1 (session 60): its deck edges, a line beside
    them, gave the pitch and the yaw right but could not place the face, whose own match, 0.78 deg turned, was kept and
    accepted 8.4 mm high. Now that match is refused (measure.check_face_yaw) and a later search measures it."""
    from drivers.sim import fast_render

    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", 0.1)
    scene, measurement = measure_random_look("fixed-wrong-accepts/unloaded-high-flat-look-2")
    assert within_bounds(errors(scene, measurement)), errors(scene, measurement)


def test_regression_the_pitch_reported_is_the_one_the_edges_measured_not_the_one_searched_at(monkeypatch):
    """Paper scene unloaded-low-front-up under random look 0 at 0.6 of its light (tests/data/scenes/
    fixed-wrong-accepts), rendered as for the test above: its deck edges measured the pitch 0.093 deg off at a pose
    searched at 0.121 deg off, within the iteration's tolerance, and the pose was reported at the pitch searched.
    The pose is now turned to the pitch measured (measure._at_pitch)."""
    from drivers.sim import fast_render

    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", 0.1)
    scene = load_scene(SCENES / "fixed-wrong-accepts/unloaded-low-front-up-look-0-light-0.6.yaml")
    image = fast_render.render_fast(scene)[0]
    detail = measure_pallet(image, load_camera(scene.camera), scene.camera_in_fork, CATALOGUE[scene.pallet.type],
                            CONFIG.vision.search, forks=CONFIG.forks)
    chosen = detail.evidence["loaded" if detail.measurement.loaded else "unloaded"]
    assert detail.measurement.pallet_in_fork.euler[1] == pytest.approx(chosen.pitch, abs=1e-12)
    assert within_bounds(errors(scene, detail.measurement)), errors(scene, detail.measurement)


def test_regression_a_face_agreeing_with_two_of_an_ambiguous_pairs_pitches_does_not_pick_one():
    """Paper scene loaded-middle-front-up under random look 4 (tests/data/scenes/fixed-wrong-accepts): at the true
    pose its load's edges give 0.12 deg high, paired with lines beside them 0.11 and 0.07 deg low and 0.16 high; the
    10 lines on its face, 0.17 deg low to +-0.034 deg, agree with both low pairings. It took the nearer and was
    accepted 0.135 deg off (with session 54's Hough peaks). A face that does not fix the pitch alone cannot choose
    between two pitches it agrees with: refused."""
    from agf.vision.grey import grey_from_bgr
    from agf.vision.pitch import loaded_evidence
    from drivers.sim.fast_render import render_fast

    scene = load_scene(SCENES / "fixed-wrong-accepts/loaded-middle-front-up-look-4.yaml")
    image = render_fast(scene)[0]
    evidence = loaded_evidence(grey_from_bgr(image), load_camera(scene.camera), scene.camera_in_fork,
                               CATALOGUE[scene.pallet.type], scene.pallet.in_fork, colour=image)
    assert not evidence.valid and "agrees with more than one of the edges' pitches" in evidence.note, evidence.note


@pytest.mark.parametrize(("pick", "searches"), [(115, 1), (44, 3)])
def test_a_search_refused_for_clipped_highlights_ends_the_searches(pick, searches, monkeypatch):
    """Campaign seed 7, first frames: pick 115's deck is clipped beside its edges in the first search, pick 44's
    (loaded) in the third. The searches after it read the same clipped pixels (none of 62 such frames measured in
    one), so the refusal, an OverexposedError whose remedy is a shorter exposure, comes at once."""
    scene, image = campaign_first_frame(7, pick)
    pallet = CATALOGUE[scene.pallet.type]
    calls = []
    searched = measure_module._Attempt.measured

    def counted(attempt, assumed):
        calls.append(assumed)
        return searched(attempt, assumed)

    monkeypatch.setattr(measure_module._Attempt, "measured", counted)
    with pytest.raises(OverexposedError) as refused:
        measure_pallet(image, load_camera(CONFIG.vision.camera), scene.camera_in_fork, pallet, CONFIG.vision.search,
                       forks=CONFIG.forks)
    assert len(calls) == searches, refused.value


def _unloaded_evidence_at_truth(scene, image):
    from agf.vision.grey import grey_from_bgr
    from agf.vision.pitch import unloaded_evidence

    return unloaded_evidence(grey_from_bgr(image), load_camera(scene.camera), scene.camera_in_fork,
                             CATALOGUE[scene.pallet.type], scene.pallet.in_fork, colour=image)


def test_regression_a_line_beside_a_deck_edge_gives_the_pitch_between_its_pairings(monkeypatch):
    """Paper scene unloaded-high-flat under random look 1, as the campaign renderer draws it since session 60 (texture
    steps sub-sampled at 0.2): a line 2.6 px beside one deck edge. At the true pose the edges' own pair gives +0.024
    deg, the pair with that line -0.069; the deck edges were refused as ambiguous. One pairing is the deck's, so the
    pitch is their midpoint, with half their spread in its sigma, and the edges no longer place the pose."""
    from agf.vision.pitch import PitchConfig
    from drivers.sim import fast_render

    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", 0.2)
    scene = load_scene(SCENES / "paper/unloaded-high-flat.yaml")
    scene = dataclasses.replace(scene, look="random", seed=scene.seed * 100 + 1 + 1)
    evidence = _unloaded_evidence_at_truth(scene, fast_render.render_fast(scene)[0])
    low, high = min(evidence.candidates), max(evidence.candidates)
    assert high - low > PitchConfig().rival_pitch, evidence.candidates  # still two pitches, not one
    assert evidence.valid and not evidence.placed, evidence.note
    assert evidence.pitch == pytest.approx((low + high) / 2, abs=1e-12)
    assert evidence.sigma >= (high - low) / 2
    assert abs(math.degrees(evidence.pitch - scene.pallet.in_fork.euler[1])) < 0.05


def test_an_ambiguous_pair_whose_pairings_are_all_off_stays_refused_for_its_clipped_deck(monkeypatch):
    """Campaign seed 7 pick 22's first frame (texture sub-sampled at 0.2): a line beside a deck edge, and at the true
    pose both pairings 0.24 and 0.31 deg low, their midpoint as far off, beside a deck clipped at 255. The midpoint
    of an ambiguous pair still meets the checks of a pair (here the highlight beside the edges): refused."""
    from drivers.sim import fast_render

    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", 0.2)
    scene, image = campaign_first_frame(7, 22)
    evidence = _unloaded_evidence_at_truth(scene, image)
    assert len(evidence.candidates) > 1 and all(
        abs(math.degrees(c - scene.pallet.in_fork.euler[1])) > 0.2 for c in evidence.candidates), evidence.candidates
    assert not evidence.valid and evidence.overexposed, evidence.note


def test_deck_edges_whose_stronger_pairing_is_off_beside_one_on_the_pitch_stay_refused(monkeypatch):
    """Campaign seed 7 pick 140's first frame (texture sub-sampled at 0.2): at the true pose the deck edges' strongest
    lines give a pitch 0.16 deg off and a line beside one edge the pitch within 0.1 deg; over the search's poses the
    strong pairing gave 0.19-0.28 deg off. The frame is refused for the line beside the edge. A final edge fit that
    weighted points down with their distance from the line (Tukey, 0.6 px; session 62, not kept) lost that line
    and accepted the frame 0.243 deg off in pitch."""
    from drivers.sim import fast_render

    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", 0.2)
    scene, image = campaign_first_frame(7, 140)
    evidence = _unloaded_evidence_at_truth(scene, image)
    off = sorted(abs(math.degrees(c - scene.pallet.in_fork.euler[1])) for c in evidence.candidates)
    assert len(off) == 2 and off[0] < 0.1 < off[1], off  # the frame described: one pairing right, one off
    with pytest.raises(MeasurementError, match="a second line runs beside the unloaded edges"):
        measure_pallet(image, load_camera(scene.camera), scene.camera_in_fork, CATALOGUE[scene.pallet.type],
                       CONFIG.vision.search, forks=CONFIG.forks)


def test_regression_a_face_agreeing_with_an_ambiguous_pairs_close_pitches_gives_the_pitch(monkeypatch):
    """Paper scene loaded-low-rear-up under random look 5, texture sub-sampled at 0.2: at the true pose the load's
    edges give +0.018 deg, paired with a line beside one -0.026; the 6 lines on its face, -0.032 deg, agree with both
    and were refused for it ("agrees with more than one of the edges' pitches"). Pairings 0.044 deg apart are one
    pitch to within the bounds (_between_rivals), and the face confirms it."""
    from agf.vision.grey import grey_from_bgr
    from agf.vision.pitch import loaded_evidence
    from drivers.sim import fast_render

    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", 0.2)
    scene = load_scene(SCENES / "paper/loaded-low-rear-up.yaml")
    scene = dataclasses.replace(scene, look="random", seed=scene.seed * 100 + 5 + 1)
    image = fast_render.render_fast(scene)[0]
    evidence = loaded_evidence(grey_from_bgr(image), load_camera(scene.camera), scene.camera_in_fork,
                               CATALOGUE[scene.pallet.type], scene.pallet.in_fork, colour=image)
    assert len(evidence.candidates) > 1, evidence.candidates
    assert evidence.valid, evidence.note
    assert abs(math.degrees(evidence.pitch - scene.pallet.in_fork.euler[1])) < 0.05
