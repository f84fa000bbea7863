"""The simulated truck behind ``agf serve`` (``plugins.fleet_truck``): every pick runs in a new
:class:`drivers.sim.world.SimulatedWorld` of the scene ``simulation.scene`` names, as if the truck had
driven up to a new pallet; the truck stands at the origin of the fleet's map.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager

from agf.clock import WallClock
from agf.config import Config
from agf.controller import PickController
from agf.fleet.pick import PickRequest
from agf.fleet.truck import FleetTruck
from agf.kinematics import MastGeometry, fork_in_truck_from_axes
from agf.pallets import PalletType, load_pallets
from agf.paths import repo_path
from agf.scene import load_scene
from drivers.sim.world import START, SimulatedWorld


class SimulatedFleetTruck(FleetTruck):
    """A :class:`agf.fleet.truck.FleetTruck` on the simulated world; ``world`` is the pick's while it runs."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self._pallets = load_pallets(config.vision.pallets)
        self.scene = load_scene(
            repo_path((config.sections.get("simulation") or {}).get("scene", "configs/scenes/pick.yaml"))
        )
        self.world: SimulatedWorld | None = None
        self.sessions = 0  # picks whose world was built (tests: bad input builds none, so moves nothing)

    def pallets(self) -> Mapping[str, PalletType]:
        return self._pallets

    def fork_height(self) -> float:
        return float(fork_in_truck_from_axes(START, MastGeometry()).translation[2])

    def position(self) -> tuple[float, float, float]:
        return (0.0, 0.0, 0.0)

    def battery(self) -> tuple[float, bool]:
        return (100.0, False)  # the simulated truck has no battery model

    def reset(self) -> None:
        """Nothing outlives a simulated pick: the next one builds a new world with reset drives."""

    @contextmanager
    def pick_session(self, request: PickRequest, progress: Callable[[str], None]) -> Iterator[PickController]:
        # a fleet manager talks in real time: the truck it dispatches keeps the wall clock
        with SimulatedWorld(self.config, self.scene, WallClock()) as world:
            # What the controller measures and plans for is the fleet's request; the scene's own pallet
            # stays the truth the world renders and checks collisions against.
            world.pallet = self._pallets[request.load_type]
            world.config = dataclasses.replace(
                self.config,
                vision=dataclasses.replace(self.config.vision, search=request.search),
                sections=self._sections(request),
            )
            if request.height is not None:  # request.search was narrowed at the forks' height now
                world.search_fork_height = self.fork_height()
            self.world = world
            self.sessions += 1
            yield world.controller(progress)

    def _sections(self, request: PickRequest) -> dict:
        if request.depth is None:
            return self.config.sections
        insertion = {**(self.config.sections.get("insertion") or {}), "depth_mm": request.depth * 1e3}
        return {**self.config.sections, "insertion": insertion}
