"""The VDA 5050 ``pick`` action on this truck: its parameters, checked before anything moves.

``loadType`` names the pallet type of the catalogue that the camera looks for; ``height`` (m, the
underside of the load above the floor, as the standard defines it) narrows the vertical search
volume to the pallet it implies; ``depth`` (m) is how far the forks go in past the pallet's front
face; ``lhd`` must be the forks; ``stationType`` and ``stationName`` are recorded, not used.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from agf.config import ForkGeometry, SearchVolume
from agf.fleet.messages import RejectedMessage, parameters, vda_error
from agf.pallets import PalletType

LOAD_POSITION = "forks"  # the truck's one load handling device

# key: (VDA 5050 valueDataType, optional, what it means here); the factsheet lists these.
PICK_PARAMETERS: dict[str, tuple[str, bool, str]] = {
    "stationType": ("STRING", False, "recorded, not used (floor, rack, truck bed: the camera measures the pallet)"),
    "loadType": ("STRING", False, "pallet type from the catalogue the camera looks for"),
    "loadId": ("STRING", True, "reported in state.loads once picked"),
    "stationName": ("STRING", True, "recorded, not used"),
    "height": ("FLOAT", True, "m, underside of the pallet above the floor: narrows the vertical search"),
    "depth": ("FLOAT", True, "m, insertion depth past the pallet's front face (default: the configured depth)"),
    "lhd": ("STRING", True, f"load handling device; only {LOAD_POSITION!r}"),
    "side": ("STRING", True, "recorded, not used"),
}


@dataclass(frozen=True)
class PickRequest:
    """One accepted ``pick``: what to look for, where, and how deep to go (m)."""

    action_id: str
    load_type: str
    station_type: str
    search: SearchVolume
    load_id: str | None = None
    depth: float | None = None
    height: float | None = None  # the pallet's underside above the floor; ``search`` was narrowed to it


def pick_request(
    action: Mapping[str, Any],
    pallets: Mapping[str, PalletType],
    forks: ForkGeometry,
    search: SearchVolume,
    fork_height: float,
    height_window: float,
    references: Mapping[str, Any],
) -> PickRequest:
    """Check a ``pick`` action's parameters and turn them into a :class:`PickRequest`.

    Parameters
    ----------
    action : the action object of the order
    pallets : the pallet catalogue, name -> type
    forks : fork geometry; ``depth`` may not exceed the fork length
    search : the configured search volume (fork frame, m)
    fork_height : height of the fork frame's origin above the floor when the pick starts (m)
    height_window : the vertical search is narrowed to +- this around the pallet ``height`` implies (m)
    references : error references of the message (topic, headerId, orderId, ...)

    Raises
    ------
    RejectedMessage
        An ``orderError`` naming the action and the parameter that is missing, unknown or out of range.
    """
    given = parameters(action)
    refs = {**references, "actionId": action["actionId"]}

    def reject(key: str, why: str) -> RejectedMessage:
        return RejectedMessage(
            vda_error("orderError", f"pick {action['actionId']}: {key}: {why}", {**refs, "actionParameter": key})
        )

    unknown = sorted(set(given) - set(PICK_PARAMETERS))
    if unknown:
        raise reject(unknown[0], f"unknown parameter; this truck takes {sorted(PICK_PARAMETERS)}")
    for key, (kind, optional, _) in PICK_PARAMETERS.items():
        if key not in given:
            if not optional:
                raise reject(key, "missing (a pick needs stationType and loadType)")
            continue
        value = given[key]
        if kind == "STRING" and not isinstance(value, str):
            raise reject(key, f"expected a string, got {value!r}")
        if kind == "FLOAT" and (
            isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value)
        ):
            raise reject(key, f"expected a number in metres, got {value!r}")
    if given["loadType"] not in pallets:
        raise reject("loadType", f"{given['loadType']!r} is not in the pallet catalogue {sorted(pallets)}")
    if given.get("lhd", LOAD_POSITION) != LOAD_POSITION:
        raise reject("lhd", f"this truck has one load handling device, {LOAD_POSITION!r}, not {given['lhd']!r}")
    depth = given.get("depth")
    if depth is not None and not 0 < depth <= forks.length:
        raise reject("depth", f"{depth} m is outside 0..{forks.length} m (the fork length)")
    if "height" in given:
        try:
            search = search_at_height(search, pallets[given["loadType"]], given["height"], fork_height, height_window)
        except ValueError as exc:
            raise reject("height", str(exc)) from None
    return PickRequest(
        action_id=action["actionId"],
        load_type=given["loadType"],
        station_type=given["stationType"],
        search=search,
        load_id=given.get("loadId"),
        depth=None if depth is None else float(depth),
        height=None if "height" not in given else float(given["height"]),
    )


def search_at_height(
    search: SearchVolume, pallet: PalletType, height: float, fork_height: float, window: float
) -> SearchVolume:
    """``search`` with its vertical range narrowed to +- ``window`` (m) around the front-face centre of a
    ``pallet`` whose underside is ``height`` (m) above the floor, seen from forks ``fork_height`` up.

    Raises
    ------
    ValueError
        If that range misses the configured search volume (the pallet is out of the camera's reach).
    """
    centre = height - pallet.deck_bottom - fork_height  # frame P's origin sits -deck_bottom above the underside
    low, high = max(search.z_min, centre - window), min(search.z_max, centre + window)
    if low >= high:
        raise ValueError(
            f"{height} m puts the pallet's front face {centre * 1e3:.0f} mm from the forks, outside the search "
            f"volume {search.z_min * 1e3:.0f}..{search.z_max * 1e3:.0f} mm"
        )
    return dataclasses.replace(search, z_min=low, z_max=high)


def picked_load(request: PickRequest, pallet: PalletType) -> dict[str, Any]:
    """The ``state.loads`` entry of a finished pick; its bounding box is the pallet's (m)."""
    load: dict[str, Any] = {
        "loadType": request.load_type,
        "loadPosition": LOAD_POSITION,
        "loadDimensions": {"length": pallet.length, "width": pallet.width, "height": pallet.height},
    }
    if request.load_id is not None:
        load["loadId"] = request.load_id
    return load
