"""The VDA 5050 factsheet of this truck: the pallets it can pick, its forks, and the ``pick`` action."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from agf.config import FleetConfig, ForkGeometry
from agf.fleet.pick import LOAD_POSITION, PICK_PARAMETERS
from agf.pallets import PalletType

INSTANT_ACTIONS = {
    "cancelOrder": "quick stop of the running pick (it ends FAILED); a local reset is needed before the next pick",
    "startPause": "hold the pick at its next state boundary, between two motions",
    "stopPause": "continue a held pick",
    "stateRequest": "publish the state now",
    "factsheetRequest": "publish the factsheet now",
}


def factsheet_body(fleet: FleetConfig, forks: ForkGeometry, pallets: Mapping[str, PalletType]) -> dict[str, Any]:
    """The factsheet without its header (m, kg, s; VDA 5050 section 6.15)."""
    truck = fleet.truck
    return {
        "typeSpecification": {
            "seriesName": truck.series_name,
            "seriesDescription": "reach truck with camera-guided fork insertion into pitched pallets",
            "agvKinematic": "THREEWHEEL",
            "agvClass": "FORKLIFT",
            "maxLoadMass": truck.max_load_kg,
            "localizationTypes": ["NATURAL"],
            "navigationTypes": ["AUTONOMOUS"],
        },
        # No travel is built here (orders must be at the truck's position): speeds are zero.
        "physicalParameters": {
            "speedMin": 0.0,
            "speedMax": 0.0,
            "accelerationMax": 0.0,
            "decelerationMax": 0.0,
            "heightMax": truck.height_max,
            "width": truck.width,
            "length": truck.length,
        },
        "protocolLimits": {
            "maxStringLens": {},
            "maxArrayLens": {"order.nodes": 1, "order.edges": 0, "node.actions": 1},
            "timing": {"minOrderInterval": 1.0, "minStateInterval": 0.1, "defaultStateInterval": fleet.state_period},
        },
        "protocolFeatures": {
            "optionalParameters": [],
            "agvActions": [_pick_action(), *_instant_actions()],
        },
        "agvGeometry": {},
        "loadSpecification": {
            "loadPositions": [LOAD_POSITION],
            "loadSets": [_load_set(name, pallet, forks, fleet.pick_time) for name, pallet in pallets.items()],
        },
    }


# No ``blockingTypes``: the 2.1.0 schema types it as an array whose value must be one enum string, which
# no array is, so a factsheet that has it cannot validate.
def _pick_action() -> dict[str, Any]:
    return {
        "actionType": "pick",
        "actionDescription": "measure the pallet with the fork camera and insert the forks, tilted to its pitch",
        "actionScopes": ["NODE"],
        "actionParameters": [
            {"key": key, "valueDataType": kind, "isOptional": optional, "description": what}
            for key, (kind, optional, what) in PICK_PARAMETERS.items()
        ],
        "resultDescription": "the picked pallet in state.loads",
    }


def _instant_actions() -> list[dict[str, Any]]:
    return [
        {"actionType": name, "actionDescription": what, "actionScopes": ["INSTANT"]}
        for name, what in INSTANT_ACTIONS.items()
    ]


def _load_set(name: str, pallet: PalletType, forks: ForkGeometry, pick_time: float) -> dict[str, Any]:
    return {
        "setName": name,
        "loadType": name,
        "loadPositions": [LOAD_POSITION],
        "loadDimensions": {"length": pallet.length, "width": pallet.width, "height": pallet.height},
        "minLoadhandlingDepth": 0.0,
        "maxLoadhandlingDepth": forks.length,
        "pickTime": pick_time,
        "description": f"pocket {pallet.pocket_height * 1e3:.0f} mm high; forks {forks.thickness * 1e3:.0f} mm thick, "
        f"{forks.length * 1e3:.0f} mm long, {forks.spacing * 1e3:.0f} mm apart",
    }
