"""The reach-truck mast: axis positions (lift, reach, tilt, optional side shift) <-> fork pose in the truck.

Frame T is fixed to the truck (X forward, Z up along the mast). At zero axes the fork frame F sits at
``origin`` in T. Lift raises it along Z, reach moves it along X, side shift along Y, and tilt rotates
the forks about a pivot (given in F at zero tilt, near the fork heel) about Y. Tilt has the sign of
pallet pitch (DESIGN.md): positive tilt turns the fork X axis down, so the tips drop by about
FL * sin(tilt) relative to a pivot at the heel.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from agf.geometry import Transform, matrix_from_euler


@dataclass(frozen=True)
class MastGeometry:
    """Where the forks are at zero axes (truck frame, m) and the tilt pivot (fork frame at zero tilt, m)."""

    origin: tuple[float, float, float] = (1.2, 0.0, 0.05)
    pivot: tuple[float, float] = (-1.07, 0.0)  # (x, z): at the fork heel, on the fork's mid-plane

    def pivot_point(self) -> np.ndarray:
        return np.array([self.pivot[0], 0.0, self.pivot[1]])


def fork_in_truck_from_axes(positions: Mapping[str, float], mast: MastGeometry) -> Transform:
    """Fork frame F in truck frame T for axis positions (m, rad); missing axes are at zero."""
    tilt = positions.get("tilt", 0.0)
    p = mast.pivot_point()
    R = matrix_from_euler(0.0, tilt, 0.0)
    carriage = np.array(mast.origin) + [
        positions.get("reach", 0.0),
        positions.get("side_shift", 0.0),
        positions.get("lift", 0.0),
    ]
    # from_euler builds the rotation about Y unchecked (the full check costs 20 us; twice every control cycle)
    return Transform.from_euler(*(carriage + p - R @ p), 0.0, tilt, 0.0)


def axes_from_fork_in_truck(fork_in_truck: Transform, mast: MastGeometry, side_shift: bool = False) -> dict[str, float]:
    """Axis positions that put the forks at ``fork_in_truck``; the inverse of the function above.

    Raises
    ------
    ValueError
        If the pose needs roll or yaw (the mast has no such axis), or a lateral offset without side shift.
    """
    yaw, pitch, roll = fork_in_truck.euler
    if abs(roll) > 1e-6 or abs(yaw) > 1e-6:
        raise ValueError(
            f"the mast cannot roll or yaw the forks (roll {math.degrees(roll):.3f} deg, "
            f"yaw {math.degrees(yaw):.3f} deg requested)"
        )
    p = mast.pivot_point()
    carriage = fork_in_truck.translation - p + matrix_from_euler(0.0, pitch, 0.0) @ p - np.array(mast.origin)
    if not side_shift and abs(carriage[1]) > 1e-6:
        raise ValueError(f"a lateral offset of {carriage[1] * 1e3:.1f} mm needs a side-shift axis")
    positions = {"lift": float(carriage[2]), "reach": float(carriage[0]), "tilt": float(pitch)}
    if side_shift:
        positions["side_shift"] = float(carriage[1])
    return positions
