"""A pitch known only loosely is refused (:func:`agf.vision.measure.check_pitch_sigma`)."""

from __future__ import annotations

import math

import pytest

from agf.errors import MeasurementError
from agf.vision.accuracy import BOUNDS
from agf.vision.measure import MeasureConfig, check_pitch_sigma

LIMIT = MeasureConfig().max_sigma_pitch


def test_the_limit_is_half_the_pitch_bound_a_measurement_is_checked_against():
    assert math.degrees(LIMIT) == pytest.approx(BOUNDS["pitch_deg"] / 2)


@pytest.mark.parametrize("hypothesis", ["loaded", "unloaded"])
def test_a_pitch_within_the_limit_passes(hypothesis):
    check_pitch_sigma(hypothesis, math.radians(0.03), LIMIT)
    check_pitch_sigma(hypothesis, LIMIT, LIMIT)  # on the limit


@pytest.mark.parametrize(
    ("hypothesis", "source"), [("loaded", "the load's edges and face"), ("unloaded", "the deck edges")]
)
def test_a_looser_pitch_is_refused_naming_its_evidence_and_the_limit(hypothesis, source):
    with pytest.raises(MeasurementError, match=rf"{source} give it only to \+-0\.057 deg \(at most 0\.050\)"):
        check_pitch_sigma(hypothesis, math.radians(0.057), LIMIT)
