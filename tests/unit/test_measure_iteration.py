"""The pose-pitch iteration's next pitch (:func:`agf.vision.measure.next_pitch`): a 2-cycle is split at its
midpoint, a steady approach is followed as measured."""

from __future__ import annotations

import math

import pytest

from agf.vision.measure import next_pitch

TOLERANCE = math.radians(0.03)


def iterate(measured_at, start: float, iterations: int = 6) -> tuple[float, float, int]:
    """Search pitch, largest swing and iterations until the measured pitch agrees with the searched one."""
    pitch, step, swing = start, 0.0, 0.0
    for n in range(iterations):
        change = measured_at(pitch) - pitch
        if abs(change) < TOLERANCE:
            return pitch, swing, n
        pitch, swung = next_pitch(pitch, pitch + change, step)
        swing, step = max(swing, swung), change
    raise AssertionError(f"no agreement after {iterations} iterations")


@pytest.mark.parametrize("gain", [-1.0, -0.95, -0.8])
def test_two_cycle_is_split_at_its_midpoint(gain):
    """Regression (random pick 73): the edges' pitch swung with the pose's about the true pitch and never
    agreed within 0.03 deg in six iterations."""
    truth = math.radians(-1.8)
    measured_at = lambda p: truth + gain * (p - truth)  # noqa: E731 - the edges lean against the pose
    start = truth + math.radians(0.07)
    pitch, swing, _ = iterate(measured_at, start)
    assert abs(pitch - truth) < TOLERANCE
    assert swing >= math.radians(0.07)  # the swing is reported, for the uncertainty


@pytest.mark.parametrize("gain", [0.0, 0.2])
def test_steady_approach_follows_the_measurement(gain):
    truth = math.radians(2.5)
    pitch, swing, n = iterate(lambda p: truth + gain * (p - truth), 0.0)
    assert abs(pitch - truth) < TOLERANCE * (1 + gain)
    assert swing == 0.0
    assert next_pitch(0.01, 0.02, 0.005) == (0.02, 0.0)


def test_a_change_turning_back_searches_at_the_midpoint():
    assert next_pitch(0.010, 0.006, 0.002) == pytest.approx((0.008, 0.004))
