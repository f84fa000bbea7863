"""From a measured pallet to axis targets, and whether inserting there is safe (paper section V.A).

After the align move the fork-tip centre should sit a stand-off in front of the pocket centre with
the tilt equal to the pallet's pitch; insertion then runs straight along the tilt direction. What
remains are a height error dZ and a tilt error dtheta; the insertion is safe when the four
inequalities of section V.A hold for every error the measurement's uncertainty allows (its fourth
inequality read with (FT/2) cos(dtheta), DESIGN.md):

    -PH/2 < dZ - (FT/2) cos(dtheta)
    dZ + (FT/2) cos(dtheta) < PH/2
    -PH/2 < dZ - (FT/2) cos(dtheta) + FL sin(dtheta)
    dZ + (FT/2) cos(dtheta) + FL sin(dtheta) < PH/2
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from agf.axis import AxisLimits
from agf.config import ForkGeometry
from agf.geometry import Transform
from agf.kinematics import MastGeometry, axes_from_fork_in_truck, fork_in_truck_from_axes
from agf.measurement import PalletMeasurement
from agf.pallets import PalletType


@dataclass(frozen=True)
class InsertionConfig:
    """Stand-off before insertion, insertion depth (m), and how many standard deviations of the
    measurement are taken off the tolerances; residual errors of the drives (m, rad) add to them."""

    standoff: float = 0.25
    depth: float = 0.6
    sigmas: float = 3.0
    drive_error_z: float = 0.002
    drive_error_tilt: float = math.radians(0.05)
    max_yaw: float = math.radians(4.0)


def tolerance_slacks(dz: float, dtheta: float, pocket_height: float, forks: ForkGeometry) -> np.ndarray:
    """The four inequalities of section V.A as slacks (m): all positive means the fork passes."""
    half = pocket_height / 2
    thick = forks.thickness / 2 * math.cos(dtheta)
    drop = forks.length * math.sin(dtheta)
    return np.array([dz - thick + half, half - dz - thick, dz - thick + drop + half, half - dz - thick - drop])


def tolerance_margins(
    error_z: float, error_tilt: float, pocket_height: float, forks: ForkGeometry
) -> tuple[float, float]:
    """Worst slack (m) over the error box |dZ| <= error_z, |dtheta| <= error_tilt, and the tilt error (rad)
    that could still be added at that height error before an inequality fails (negative: already fails)."""
    corners = [(sz * error_z, st * error_tilt) for sz in (-1, 1) for st in (-1, 1)]
    margin = min(float(tolerance_slacks(dz, dt, pocket_height, forks).min()) for dz, dt in corners)
    low, high = 0.0, math.radians(20.0)
    for _ in range(50):  # largest tilt error every height error in the box survives
        mid = (low + high) / 2
        ok = all(
            tolerance_slacks(sz * error_z, st * mid, pocket_height, forks).min() > 0 for sz in (-1, 1) for st in (-1, 1)
        )
        low, high = (mid, high) if ok else (low, mid)
    return margin, low - error_tilt


@dataclass(frozen=True)
class InsertionPlan:
    """Targets (axis name -> m or rad) and the verdict; ``sigma_pitch`` (rad) is the standard deviation of the pitch
    of the measurement it was made from."""

    safe: bool
    reason: str | None
    align: dict[str, float]
    insert: dict[str, float]
    margin_mm: float
    margin_deg: float
    pallet_in_truck: Transform
    sigma_pitch: float = 0.0


def plan_insertion(
    measurement: PalletMeasurement,
    axes_now: Mapping[str, float],
    mast: MastGeometry,
    forks: ForkGeometry,
    pallet: PalletType,
    limits: Mapping[str, AxisLimits],
    config: InsertionConfig = InsertionConfig(),
) -> InsertionPlan:
    """Align and insert targets for the measured pallet; ``safe`` False with the reason when refused."""
    pallet_in_truck = fork_in_truck_from_axes(axes_now, mast) @ measurement.pallet_in_fork
    yaw, pitch, _ = pallet_in_truck.euler
    along = np.array([math.cos(pitch), 0.0, -math.sin(pitch)])  # pallet X in the truck's X-Z plane
    tip = pallet_in_truck.translation - config.standoff * along
    side_shift = "side_shift" in limits
    lateral = tip[1]
    target = Transform.from_euler(tip[0], lateral if side_shift else 0.0, tip[2], 0.0, pitch, 0.0)
    align = axes_from_fork_in_truck(target, mast, side_shift)
    travel = config.standoff + config.depth
    insert = {**align, "reach": align["reach"] + travel * along[0], "lift": align["lift"] + travel * along[2]}
    error_z = config.sigmas * measurement.sigma_z + config.drive_error_z
    error_tilt = config.sigmas * measurement.sigma_pitch + config.drive_error_tilt
    margin, margin_tilt = tolerance_margins(error_z, error_tilt, pallet.pocket_height, forks)
    reason = _refusal(
        align, insert, limits, margin, margin_tilt, yaw, lateral if not side_shift else 0.0, forks, pallet, config
    )
    return InsertionPlan(
        reason is None, reason, align, insert, margin * 1e3, math.degrees(margin_tilt), pallet_in_truck,
        measurement.sigma_pitch,
    )


def _refusal(align, insert, limits, margin, margin_tilt, yaw, lateral, forks, pallet, config) -> str | None:
    for name, target in (*align.items(), *insert.items()):
        if not limits[name].contains(target):
            return (
                f"axis {name} would have to reach {target:.4f}, outside its limits "
                f"[{limits[name].minimum:.4f}, {limits[name].maximum:.4f}]"
            )
    if margin <= 0 or margin_tilt <= 0:
        return (
            f"tolerance exceeded: worst slack {margin * 1e3:.1f} mm, tilt margin "
            f"{math.degrees(margin_tilt):.2f} deg (pocket {pallet.pocket_height * 1e3:.0f} mm)"
        )
    if abs(yaw) > config.max_yaw:
        return f"pallet yaw {math.degrees(yaw):.2f} deg exceeds {math.degrees(config.max_yaw):.1f} deg"
    drift = abs(lateral) + (config.standoff + config.depth) * abs(math.sin(yaw))
    room = _lateral_room(forks, pallet)
    if drift >= room:
        return f"lateral offset {drift * 1e3:.0f} mm over the insertion exceeds the pocket's {room * 1e3:.0f} mm room"
    return None


def _lateral_room(forks: ForkGeometry, pallet: PalletType) -> float:
    """How far (m) both tines may move sideways and stay inside their pockets."""
    room = math.inf
    for centre in (-forks.spacing / 2, forks.spacing / 2):
        low, high = centre - forks.width / 2, centre + forks.width / 2
        pocket = next(((a, b) for a, b in pallet.pockets() if a <= low and high <= b), None)
        if pocket is None:
            return 0.0
        room = min(room, low - pocket[0], pocket[1] - high)
    return room
