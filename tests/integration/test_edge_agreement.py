"""The face-edge agreement check (agf/vision/edge_agreement.py): a right pose is confirmed, a pose one
deck board off is refused, and the wrong accept it was built against stays refused."""

from __future__ import annotations

import dataclasses
import json
import math

import cv2
import numpy as np
import pytest
import yaml

from agf.camera import load_camera
from agf.config import load_config
from agf.errors import MeasurementError
from agf.geometry import Transform, transform_from_dict
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.scene import load_scene
from agf.vision.edge_agreement import EdgeAgreementConfig, check_face_edges, face_edge_agreement, line_of_sight
from agf.vision.face_model import face_model_from_pallet
from agf.vision.grey import grey_from_bgr
from agf.vision.measure import measure_pallet
from tests.integration.conftest import SCENES, SHARED_DATA, campaign_first_frame

CONFIG = load_config(DEFAULT_CONFIG)
CATALOGUE = load_pallets(CONFIG.vision.pallets)
FOREIGN = SHARED_DATA / "foreign-renders"


def _scene(key: str, rendered):
    scene = load_scene(SCENES / f"{key}.yaml")
    image = cv2.imread(str(rendered[key]), cv2.IMREAD_GRAYSCALE)
    face = face_model_from_pallet(CATALOGUE[scene.pallet.type])
    return scene, image, load_camera(scene.camera), face


def _moved(T: Transform, dy: float, dz: float) -> Transform:
    return Transform(T.rotation, T.apply(np.array([0.0, dy, dz])))


def test_true_pose_is_confirmed_and_agrees_better_than_moved_ones(rendered):
    scene, image, camera, face = _scene("paper/loaded-middle-flat", rendered)
    truth = scene.pallet.in_fork
    own = check_face_edges(image, camera, scene.camera_in_fork, truth, face, CONFIG.forks)
    assert own.score > 0.8
    moved = face_edge_agreement(
        image, camera, scene.camera_in_fork, [_moved(truth, 0.0, 0.022), _moved(truth, 0.03, 0.0)], face, CONFIG.forks
    )
    assert all(m.score < own.score - 0.1 for m in moved), [m.score for m in moved]


MEASURING = EdgeAgreementConfig()
CONFIRMING = dataclasses.replace(MEASURING, blank_disagrees=False)  # as confirm_pallet checks


@pytest.mark.parametrize("config", [MEASURING, CONFIRMING], ids=["measuring", "confirming"])
@pytest.mark.parametrize("dz", [0.022, -0.022, 0.045])
def test_pose_a_deck_board_off_is_refused(rendered, dz, config):
    scene, image, camera, face = _scene("paper/unloaded-middle-flat", rendered)
    with pytest.raises(MeasurementError, match="does not confirm the measured pose"):
        check_face_edges(image, camera, scene.camera_in_fork, _moved(scene.pallet.in_fork, 0.0, dz), face, CONFIG.forks,
                         config)


def _along_sight(T: Transform, camera_in_fork: Transform, face, distance: float) -> Transform:
    return Transform(T.rotation, T.translation + distance * line_of_sight(T, camera_in_fork, face))


@pytest.mark.parametrize("distance", [0.025, -0.025])
def test_pose_off_along_the_line_of_sight_is_refused(rendered, distance):
    scene, image, camera, face = _scene("paper/unloaded-middle-flat", rendered)
    moved = _along_sight(scene.pallet.in_fork, scene.camera_in_fork, face, distance)
    with pytest.raises(MeasurementError, match="does not confirm the measured pose"):
        check_face_edges(image, camera, scene.camera_in_fork, moved, face, CONFIG.forks)


@pytest.mark.skipif(not FOREIGN.is_dir(), reason="../shared/data/foreign-renders is not beside this checkout")
def test_regression_foreign_unloaded_flat_face_too_far_along_the_line_of_sight_is_refused():
    """Searched from the pyramid's level 2, the face was fitted 24 mm too far along the line of sight (x +18,
    z -16 mm), the deck edges' pose with that x was refused, and the face's own pose was confirmed by its
    edges at 50-60 % and accepted (foreign render unloaded-flat): the face 20 mm nearer agreed at 93 %."""
    scene = yaml.safe_load((FOREIGN / "scenes/unloaded-flat.yaml").read_text())
    truth = transform_from_dict(json.loads((FOREIGN / "images/unloaded-flat.truth.json").read_text())["pallet_in_fork"])
    image = cv2.imread(str(FOREIGN / "images/unloaded-flat.png"), cv2.IMREAD_GRAYSCALE)
    camera = load_camera(FOREIGN / scene["camera"])
    camera_in_fork = transform_from_dict(scene["camera_in_fork"], where="camera_in_fork")
    face = face_model_from_pallet(CATALOGUE[scene["pallet"]["type"]])
    check_face_edges(image, camera, camera_in_fork, truth, face, CONFIG.forks)
    too_far = _along_sight(truth, camera_in_fork, face, 0.024)
    with pytest.raises(MeasurementError, match="nearer to the camera explains its edges better"):
        check_face_edges(image, camera, camera_in_fork, too_far, face, CONFIG.forks)


def test_regression_campaign_loaded_pallet_45_mm_along_the_line_of_sight_is_refused():
    """Seen steeply from 1.2 m above, a loaded pallet's face was fitted 45 mm too far along the line of sight
    (x +29, z -35 mm) and accepted: its pocket tops and bottoms lay on lines, only its upright edges did not
    (first frame of pick 29 of campaign seed 7; the whole measurement is checked by its scene file in
    tests/data/scenes/fixed-wrong-accepts)."""
    scene, frame = campaign_first_frame(7, 29)
    image = grey_from_bgr(frame)  # the grey the measurement works on
    camera = load_camera(CONFIG.vision.camera)
    face = face_model_from_pallet(CATALOGUE[scene.pallet.type])
    check_face_edges(image, camera, scene.camera_in_fork, scene.pallet.in_fork, face, CONFIG.forks)
    accepted = Transform.from_euler(0.2157, -0.0013, -0.2021, 0.0, math.radians(3.33), math.radians(0.30))
    with pytest.raises(MeasurementError, match="upright edges"):
        check_face_edges(image, camera, scene.camera_in_fork, accepted, face, CONFIG.forks)


def test_regression_campaign_blue_pallet_in_dim_light_is_confirmed_in_colour():
    """A blue pallet in dim light shows its pockets in blue (78 to 4) and hardly in grey (18 to 2): its true pose
    agreed 21 % in grey and the first frame was refused (campaign seed 7, pick 94). In colour each channel counts
    against its own noise."""
    scene, frame = campaign_first_frame(7, 94)
    camera = load_camera(CONFIG.vision.camera)
    face = face_model_from_pallet(CATALOGUE[scene.pallet.type])
    truth = scene.pallet.in_fork
    colour = check_face_edges(frame, camera, scene.camera_in_fork, truth, face, CONFIG.forks)
    [grey] = face_edge_agreement(grey_from_bgr(frame), camera, scene.camera_in_fork, [truth], face, CONFIG.forks)
    assert colour.score >= 0.5 > grey.score


def test_regression_random_look_pose_turned_in_yaw_is_refused():
    """A pose 8 mm high and 0.74 deg off in yaw has no rival among the face's shifts: with its edges read in
    colour it agreed 55 % and was accepted (random look 2 of paper scene unloaded-high-flat). The face turned
    back by half a degree agrees better; the true pose is confirmed."""
    from drivers.sim.fast_render import render_fast

    base = load_scene(SCENES / "paper/unloaded-high-flat.yaml")
    scene = dataclasses.replace(base, look="random", seed=base.seed * 100 + 2 + 1)
    frame = render_fast(scene)[0]
    camera = load_camera(scene.camera)
    face = face_model_from_pallet(CATALOGUE[scene.pallet.type])
    check_face_edges(frame, camera, scene.camera_in_fork, scene.pallet.in_fork, face, CONFIG.forks)
    accepted = Transform.from_euler(0.21434, 0.00182, -0.25555, 0.0, math.radians(1.692), math.radians(-0.742))
    with pytest.raises(MeasurementError, match=r"turned \+0\.5 deg in yaw about its centre explains its edges"):
        check_face_edges(frame, camera, scene.camera_in_fork, accepted, face, CONFIG.forks)


@pytest.mark.parametrize("config", [MEASURING, CONFIRMING], ids=["measuring", "confirming"])
def test_pose_on_a_blank_image_is_refused(rendered, config):
    """Confirming too, where an edge the image leaves blank does not count against the pose: nothing shown is no
    face."""
    scene, image, camera, face = _scene("paper/unloaded-middle-flat", rendered)
    blank = np.full_like(image, 128)
    with pytest.raises(MeasurementError, match="face edges agree 0%"):
        check_face_edges(blank, camera, scene.camera_in_fork, scene.pallet.in_fork, face, CONFIG.forks, config)


@pytest.mark.skipif(not FOREIGN.is_dir(), reason="../shared/data/foreign-renders is not beside this checkout")
def test_regression_foreign_loaded_front_up_one_board_high_is_refused():
    """An independent renderer's pockets show their lit floor: the pose fit settled 23 mm high (one deck
    board) with every other check passing, and was accepted (foreign render loaded-front-up)."""
    scene = yaml.safe_load((FOREIGN / "scenes/loaded-front-up.yaml").read_text())
    truth = json.loads((FOREIGN / "images/loaded-front-up.truth.json").read_text())["pallet_in_fork"]
    image = cv2.imread(str(FOREIGN / "images/loaded-front-up.png"), cv2.IMREAD_GRAYSCALE)
    camera = load_camera(FOREIGN / scene["camera"])
    camera_in_fork = transform_from_dict(scene["camera_in_fork"], where="camera_in_fork")
    pallet = CATALOGUE[scene["pallet"]["type"]]
    try:
        detail = measure_pallet(image, camera, camera_in_fork, pallet, CONFIG.vision.search, forks=CONFIG.forks)
    except MeasurementError:
        return
    got = detail.measurement.pallet_in_fork.to_dict()
    assert abs(got["z_mm"] - truth["z_mm"]) <= 5 and abs(got["x_mm"] - truth["x_mm"]) <= 10
    assert abs(got["pitch_deg"] - truth["pitch_deg"]) <= 0.1
    assert math.isfinite(detail.measurement.scores["edges"])


def _measure_json(capsys, *argv):
    from agf.cli import main

    code = main(["measure", *argv, "--json"])
    return code, json.loads(capsys.readouterr().out.strip())


def test_refused_measurement_still_writes_its_overlay(tmp_path, capsys):
    """A refusal is when a commissioning engineer needs the picture: a frame with no pallet in it."""
    camera = load_camera(CONFIG.vision.camera)
    image = tmp_path / "empty.png"
    cv2.imwrite(str(image), np.full((camera.height, camera.width), 90, np.uint8))
    overlay = tmp_path / "refused.png"
    code, payload = _measure_json(capsys, str(image), "--overlay", str(overlay))
    assert code == 1 and payload["ok"] is False and payload["error"]
    picture = cv2.imread(str(overlay))
    assert picture is not None and picture.shape[0] > 720  # the frame, and the reason's band below it
    assert payload["overlay"] == str(overlay)


@pytest.mark.skipif(not FOREIGN.is_dir(), reason="../shared/data/foreign-renders is not beside this checkout")
def test_refusal_overlay_draws_the_candidate_it_refused(tmp_path, capsys):
    scene = yaml.safe_load((FOREIGN / "scenes/unloaded-flat.yaml").read_text())
    calibration = tmp_path / "calibration.yaml"
    calibration.write_text(yaml.safe_dump({"camera_in_fork": scene["camera_in_fork"]}))
    overlay = tmp_path / "refused.png"
    code, payload = _measure_json(
        capsys, str(FOREIGN / "images/unloaded-flat.png"), "--camera", str(FOREIGN / scene["camera"]),
        "--calibration", str(calibration), "--pallet-type", scene["pallet"]["type"], "--overlay", str(overlay),
    )
    picture = cv2.imread(str(overlay))
    assert picture is not None
    if payload["ok"]:
        return  # measured: the ordinary overlay was written, nothing refused to draw
    red = (picture[..., 2] > 200) & (picture[..., 1] < 80) & (picture[..., 0] < 80)
    assert red.sum() > 200, "the refused candidate's face is drawn in red"
