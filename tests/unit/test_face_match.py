"""The pose scan's two face similarities, computed at every offset from integral images: the paper's
correlation equals OpenCV's ``TM_CCOEFF_NORMED`` with the face raster, and the region match equals the
ANOVA R^2 of the face's regions computed pixel by pixel; the region match does not care whether the
pockets are darker or lighter than the wood, the correlation does."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from agf.camera import CameraModel, load_camera
from agf.config import load_config
from agf.errors import FaceSimilarityError, MeasurementError
from agf.geometry import Transform
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.vision.face_model import FaceModel, face_model_from_pallet
from agf.vision.pallet_pose import (
    PoseEstimate,
    PoseSearchConfig,
    _Correlation,
    _RegionMatch,
    _templates,
    check_pose_estimate,
    region_match,
)

PIXEL = 0.01  # m per pixel of the synthetic views


@pytest.fixture(scope="module")
def face() -> FaceModel:
    config = load_config(DEFAULT_CONFIG)
    return face_model_from_pallet(load_pallets(config.vision.pallets)["jis-t11"])


def regions_image(face: FaceModel, bands: int) -> np.ndarray:
    """The face's region raster at :data:`PIXEL`, as :func:`_templates` lays out its cells."""
    regions, _, _ = face.region_raster(PIXEL, bands)
    return regions


def scores_at_every_offset(matcher, face: FaceModel, view: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    template = _templates(face, matcher.edges, np.array([PIXEL]))[0]
    shape = (view.shape[0] - template.height + 1, view.shape[1] - template.width + 1)
    integrals = cv2.integral2(view, sdepth=cv2.CV_64F, sqdepth=cv2.CV_64F)
    return score_one(matcher, integrals, template, shape), np.array([template.height, template.width])


def score_one(matcher, integrals, template, shape: tuple[int, int]) -> np.ndarray:
    """One template's scores at the first ``shape`` offsets of the view the ``integrals`` are of."""
    out = np.empty((1, *shape), np.float32)
    matcher.scores(integrals, [template], np.array([[0, 0, *shape]]), out)
    return out[0]


def r2_by_pixels(window: np.ndarray, regions: np.ndarray) -> float:
    values, labels = window.ravel().astype(np.float64), regions.ravel()
    total = np.sum((values - values.mean()) ** 2)
    means = np.bincount(labels, values) / np.bincount(labels)
    return float(np.sum((means[labels] - values.mean()) ** 2) / total)


@pytest.mark.parametrize("seed", range(3))
def test_correlation_equals_opencv_match_template(face, seed):
    rng = np.random.default_rng(seed)
    view = cv2.GaussianBlur(rng.uniform(0, 255, (40, 150)).astype(np.float32), (0, 0), 2.0)
    raster = (regions_image(face, 1) == 0).astype(np.float32)
    score, size = scores_at_every_offset(_Correlation.of(face), face, view)
    assert tuple(size) == raster.shape
    expected = cv2.matchTemplate(view, raster, cv2.TM_CCOEFF_NORMED)
    np.testing.assert_allclose(score, expected, atol=2e-4)


@pytest.mark.parametrize("seed", range(3))
def test_region_match_equals_r2_pixel_by_pixel(face, seed):
    rng = np.random.default_rng(seed)
    view = cv2.GaussianBlur(rng.uniform(0, 255, (36, 140)).astype(np.float32), (0, 0), 2.0)
    regions = regions_image(face, 3)
    score, (h, w) = scores_at_every_offset(_RegionMatch.of(face, 3), face, view)
    assert (h, w) == regions.shape
    for r, c in rng.integers(0, score.shape, (25, 2)).tolist():
        assert score[r, c] == pytest.approx(r2_by_pixels(view[r : r + h, c : c + w], regions), abs=1e-4)


@pytest.mark.parametrize("pockets", ["dark", "lit"])
def test_region_match_does_not_ask_which_is_brighter(face, pockets):
    """Regression (foreign renders): pockets seen from above show the lit bottom deck and a shadowed
    ceiling; the correlation with dark pockets scored the true pose near 0 and matched elsewhere."""
    regions = regions_image(face, 3)
    wood, pocket = (180.0, 40.0) if pockets == "dark" else (120.0, 220.0)
    view = np.full((regions.shape[0] + 20, regions.shape[1] + 20), 90.0, np.float32)
    view[10:-10, 10:-10] = np.where(regions == 0, wood, pocket)
    view += np.random.default_rng(1).normal(0, 3, view.shape).astype(np.float32)
    regions_score, _ = scores_at_every_offset(_RegionMatch.of(face, 3), face, view)
    correlation, _ = scores_at_every_offset(_Correlation.of(face), face, view)
    assert np.unravel_index(np.argmax(regions_score), regions_score.shape) == (10, 10)
    assert regions_score[10, 10] > 0.95
    assert correlation[10, 10] > 0.95 if pockets == "dark" else correlation[10, 10] < -0.95


@pytest.mark.parametrize("matcher", ["correlation", "regions"])
def test_scales_scored_in_one_call_equal_each_scored_alone(face, matcher):
    """The scan scores every scale of a yaw in one compiled call, each from its own first offset: each must
    equal that template scored alone from offset 0 of the view cut at that offset."""
    scorer = _Correlation.of(face) if matcher == "correlation" else _RegionMatch.of(face, 3)
    rng = np.random.default_rng(4)
    view = cv2.GaussianBlur(rng.uniform(0, 255, (60, 180)).astype(np.float32), (0, 0), 1.5)
    integrals = cv2.integral2(view, sdepth=cv2.CV_64F, sqdepth=cv2.CV_64F)
    templates = _templates(face, scorer.edges, np.array([PIXEL, 1.3 * PIXEL, 1.7 * PIXEL]))
    spans = np.array([[3, 7, 9, 20], [0, 0, 12, 31], [11, 2, 5, 8]])
    out = np.full((3, 14, 31), -2.0, np.float32)
    scorer.scores(integrals, templates, spans, out)
    for n, (top, left, rows, cols) in enumerate(spans.tolist()):
        alone = score_one(scorer, [image[top:, left:] for image in integrals], templates[n], (rows, cols))
        np.testing.assert_array_equal(out[n, :rows, :cols], alone)
        assert np.all(out[n, rows:] == -2.0) and np.all(out[n, :, cols:] == -2.0)  # nothing beyond its span


def test_region_match_of_a_flat_window_is_zero():
    sums, areas = np.array([[10.0], [30.0]]), np.array([1.0, 3.0])  # every pixel 10
    assert region_match(sums, areas, np.array([40.0]), np.array([400.0]))[0] == 0.0


def test_pocket_bands_must_be_positive():
    with pytest.raises(ValueError, match="pocket_bands"):
        PoseSearchConfig(pocket_bands=0)
    with pytest.raises(ValueError, match="similarity"):
        PoseSearchConfig(similarity="edges")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("change", "match"),
    [({"similarity": "chamfer"}, "similarity"), ({"pocket_bands": 0}, "pocket_bands"), ({"depths": -1}, "depths"),
     ({"min_face_px": 0.0}, "min_face_px"), ({"slab_step": -0.05}, "slab_step"), ({"fine_level": 4}, "fine_level")],
)
def test_a_pose_search_config_out_of_its_range_is_refused(change, match):
    with pytest.raises(ValueError, match=match):
        PoseSearchConfig(**change)


def _camera() -> CameraModel:
    return load_camera(load_config(DEFAULT_CONFIG).vision.camera)


def _estimate(score: float, margin: float) -> PoseEstimate:
    """A pose 0.3 m ahead of the tips and 0.2 m below the forks, in view and fitted well, with this similarity."""
    camera_in_fork = Transform.from_euler(-0.705, 0.0, 1.055, 0.0, 0.0, 0.0)
    pallet_in_fork = Transform.from_euler(0.3, 0.0, -0.2, 0.0, 0.0, 0.0)
    return PoseEstimate(camera_in_fork.inverse() @ pallet_in_fork, pallet_in_fork, score, margin, 0.3, 100, 0.0, 1.0)


@pytest.mark.parametrize(
    ("margin", "says"), [(0.04, "the runner-up is within 0.04"), (-0.02, "a rival scores 0.02 above")]
)
def test_an_ambiguous_pose_says_whether_a_rival_leads_or_trails(face, margin, says):
    """Regression: a pose refined at the measured pitch scored below a rival of the first search, and the refusal
    read "the runner-up is within -0.02 of the best similarity" (foreign render lowlight-loaded)."""
    with pytest.raises(MeasurementError, match=f"ambiguous pallet: {says}"):
        check_pose_estimate(_estimate(0.8, margin), _camera(), face)


@pytest.mark.parametrize(("score", "margin"), [(0.8, 0.04), (0.8, -0.02), (0.45, 0.3)])
def test_the_face_similarity_refusals_are_their_own_type_and_can_be_settled_elsewhere(face, score, margin):
    """A pose refused for its similarity alone (too low, a rival too close) raises FaceSimilarityError, which the
    measurement may excuse on the face's edges; with ``similarity`` False the geometric checks still refuse."""
    camera, estimate = _camera(), _estimate(score, margin)
    with pytest.raises(FaceSimilarityError):
        check_pose_estimate(estimate, camera, face)
    check_pose_estimate(estimate, camera, face, similarity=False)
    poorly_fitted = dataclasses.replace(estimate, group_inliers=0.4)
    with pytest.raises(MeasurementError, match="pocket edges fit poorly") as refused:
        check_pose_estimate(poorly_fitted, camera, face, similarity=False)
    assert not isinstance(refused.value, FaceSimilarityError)
