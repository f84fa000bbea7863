"""The fault matrix in the simulated world (issue 18), and ``agf bench``'s ``faults.reaction_ms``.

Each fault is injected into one pick of the default scene (``configs/scenes/pick.yaml``) while the
forks move: :class:`FaultPick` is a :class:`drivers.sim.world.SimulatedWorld` with its real drives,
CAN bus, controller, planner and measurement, and a :class:`drivers.lossy_bus.LossyBus` between the
master and the drives. Only the frames are not rendered live: the frame at the start pose and the
frame at the pose the plan aligns to are rendered once (:func:`pick_frames`) and replayed through
the camera source a truck uses for logged picks (:class:`drivers.camera_source.Folder`), so a pick
costs its motion and two measurements, not two 20 s renders.

The reaction time is measured on the simulated drives themselves (their own velocity, sampled every
2 ms): from the moment the fault is injected to the moment every axis is at rest for good.
``tests/integration/test_faults.py`` asserts each row; this bench prints the figures that
``docs/reliability.md`` lists.
"""

from __future__ import annotations

import hashlib
import re
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from agf.bench import bench_case
from agf.config import load_config
from agf.controller import PickResult
from agf.frames import Frame
from agf.geometry import Transform
from agf.paths import DEFAULT_CONFIG, repo_path
from agf.scene import load_scene
from drivers.camera_source import Folder
from drivers.lossy_bus import LossyBus, drop, scramble, truncate
from drivers.sim.render import render
from drivers.sim.world import START, SimulatedWorld

SCENE_PATH = repo_path("configs/scenes/pick.yaml")
REST_COUNTS_S = 1.0  # a drive slower than this (counts/s: 10 um/s, 2 urad/s) is at rest
LINGER_S = 1.5  # watched after the pick ends: longer than a master-heartbeat timeout plus a stop ramp
_FRAME_INPUTS = ("configs/scenes/pick.yaml", "configs/agf.yaml", "configs/calibration.yaml", "configs/pallets.yaml",
                 "configs/cameras/thetav_front.txt", "drivers/sim/render.py", "drivers/sim/raycast.py")


BUMP = Transform.from_euler(0.0, 0.03, 0.0, 0.0, 0.0, 0.0)  # a neighbour pushed the pallet 30 mm sideways


def pick_frames(folder: Path) -> dict[str, Path]:
    """Render the default pick's frames into ``folder`` once (kept while their inputs are unchanged):
    ``start`` at the start pose, ``aligned`` at the pose its plan aligns to, ``bumped`` there too with
    the pallet moved by :data:`BUMP` since the start frame."""
    folder.mkdir(parents=True, exist_ok=True)
    files = {name: folder / f"{name}.png" for name in ("start", "aligned", "bumped")}
    key = hashlib.sha256(b"".join(repo_path(p).read_bytes() for p in _FRAME_INPUTS)).hexdigest()
    stamp = folder / "inputs.sha256"
    if stamp.is_file() and stamp.read_text() == key and all(f.is_file() for f in files.values()):
        return files
    with SimulatedWorld(load_config(DEFAULT_CONFIG), load_scene(SCENE_PATH)) as world:
        controller = world.controller()
        start, _ = render(world.scene_at(START), world.camera)
        measurement = controller.measure(Frame(start, 0.0, 1), None)
        plan = controller.planner.plan(measurement, START)
        if not plan.safe:
            raise RuntimeError(f"the default pick is refused ({plan.reason}): no frames to replay")
        aligned, _ = render(world.scene_at(plan.align), world.camera)
        world.pallet_in_truck = BUMP @ world.pallet_in_truck
        bumped, _ = render(world.scene_at(plan.align), world.camera)
    for name, image in (("start", start), ("aligned", aligned), ("bumped", bumped)):
        cv2.imwrite(str(files[name]), image)
    stamp.write_text(key)
    return files


def replay_folder(folder: Path, frames: list[Path]) -> Path:
    """A folder that replays ``frames`` in this order (numbered links), for :class:`FaultPick`."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        (folder / f"{i:03d}-{frame.name}").symlink_to(frame.resolve())
    return folder


@dataclass(frozen=True)
class Reaction:
    """How one pick met its fault.

    ``reaction_s``: injection to every drive at rest for good (None: not at rest when watching ended);
    ``moved_after_rest``: the largest drive movement after that (counts); ``state_later`` and
    ``enabled_later``: the controller's state and the drives still in OPERATION ENABLED, watched
    :data:`LINGER_S` after the pick ended (no automatic restart).
    """

    result: PickResult
    injected: bool
    reaction_s: float | None
    moved_after_rest: float
    collision: bool
    min_clearance_mm: float
    state_later: str
    enabled_later: tuple[str, ...]


class FaultPick:
    """One pick of the default scene, frames replayed from ``frames``, a :class:`LossyBus` on the master.

    A context manager; ``drives`` maps axis name to its :class:`drivers.sim.drive.SimDrive`.
    """

    def __init__(self, frames: Path, *, loss: float = 0.0, seed: int = 0) -> None:
        self.bus: LossyBus | None = None
        self._loss, self._seed = loss, seed
        self.world = SimulatedWorld(load_config(DEFAULT_CONFIG), load_scene(SCENE_PATH), bus_wrapper=self._wrap)
        self.drives = dict(zip(self.world.axes, self.world.network.sim_drives, strict=True))
        self.controller = self.world.controller()
        self.controller.frames = Folder(frames, self.world.camera.width, self.world.camera.height)

    def _wrap(self, bus: Any) -> LossyBus:
        self.bus = LossyBus(bus, loss=self._loss, seed=self._seed)
        return self.bus

    def __enter__(self) -> FaultPick:
        return self

    def __exit__(self, *exc: object) -> None:
        self.world.network.close()

    def run(self, inject: Callable[[FaultPick], None] | None = None, state: str = "aligning",
            after: float = 0.1) -> Reaction:
        """Run the pick; ``inject(self)`` once, ``after`` s into ``state`` (at its first control cycle
        from then: on a loaded machine the controller's cycles come late, the motion does not wait)."""
        samples: list[tuple[float, np.ndarray, np.ndarray]] = []
        stop = threading.Event()
        sampler = threading.Thread(target=self._sample, args=(samples, stop), daemon=True)
        counter: dict[str, float | None] = {"entered": None, "t": None}
        plain = self.controller.on_cycle

        def on_cycle(positions: Any) -> None:
            plain(positions)
            if inject is None or counter["t"] is not None or self.controller._state() != state:
                return
            now = time.monotonic()
            counter["entered"] = counter["entered"] or now
            if now - counter["entered"] >= after:
                counter["t"] = now
                sampler.start()
                inject(self)

        self.controller.on_cycle = on_cycle
        result = self.controller.run()
        injected = inject is None or counter["t"] is not None
        if counter["t"] is None:  # no fault in motion (a frame fault, or none): watch from the end
            counter["t"] = time.monotonic()
            sampler.start()
        time.sleep(LINGER_S)
        stop.set()
        sampler.join()
        state_later = self.controller._state()
        enabled = tuple(name for name, drive in self.drives.items() if drive.state == "OPERATION ENABLED")
        reaction, moved = _rest(samples, counter["t"])
        world = self.world
        return Reaction(result, injected, reaction, moved, world.min_clearance < 0,
                        world.min_clearance * 1e3, state_later, enabled)

    def _sample(self, samples: list, stop: threading.Event) -> None:
        drives = list(self.drives.values())
        while not stop.wait(0.002):
            samples.append((time.monotonic(), np.array([d.position for d in drives]),
                            np.array([d.velocity for d in drives])))


def _rest(samples: list[tuple[float, np.ndarray, np.ndarray]], start: float) -> tuple[float | None, float]:
    """When every drive came to rest for good after ``start`` (s after it), and how far any moved after."""
    if not samples:
        return None, 0.0
    moving = np.array([np.abs(v).max() >= REST_COUNTS_S for _, _, v in samples])
    if moving[-1]:
        return None, 0.0
    first = int(np.flatnonzero(moving)[-1] + 1) if moving.any() else 0
    positions = np.array([p for _, p, _ in samples[first:]])
    return samples[first][0] - start, float(np.ptp(positions, axis=0).max())


def _limit_switch_ahead(pick: FaultPick) -> None:
    drive = pick.drives["reach"]
    switch = drive.position + (500.0 if drive.velocity >= 0 else -500.0)  # 5 mm ahead of the moving reach
    drive.set_limit_switches(*sorted((switch, drive.position - 1e9 * np.sign(switch - drive.position))))


def _node(pick: FaultPick, axis: str) -> int:
    return pick.world.axes[axis].drive.node_id


# name -> (injection, state it is injected in, pattern (re.search) the FAULT reason must match); with
# 10 % of frames lost either side may notice first: the master counting missing feedback PDOs, or a
# drive missing three master heartbeats in a row (its own EMCY 0x8130, or its error code 0x603F when
# that EMCY was among the frames lost)
SCENARIOS: dict[str, tuple[Callable[[FaultPick], None], str, str]] = {
    "can_loss_10pct": (lambda pick: pick.bus.set_loss(0.10), "aligning",
                       "CAN frames lost|0x8130 master heartbeat lost"),
    "can_burst_200ms": (lambda pick: pick.bus.burst(0.2), "aligning", "feedback lost"),
    "heartbeats_lost": (lambda pick: pick.bus.mangle(drop(0x700 + _node(pick, "reach"))), "aligning",
                        "CAN frames lost: no heartbeat"),
    "tpdo_wrong_length": (lambda pick: pick.bus.mangle(truncate(0x180 + _node(pick, "reach"), 3)), "aligning",
                          "rejected for their length"),
    "tpdo_garbled": (lambda pick: pick.bus.mangle(scramble(0x180 + _node(pick, "reach"))), "aligning",
                     "an impossible position"),
    "can_bus_gone": (lambda pick: pick.bus.unplug(), "aligning", "CAN bus gone"),
    "drive_reboot": (lambda pick: pick.drives["reach"].reboot(), "aligning", "rebooted"),
    "emcy_warning": (lambda pick: pick.drives["lift"].emcy(0x4210), "aligning", "EMCY 0x4210"),
    "emcy_fault": (lambda pick: pick.drives["lift"].inject_fault(0x2310), "aligning", "over-current"),
    "following_error": (lambda pick: pick.drives["reach"].set_load(3000), "inserting", "following error"),
    "limit_switch": (_limit_switch_ahead, "inserting", "limit switch"),
}


def run_scenario(frames: Path, name: str) -> Reaction:
    """One pick with the fault ``name`` of :data:`SCENARIOS` injected; ``frames`` a :func:`replay_folder`."""
    inject, state, _ = SCENARIOS[name]
    with FaultPick(frames) as pick:
        return pick.run(inject, state)


@bench_case("faults.reaction_ms", "control")
def reaction_ms(quick: bool) -> dict[str, Any]:
    """Fault injected mid-motion -> every simulated drive at rest, ms, per row of the fault matrix."""
    rendered = pick_frames(Path(tempfile.gettempdir()) / "agf-fault-frames")
    figures: dict[str, Any] = {}
    for name in SCENARIOS:
        try:
            times = [_reaction_ms(rendered, name) for _ in range(1 if quick else 3)]
        except RuntimeError as exc:  # this row's figure cannot be trusted; the others still can
            figures[name] = {"error": str(exc)}
            continue
        figures[name] = {"median": statistics.median(times), "max": max(times), "n": len(times)}
    return figures


def _reaction_ms(rendered: dict[str, Path], name: str) -> float:
    pattern = SCENARIOS[name][2]
    with tempfile.TemporaryDirectory() as folder:
        reaction = run_scenario(replay_folder(Path(folder), [rendered["start"], rendered["aligned"]]), name)
    if reaction.result.state != "fault" or not re.search(pattern, reaction.result.reason or ""):
        raise RuntimeError(f"{name}: expected a FAULT matching {pattern!r}, got {reaction.result.reason!r}"
                           f"{'' if reaction.injected else ' (not injected: the motion ended first)'}")
    if reaction.reaction_s is None or reaction.moved_after_rest > 10 or reaction.collision:
        raise RuntimeError(f"{name}: the axes did not come to rest for good ({reaction})")
    return reaction.reaction_s * 1e3
