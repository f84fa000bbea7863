"""The simulated world: a truck whose forks move on simulated CiA 402 drives over a CAN bus, a pallet
standing in front of it, and a camera on the fork carriage that renders what it sees (``agf run`` on
the default config and ``agf simulate``).

The pallet is fixed in the truck frame; the camera moves with the forks, so every frame is rendered
for the axes' actual positions. Every control cycle the tines are checked against the pallet's
solid parts and the slab it stands on (truck bed or dock): a negative clearance is a collision, counted,
never hidden.

``agf simulate`` runs its picks on a simulated clock (:class:`agf.clock.SimulatedClock`): the same
setpoints, drive physics and CAN messages as in real time, as fast as the CPU allows; ``agf run``
(and a world with real drives, hardware in the loop) keeps wall-clock time.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import math
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from agf.camera import load_camera
from agf.clock import Clock, SimulatedClock, WallClock
from agf.config import Config, ForkGeometry, SearchVolume, load_calibration
from agf.controller import ControllerConfig, PickController, PickResult
from agf.errors import ConfigError, DriveFault, MeasurementError
from agf.frames import Frame, FrameSource, JpegImage
from agf.geometry import Transform
from agf.kinematics import MastGeometry, fork_in_truck_from_axes
from agf.measurement import PalletMeasurement, uncertainty_json
from agf.motion import plan_move
from agf.pallets import load_pallets
from agf.paths import repo_path
from agf.planner import PickPlanner, pick_settings_from_mapping
from agf.plugins import load_object
from agf.recorder import McapRecorder, MeasurementSetup, Recorder, open_pick_log
from agf.scene import Environment, Load, PalletPlacement, Scene, load_scene
from agf.vision.measure import confirm_pallet, measure_pallet
from agf.viz import fork_path_side_view, pick_plots
from drivers.can_tap import CanTap
from drivers.cia402_axis import axes_from_config
from drivers.sim.campaign import make_backend, run_campaign
from drivers.sim.collision import clearance, pallet_parts, signed_distances, tine_surface
from drivers.sim.drive import start_simulated_drives
from drivers.sim.fast_render import camera_output
from drivers.sim.looks import draw_look
from drivers.sim.render import catalogued, exposed, support_box

# Axes at the start of a pick (m, rad): reach 0.15 m leaves the 1.3 m stroke room for a pallet 400 mm
# ahead plus 850 mm of stand-off and insertion (at 0.3 m, six of 200 random picks were out of reach).
START = {"lift": 0.6, "reach": 0.15, "tilt": 0.0}
SUPPORT_GAP = 0.02  # m: a campaign scene's tines start at least this far from the slab the pallet stands on
FORKS = ForkGeometry()  # the paper's, as agf.yaml configures them
LOAD_INSET = 0.05  # m: a random load's sides and back inside the pallet's (load_footprint)
_TYPE_STREAM = 1  # the third word of the seed of a campaign pick's pallet type (campaign_scene)


class RenderedCamera(FrameSource):
    """Frames rendered for the forks' actual position."""

    def __init__(self, world: SimulatedWorld) -> None:
        super().__init__(world.camera.width, world.camera.height)
        self.world = world

    def describe(self) -> str:
        return "simulated camera"

    def _set_exposure(self, scale: float) -> None:
        pass  # the next frames are rendered with the scene's light scaled (see _read)

    def _read(self, timeout: float) -> np.ndarray | JpegImage | None:
        if self.world.frames_lost:
            self.world.frames_lost -= 1
            return None
        scene = self.world.scene_now()
        sent = camera_output(exposed(scene, self.exposure), self.world.camera)
        self.world.frame_truths.append(scene.pallet.in_fork)
        return sent


class SimulatedWorld:
    """Drives, pallet and camera of one simulated pick; a context manager that closes the bus.

    ``clock`` is the time the drives, the CANopen master and the controller keep: simulated by default
    when the drives are simulated in this process on a virtual bus (see :func:`world_clock`).
    ``bus_wrapper`` (the fault tests put drivers.lossy_bus between master and drives) wraps the
    master's connection.
    """

    def __init__(self, config: Config, scene: Scene, clock: Clock | None = None, bus_wrapper: Any = None) -> None:
        if scene.pallet is None:
            raise ConfigError("a pick scene needs a 'pallet' (a calibration scene cannot be picked)")
        self.config, self.scene = config, scene
        # the fault tests' lossy bus keeps wall time, as the fault matrix was measured on it
        self.clock = clock or (WallClock() if bus_wrapper is not None else world_clock(config))
        self.camera = load_camera(scene.camera)
        self.mast = MastGeometry()
        self.pallet = load_pallets(config.vision.pallets)[scene.pallet.type]
        self.pick_settings = pick_settings_from_mapping(config.sections.get("insertion"), f"{config.source}: insertion")
        self.network, self.axes = axes_from_config(
            config.sections["drives"], config.sections["bus"], f"{config.source}:", base_dir=config.source.parent,
            start_drives=_placed(drive_starter(config), START),
            bus_wrapper=bus_wrapper,
            clock=self.clock,
        )
        self.frames_lost = 0
        self.frame_truths: list[Transform] = []  # the true pallet_in_fork of each rendered frame
        self.measured_truths: list[Transform] = []  # ... of each frame measured successfully
        # The fork height (m, truck frame) vision.search was narrowed at when it is anchored to the floor (a fleet
        # pick's height), None when it moves with the forks (the configured volume).
        self.search_fork_height: float | None = None
        self.min_support_clearance = math.inf  # to the slab the pallet stands on (m)
        self.inside = False
        self._tines = tine_surface(config.forks)
        y, ft, fl = config.forks.spacing / 2, config.forks.thickness / 2, config.forks.length
        self._outline = np.array([[0.0, y, ft], [0.0, y, -ft], [-fl, y, -ft], [-fl, y, ft]])  # left tine, side
        self.outlines: list[np.ndarray] = []  # per cycle, the left tine's side outline in frame P
        self.clearances: list[float] = []  # per cycle, to the pallet (m)
        self._parts = pallet_parts(self.pallet)
        self._support = support_box(self.pallet, draw_look(scene) if scene.look == "random" else None)[None]
        try:
            self._move_to(START)
        except BaseException:  # no `with` holds the world yet: close its bus, or its drives live on
            self.network.close()
            raise
        self.pallet_in_truck = fork_in_truck_from_axes(self.positions(), self.mast) @ scene.pallet.in_fork

    def __enter__(self) -> SimulatedWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.network.close()

    def positions(self) -> dict[str, float]:
        return {name: axis.feedback().position for name, axis in self.axes.items()}

    def fork_height(self) -> float:
        """Height of the fork frame's origin in the truck frame now (m)."""
        return float(fork_in_truck_from_axes(self.positions(), self.mast).translation[2])

    def search(self) -> SearchVolume:
        """The volume the vision searches now, in the fork frame: one anchored to the floor moves down as the
        forks rise (after aligning, a fleet pick's pallet sits level with the forks, far below where the forks
        started)."""
        search = self.config.vision.search
        if self.search_fork_height is None:
            return search
        return search.lifted(self.fork_height() - self.search_fork_height)

    def scene_now(self) -> Scene:
        return self.scene_at(self.positions())

    def scene_at(self, positions: dict[str, float]) -> Scene:
        """The scene as the camera sees it with the axes at ``positions`` (m, rad)."""
        fork_in_truck = fork_in_truck_from_axes(positions, self.mast)
        placement = PalletPlacement(self.scene.pallet.type, fork_in_truck.inverse() @ self.pallet_in_truck)
        return dataclasses.replace(self.scene, pallet=placement)

    def on_cycle(self, positions: dict[str, float]) -> None:
        fork_in_pallet = self.pallet_in_truck.inverse() @ fork_in_truck_from_axes(positions, self.mast)
        self.clearances.append(clearance(self._tines, fork_in_pallet, self._parts))
        self.outlines.append(fork_in_pallet.apply(self._outline))
        support = clearance(self._tines, fork_in_pallet, self._support)
        self.min_support_clearance = min(self.min_support_clearance, support)

    @property
    def min_clearance(self) -> float:
        """The smallest clearance (m) of the tines to the pallet and to the slab it stands on so far (inf before any
        control cycle); negative is a collision."""
        return min(min(self.clearances, default=math.inf), self.min_support_clearance)

    def plots(self, result: PickResult, folder: Path) -> list[str]:
        """The pick's plots in ``folder``: axis trajectories and the side view of the fork path."""
        written = pick_plots(result, folder)
        if self.outlines:
            side = folder / "fork_path_side.png"
            written.append(fork_path_side_view(np.array(self.outlines), np.array(self.clearances), self.pallet, side))
        return written

    def _move_to(self, target: dict[str, float]) -> None:
        """Bring the axes to the start pose (setup, not part of the pick)."""
        for axis in self.axes.values():
            axis.enable()
        now = self.positions()
        share = self.pick_settings.motion_share  # the headroom the pick's own plans keep
        motion = plan_move(now, target, {n: a.limits.scaled(share) for n, a in self.axes.items()})
        self.network.stream(lambda t: motion.at(min(t, motion.duration)))  # from the SYNC thread or event
        clock = self.clock
        deadline = clock.monotonic() + 10 * motion.duration + 5.0  # SYNC time runs behind on a loaded CPU
        while clock.monotonic() < deadline and any(abs(p - target[n]) > 1e-4 for n, p in self.positions().items()):
            next(iter(self.axes.values())).wait_for_feedback(timeout=0.2)
        self.network.stream(None)

    def controller(self, progress=None, recorder: Recorder | None = None) -> PickController:
        calibration = load_calibration(self.config.vision.calibration)
        camera = load_camera(self.config.vision.camera)

        def counted(frame: Frame, measurement: PalletMeasurement) -> PalletMeasurement:
            if frame.index <= len(self.frame_truths):  # a replayed frame (the fault tests') has no truth
                self.measured_truths.append(self.frame_truths[frame.index - 1])
            return measurement

        def measure(frame: Frame, prior: PalletMeasurement | None) -> PalletMeasurement:
            return counted(frame, measure_pallet(
                frame.image, camera, calibration, self.pallet, self.search(), forks=self.config.forks,
                verifying=prior is not None,
            ).measurement)

        def confirm(frame: Frame, expected: Transform, measured: PalletMeasurement) -> PalletMeasurement:
            return counted(frame, confirm_pallet(
                frame.image, camera, calibration, self.pallet, self.search(), expected, loaded=measured.loaded,
                sigma_pitch=measured.sigma_pitch, forks=self.config.forks,
            ).measurement)

        planner = PickPlanner(
            self.mast, self.config.forks, self.pallet, {n: a.limits for n, a in self.axes.items()}, self.pick_settings
        )
        timeouts = {**ControllerConfig().timeouts, "acquiring": 60.0, "measuring": 30.0, "verifying": 90.0}
        return PickController(
            self.axes,
            RenderedCamera(self),
            measure,
            planner,
            ControllerConfig(cycle=self.network.settings.cycle, timeouts=timeouts),
            on_cycle=self.on_cycle,
            progress=progress,
            recorder=recorder,
            streamer=self.network,
            clock=self.clock,
            confirm=confirm,
        )


@contextlib.contextmanager
def pick_log(config: Config, scene: Scene, name: str, clock: Clock | None = None) -> Iterator[McapRecorder]:
    """The pick's MCAP log in the configured folder, with the bus traffic from before the drives start;
    ``clock`` is the time of the pick's bus (the wall clock by default; see :class:`drivers.can_tap.CanTap`)."""
    setup = MeasurementSetup.from_config(config, scene.pallet.type if scene.pallet else None)
    truth = {"scene_pallet_in_fork": json.dumps(scene.pallet.in_fork.to_dict())} if scene.pallet else {}
    fork_in_truck = functools.partial(fork_in_truck_from_axes, mast=MastGeometry())
    with (
        open_pick_log(config, name, setup, context={"command": name, **truth}, fork_in_truck=fork_in_truck) as log,
        CanTap(config.sections["bus"], f"{config.source}: bus", log, clock),
    ):
        yield log


def drive_starter(config: Config) -> Any:
    """What ``plugins.drives`` names to start the drives with, or None (a truck's drives run on their own)."""
    spec = config.plugins.get("drives")
    return None if spec is None else load_object(spec, key=f"{config.source}: plugins.drives")


def _placed(start_drives: Any, positions: dict[str, float]) -> Any:
    """``start_drives`` whose simulated drives start with their axes at ``positions`` (m, rad; see
    :meth:`drivers.sim.drive.SimDrive.place`): the truck arrives with its forks there, and the world's move
    to the start pose has nothing left to do (it was 0.6 s of wall time a pick). None stays None."""
    if start_drives is None:
        return None

    def start(drives: Sequence[Any], *args: Any, **kwargs: Any) -> list[Any]:
        started = start_drives(drives, *args, **kwargs)
        for settings, drive in zip(drives, started, strict=True):
            if hasattr(drive, "place"):
                drive.place(positions.get(settings.name, 0.0) * settings.counts_per_unit)
        return started

    return start


def scene_summary(scene: Scene) -> dict[str, Any]:
    """What a campaign report plots results against: the true pallet pose at the start, load and looks."""
    return {
        "pallet_type": scene.pallet.type,
        "pallet_in_fork": scene.pallet.in_fork.to_dict(),
        "loaded": scene.loaded,
        **dataclasses.asdict(scene.environment),
        "seed": scene.seed,
    }


def pick_outcome(result: PickResult, world: SimulatedWorld) -> str:
    """``collided`` (any contact), ``inserted``, ``refused`` (the pick ended on a refusal, :attr:`PickResult.refused`,
    or an unsafe plan) or ``faulted`` (drive fault, lost frame, timeout, the pallet moving after alignment)."""
    if world.min_clearance < 0:
        return "collided"
    if result.ok:
        return "inserted"
    unsafe = result.plan is not None and not result.plan.safe and (result.reason or "").startswith("planning")
    return "refused" if unsafe or result.refused else "faulted"


def world_clock(config: Config) -> Clock:
    """A simulated clock when every drive is simulated in this process on python-can's virtual bus
    (``plugins.drives: drivers.sim.drive:start_simulated_drives``, ``bus.interface: virtual``), else
    the wall clock: real drives in the loop, or drives in other processes, keep real time."""
    bus = config.sections["bus"] or {}
    simulated = drive_starter(config) is start_simulated_drives and bus.get("interface") == "virtual"
    return SimulatedClock() if simulated else WallClock()


def pick_summary(result: PickResult, world: SimulatedWorld) -> dict[str, Any]:
    """One pick's outcome. ``cycle_s`` is the truck's cycle: on a simulated clock the simulated seconds
    plus the vision's compute time (measured, as a camera frame takes no rendering), on the wall clock
    the seconds the pick took. ``wall_s`` is what it took here, rendering included."""
    final = world.scene_now().pallet.in_fork.to_dict()
    cycle = sum(result.durations.values())
    if not world.clock.realtime:
        cycle += sum(m.timing_ms.get("total", 0.0) for m in result.measurements) / 1e3
    return {
        "ok": result.ok,
        "outcome": pick_outcome(result, world),
        "state": result.state,
        "reason": result.reason,
        "collision": world.min_clearance < 0,
        "min_clearance_mm": world.min_clearance * 1e3 if math.isfinite(world.min_clearance) else None,
        "min_support_clearance_mm": (world.min_support_clearance * 1e3 if math.isfinite(world.min_support_clearance)
                                     else None),
        "cycle_s": cycle,
        "wall_s": sum(result.wall_durations.values()),
        "viewing_moves": len(result.views),
        "viewing_reasons": list(result.views),
        "withdrawals": len(result.withdrawals),
        "confirmations": len(result.confirmations),
        "exposure_changes": len(result.exposures),
        "durations_s": result.durations,
        "measured": [m.pallet_in_fork.to_dict() for m in result.measurements],
        "uncertainty": [uncertainty_json(m) for m in result.measurements],
        "truth": [t.to_dict() for t in world.measured_truths[: len(result.measurements)]],
        "scene": scene_summary(world.scene),
        "pallet_in_fork_at_end": final,
    }


def _pick(
    config: Config, plots: Path | None, base: Scene, seed: int, random: bool, pallet_types: tuple[str, ...], index: int
) -> dict[str, Any]:
    """Pick ``index`` of a campaign in a world of its own, summarised by :func:`pick_summary`; its plots in
    ``plots``/pick-NNN when ``plots`` is given. ``random``: the scene is :func:`campaign_scene` (its pallet drawn
    from ``pallet_types``, where given), else ``base``."""
    scene = campaign_scene(base, seed, index, config.forks, pallet_types) if random else base
    try:
        clock = world_clock(config)  # the bus's, for the log's CAN tap too
        with (
            pick_log(config, scene, f"simulate-pick-{index:03d}", clock) as log,
            SimulatedWorld(config, scene, clock) as world,
        ):
            result = world.controller(recorder=log).run()
            summary = {**pick_summary(result, world), "log": str(log.path)}
        if plots is not None:
            summary["plots"] = world.plots(result, plots / f"pick-{index:03d}")
        return summary
    except (MeasurementError, DriveFault) as exc:  # the world could not be set up: no pick was tried
        return {
            "ok": False,
            "outcome": "refused" if isinstance(exc, MeasurementError) else "faulted",
            "reason": f"setting up the simulated world: {exc}",
            "collision": False,
            "min_clearance_mm": None,
            "scene": scene_summary(scene),
        }


def run_command(config: Config, *, plots: str | None = None, progress: bool = True) -> dict[str, Any]:
    """``agf run`` on the simulated world: one pick of the scene ``simulation.scene`` names."""
    scene_path = repo_path((config.sections.get("simulation") or {}).get("scene", "configs/scenes/pick.yaml"))
    scene = load_scene(scene_path)
    say = (lambda state: print(f"agf run: {state}", flush=True)) if progress else None
    with pick_log(config, scene, "run") as log, SimulatedWorld(config, scene, clock=WallClock()) as world:
        result = world.controller(say, log).run()
        summary = {**pick_summary(result, world), "log": str(log.path)}
    if plots:
        summary["plots"] = world.plots(result, Path(plots))
    return summary


def random_scene(rng: np.random.Generator, base: Scene, forks: ForkGeometry = FORKS) -> Scene:
    """A random pick of ``base``'s pallet type: pitch -5..5 deg, fork heights of the paper and more, loaded or not
    (a load :func:`load_footprint` long and wide), yaw +-3 deg, stand-off 150..400 mm, and a random look (textures,
    lights, sensor) drawn from its seed. A look whose truck bed or dock would hold the tips of the tines (``forks``)
    is drawn again from the next seed: the slab reaches up to 0.35 m before the pallet's face, and with the pallet
    above the forks 10 % of the scenes started with the tines inside it (campaign seed 7: 30 of its first 300
    picks)."""
    pose = Transform.from_euler(
        rng.uniform(0.15, 0.4),
        rng.uniform(-0.03, 0.03),
        rng.uniform(-0.3, 0.45),
        0.0,
        math.radians(rng.uniform(-5, 5)),
        math.radians(rng.uniform(-3, 3)),
    )
    load = Load((*load_footprint(base.pallet.type), float(rng.uniform(0.5, 1.0)))) if rng.random() < 0.5 else None
    environment = Environment(
        floor=str(rng.choice(["floor", "truck-bed"])),
        clutter_verticals=int(rng.integers(0, 8)),
        light=float(rng.uniform(0.6, 1.3)),
        neighbours=int(rng.integers(0, 3)),
    )
    scene = dataclasses.replace(
        base,
        pallet=PalletPlacement(base.pallet.type, pose),
        load=load,
        environment=environment,
        seed=int(rng.integers(0, 2**31)),
        look="random",
    )
    while support_gap(scene, forks) < SUPPORT_GAP:
        scene = dataclasses.replace(scene, seed=int(rng.integers(0, 2**31)))
    return scene


def support_gap(scene: Scene, forks: ForkGeometry) -> float:
    """How far (m) the tips of the tines at the scene's fork pose are from the slab its pallet stands on
    (:func:`drivers.sim.render.support_box`); negative inside it."""
    tips = forks.tip_corners()
    slab = support_box(catalogued(scene.pallet.type), draw_look(scene) if scene.look == "random" else None)
    return float(signed_distances(scene.pallet.in_fork.inverse().apply(tips), slab[None]).min())


def load_footprint(pallet: str) -> tuple[float, float]:
    """The length and width (m) of a random pick's load on a ``pallet`` of the catalogue: 50 mm inside its sides
    and back, as cartons are stacked (1.0 x 1.0 m on the paper's JIS T11 pallet, 1100 x 1100 mm)."""
    kind = catalogued(pallet)
    return round(kind.length - 2 * LOAD_INSET, 6), round(kind.width - 2 * LOAD_INSET, 6)


def campaign_scene(
    base: Scene, seed: int, index: int, forks: ForkGeometry = FORKS, pallet_types: Sequence[str] = ()
) -> Scene:
    """Pick ``index`` of the random campaign ``seed``, drawn from a generator of its own: any pick can be
    run alone and gives the scene it has inside the whole campaign, with ``forks`` (the configured ones).

    ``pallet_types``: catalogue names the pick's pallet is drawn from, uniformly, by a generator of its own, so that
    the rest of the scene is drawn as with the pallet of ``base`` (empty: ``base``'s pallet).
    """
    if pallet_types:
        kind = pallet_types[int(np.random.default_rng([seed, index, _TYPE_STREAM]).integers(len(pallet_types)))]
        base = dataclasses.replace(base, pallet=PalletPlacement(kind, base.pallet.in_fork))
    return random_scene(np.random.default_rng([seed, index]), base, forks)


def simulate_command(
    config: Config,
    *,
    scene: Path | None,
    runs: int | None,
    seed: int,
    plots: str | None = None,
    jobs: int | None = None,
    backend: str = "pool",
    address: str | None = None,
    out: str | None = None,
    resume: bool = False,
    indices: Sequence[int] | None = None,
    progress: bool = True,
    pallet_types: Sequence[str] = (),
) -> dict[str, Any]:
    """``agf simulate``: whole picks in the simulated world, run as a campaign
    (:func:`drivers.sim.campaign.run_campaign`: results streamed to ``out``, resumable, on a process pool
    or Ray). ``indices`` runs those picks of the campaign only (default: all ``runs``); ``pallet_types`` the
    catalogue's pallets a random pick's is drawn from (default: the base scene's)."""
    base = load_scene(scene or repo_path("configs/scenes/pick.yaml"))
    types = tuple(pallet_types)
    pick = functools.partial(_pick, config, Path(plots) if plots else None, base, seed, runs is not None, types)
    identity = {"scene": str(scene) if scene else None, "random": runs, "seed": seed if runs else None}
    if types:  # absent otherwise, so that campaigns written before the option resume as they were
        identity["pallet_types"] = list(types)
    summary = run_campaign(
        pick,
        list(range(runs or 1)) if indices is None else list(indices),
        identity,
        out=Path(out) if out else None,
        backend=make_backend(backend, jobs=jobs, address=address),
        resume=resume,
        progress=progress,
    )
    return {**({"plots": plots} if plots else {}), **summary}
