"""What the fleet interface needs from the truck it dispatches (simulated: drivers/sim/fleet_truck.py)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from contextlib import AbstractContextManager

from agf.controller import PickController
from agf.fleet.pick import PickRequest
from agf.pallets import PalletType


class FleetTruck(ABC):
    """A truck that runs picks for the fleet: its pallet catalogue, where it stands, and pick sessions."""

    @abstractmethod
    def pallets(self) -> Mapping[str, PalletType]:
        """The pallet types this truck can pick (the catalogue), name -> type."""

    @abstractmethod
    def fork_height(self) -> float:
        """Height of the fork frame's origin above the floor when a pick starts (m)."""

    @abstractmethod
    def position(self) -> tuple[float, float, float]:
        """Where the truck stands on the fleet's map: x, y (m), theta (rad)."""

    @abstractmethod
    def battery(self) -> tuple[float, bool]:
        """Battery charge (%) and whether it is charging."""

    @abstractmethod
    def pick_session(
        self, request: PickRequest, progress: Callable[[str], None]
    ) -> AbstractContextManager[PickController]:
        """A context that yields the controller of one pick for ``request`` (``run()`` is the caller's)
        and releases what the pick held when it exits; ``progress`` receives the controller's states."""

    @abstractmethod
    def reset(self) -> None:
        """The local reset after a failed pick (drive fault reset); never called from the network."""
