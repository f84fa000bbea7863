"""Ruckig motions: synchronised align, straight-line insertion, limits respected, targets refused."""

from __future__ import annotations

import numpy as np
import pytest

from agf.axis import AxisLimits
from agf.errors import ConfigError
from agf.motion import MoveSequence, plan_move
from agf.planner import pick_settings_from_mapping

LIMITS = {
    "lift": AxisLimits(0.0, 3.0, 0.4, 0.8, 4.0),
    "reach": AxisLimits(0.0, 1.3, 0.25, 0.5, 2.5),
    "tilt": AxisLimits(-0.1, 0.1, 0.07, 0.14, 0.7),
}


def test_align_move_finishes_every_axis_together():
    move = plan_move({"lift": 0.6, "reach": 0.3, "tilt": 0.0}, {"lift": 0.85, "reach": 0.2, "tilt": 0.03}, LIMITS)
    end = move.at(move.duration)
    assert end == pytest.approx({"lift": 0.85, "reach": 0.2, "tilt": 0.03}, abs=1e-9)
    before = move.at(move.duration * 0.97)
    assert all(abs(before[n] - end[n]) > 1e-7 for n in end)  # nobody arrives early: time-synchronised
    assert all(abs(v) < 1e-9 for v in move.velocity_at(move.duration).values())


def test_insertion_runs_on_a_straight_line():
    start, target = {"lift": 0.8, "reach": 0.25}, {"lift": 0.779, "reach": 0.8496}
    move = plan_move(start, target, LIMITS, "phase")
    direction = np.array([target["reach"] - start["reach"], target["lift"] - start["lift"]])
    direction /= np.linalg.norm(direction)
    for t in np.linspace(0, move.duration, 200):
        p = move.at(t)
        offset = np.array([p["reach"] - start["reach"], p["lift"] - start["lift"]])
        assert abs(offset[0] * direction[1] - offset[1] * direction[0]) < 1e-3  # < 1 mm off the line


def test_sampled_trajectory_respects_velocity_acceleration_and_jerk():
    move = plan_move({"lift": 0.0, "reach": 0.0}, {"lift": 1.2, "reach": 0.9}, LIMITS)
    dt = 1e-3
    t = np.arange(0, move.duration, dt)
    for name in ("lift", "reach"):
        x = np.array([move.at(ti)[name] for ti in t])
        v, a, j = np.diff(x) / dt, np.diff(x, 2) / dt**2, np.diff(x, 3) / dt**3
        assert np.max(np.abs(v)) <= LIMITS[name].max_velocity * 1.001
        assert np.max(np.abs(a)) <= LIMITS[name].max_acceleration * 1.01
        assert np.max(np.abs(j)) <= LIMITS[name].max_jerk * 1.05


def test_target_outside_the_limits_is_refused_not_clamped():
    with pytest.raises(ValueError, match="outside its limits"):
        plan_move({"reach": 0.5}, {"reach": 1.5}, LIMITS)


def test_scaled_limits_keep_the_stroke_and_cut_the_dynamics():
    limits = AxisLimits(0.0, 3.0, 0.5, 1.0, 5.0)
    cut = limits.scaled(0.8)
    assert (cut.minimum, cut.maximum) == (0.0, 3.0)
    assert (cut.max_velocity, cut.max_acceleration, cut.max_jerk) == pytest.approx((0.4, 0.8, 4.0))
    for share in (0.0, 1.2, float("nan")):
        with pytest.raises(ValueError, match="motion share"):
            limits.scaled(share)


def test_motion_share_out_of_range_is_a_named_config_error():
    with pytest.raises(ConfigError, match=r"agf.yaml: insertion: motion_share must be in \(0, 1\], got 1.5"):
        pick_settings_from_mapping({"motion_share": 1.5}, "agf.yaml: insertion")


def test_a_move_sequence_runs_each_move_from_where_the_last_ended():
    start = {"lift": 0.6, "reach": 0.3, "tilt": 0.0}
    rise = plan_move(start, {"lift": 0.9, "tilt": 0.03}, LIMITS)
    approach = plan_move({**start, "lift": 0.9, "tilt": 0.03}, {"reach": 0.2}, LIMITS)
    sequence = MoveSequence(start, (rise, approach))
    assert sequence.names == ("lift", "tilt", "reach")
    assert sequence.duration == pytest.approx(rise.duration + approach.duration)
    assert sequence.at(0.0) == pytest.approx(start)
    assert sequence.at(rise.duration) == pytest.approx({"lift": 0.9, "tilt": 0.03, "reach": 0.3}, abs=1e-9)
    middle = sequence.at(rise.duration / 2)
    assert middle["reach"] == 0.3 and 0.6 < middle["lift"] < 0.9  # the reach waits for the lift
    later = sequence.at(rise.duration + approach.duration / 2)
    assert later["lift"] == pytest.approx(0.9, abs=1e-9) and 0.2 < later["reach"] < 0.3
    assert sequence.at(sequence.duration + 1.0) == pytest.approx({"lift": 0.9, "tilt": 0.03, "reach": 0.2}, abs=1e-9)
