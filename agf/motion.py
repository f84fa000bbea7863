"""Jerk-limited fork motions with Ruckig: plain data in (start, target, limits), a trajectory out.

The align move synchronises all axes in time; the insertion synchronises reach and lift in phase, so
with the tilt held the fork tip runs on a straight line along the tilt direction. The free Ruckig
ignores position limits, so every target is checked against the axis limits here and refused, never
clamped silently; intermediate waypoints (Ruckig's cloud service) are never used.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from ruckig import InputParameter, Result, Ruckig, Synchronization
from ruckig import Trajectory as RuckigTrajectory

from agf.axis import AxisLimits


@dataclass(frozen=True)
class Trajectory:
    """A planned motion of named axes: positions at time ``t`` (s) from its start; ``duration`` (s)."""

    names: tuple[str, ...]
    duration: float
    _trajectory: RuckigTrajectory

    def at(self, t: float) -> dict[str, float]:
        position, _, _ = self._trajectory.at_time(min(max(t, 0.0), self.duration))
        return dict(zip(self.names, position, strict=True))

    def velocity_at(self, t: float) -> dict[str, float]:
        _, velocity, _ = self._trajectory.at_time(min(max(t, 0.0), self.duration))
        return dict(zip(self.names, velocity, strict=True))


@dataclass(frozen=True)
class MoveSequence:
    """Moves run one after another, each from rest where the one before ended: positions of every axis any of
    them moves (the ``start`` of those a move leaves alone) at time ``t`` (s) from the first one's start."""

    start: Mapping[str, float]
    moves: tuple[Trajectory, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(name for move in self.moves for name in move.names))

    @property
    def duration(self) -> float:
        return sum(move.duration for move in self.moves)

    def at(self, t: float) -> dict[str, float]:
        positions = {name: self.start[name] for name in self.names}
        for move in self.moves:
            positions.update(move.at(t))
            if t <= move.duration:
                break
            t -= move.duration
        return positions


def plan_move(
    start: Mapping[str, float],
    target: Mapping[str, float],
    limits: Mapping[str, AxisLimits],
    synchronization: Literal["time", "phase"] = "time",
) -> Trajectory:
    """A jerk-limited move from rest at ``start`` to rest at ``target`` for the axes named in ``target``.

    Raises
    ------
    ValueError
        If a target lies outside its axis limits or Ruckig finds no trajectory.
    """
    names = tuple(target)
    for name in names:
        if not limits[name].contains(target[name]):
            raise ValueError(
                f"target {target[name]:.4f} of axis {name} is outside its limits "
                f"[{limits[name].minimum:.4f}, {limits[name].maximum:.4f}]"
            )
    otg = Ruckig(len(names))
    inp = InputParameter(len(names))
    inp.current_position = [start[n] for n in names]
    inp.target_position = [target[n] for n in names]
    inp.max_velocity = [limits[n].max_velocity for n in names]
    inp.max_acceleration = [limits[n].max_acceleration for n in names]
    inp.max_jerk = [limits[n].max_jerk for n in names]
    inp.synchronization = Synchronization.Phase if synchronization == "phase" else Synchronization.Time
    trajectory = RuckigTrajectory(len(names))
    result = otg.calculate(inp, trajectory)
    if result not in (Result.Working, Result.Finished):
        raise ValueError(f"Ruckig found no trajectory ({result}) from {dict(start)} to {dict(target)}")
    return Trajectory(names, float(trajectory.duration), trajectory)
