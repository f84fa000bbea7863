"""Whole picks in the simulated world: simulated CiA 402 drives on python-can's virtual bus, frames
rendered through the camera model for the forks' actual position, collisions checked every cycle."""

from __future__ import annotations

import math

import cv2
import pytest

from agf.axis import AxisState
from agf.config import load_config
from agf.paths import DEFAULT_CONFIG, repo_path
from agf.scene import load_scene
from drivers.sim.world import SimulatedWorld, pick_summary, simulate_command

CONFIG = load_config(DEFAULT_CONFIG)
SCENE = load_scene(repo_path("configs/scenes/pick.yaml"))


def run_with(inject=None, when_state="aligning", after_cycles=20):
    """One pick; ``inject(world)`` runs once, ``after_cycles`` control cycles into ``when_state``."""
    with SimulatedWorld(CONFIG, SCENE) as world:
        controller = world.controller()
        cycles = {"n": 0}
        plain = controller.on_cycle

        def on_cycle(positions):
            plain(positions)
            if inject is not None and controller._state() == when_state:
                cycles["n"] += 1
                if cycles["n"] == after_cycles:
                    inject(world)

        controller.on_cycle = on_cycle
        result = controller.run()
        summary = pick_summary(result, world)
        world.clock.sleep(1.0)  # the quick-stop ramp
        before = world.positions()
        world.clock.sleep(0.5)
        after = world.positions()
        states = {name: axis.feedback().state for name, axis in world.axes.items()}
    return result, summary, before, after, states


def test_a_pick_inserts_without_collision():
    result, summary, *_ = run_with()
    assert result.ok, result.reason
    assert not summary["collision"] and summary["min_clearance_mm"] > 5
    end = summary["pallet_in_fork_at_end"]
    assert end["x_mm"] == pytest.approx(-600, abs=10)  # inserted to the configured depth
    assert abs(end["z_mm"]) < 5 and abs(end["pitch_deg"]) < 0.1
    # each measurement's stated uncertainty, in the units and order of its pose, for the campaign report
    assert summary["uncertainty"] == [
        {"z_mm": pytest.approx(m.sigma_z * 1e3), "pitch_deg": pytest.approx(math.degrees(m.sigma_pitch))}
        for m in result.measurements
    ] and len(summary["uncertainty"]) == len(summary["measured"]) >= 2


def assert_stopped(result, before, after, states, reason):
    assert result.state == "fault" and reason in result.reason
    assert all(abs(after[n] - before[n]) < 1e-4 for n in before)  # no further motion
    assert not any(s is AxisState.ENABLED for s in states.values())


def test_drive_fault_mid_motion_ends_in_quick_stop_with_its_name():
    result, _, before, after, states = run_with(lambda world: world.network.sim_drives[1].inject_fault(0x4310))
    assert_stopped(result, before, after, states, "drive fault on reach")
    assert "over-temperature" in result.reason


def test_lost_drive_heartbeat_mid_motion_ends_in_quick_stop():
    result, _, before, after, states = run_with(lambda world: world.network.sim_drives[0].go_silent())
    assert result.state == "fault" and "heartbeat" in result.reason


def test_lost_frame_ends_in_quick_stop_with_the_reason():
    def lose(world):
        world.frames_lost = 3  # every read of the verify frame (one lost frame is read again)

    result, _, before, after, states = run_with(lose)
    assert_stopped(result, before, after, states, "no frame")


def test_operator_stop_mid_motion():
    with SimulatedWorld(CONFIG, SCENE) as world:
        controller = world.controller()
        plain = controller.on_cycle

        def on_cycle(positions):
            plain(positions)
            if controller._state() == "inserting":
                controller.stop("operator stop button")

        controller.on_cycle = on_cycle
        result = controller.run()
        assert result.state == "fault" and "operator stop button" in result.reason
        assert math.isfinite(world.min_clearance)
        controller.reset()  # only an explicit reset leaves FAULT
        assert controller._state() == "idle"


def test_simulate_runs_picks_side_by_side_each_on_its_own_bus(capsys, tmp_path):
    report = simulate_command(CONFIG, scene=None, runs=2, seed=3, jobs=2, plots=str(tmp_path))
    assert report["runs"] == 2 and report["collisions"] == 0
    assert report["inserted"] + len(report["failures"]) == 2
    assert all(f["reason"] for f in report["failures"])  # a refusal always says why
    assert "2/2 picks" in capsys.readouterr().err
    refused = {f["run"] for f in report["failures"]}
    for run in set(range(2)) - refused:  # an inserted pick moved: both of its plots are written
        side = cv2.imread(str(tmp_path / f"pick-{run:03d}" / "fork_path_side.png"))
        assert side is not None and (tmp_path / f"pick-{run:03d}" / "pick_axes.png").is_file()
        green_path = (side[..., 1] > 120) & (side[..., 0] < 40) & (side[..., 2] < 40)
        assert green_path.sum() > 100  # the tip's path, with clearance to spare


def test_tines_driven_into_the_slab_the_pallet_stands_on_are_a_collision():
    """The world counts contact with the truck bed or dock under the pallet as it counts contact with the pallet:
    a control cycle with the tines' tips 50 mm before the pallet's face and 100 mm below its underside (inside the
    slab, which reaches 0.12 m before the face in the fixed look) is a collision, while the pallet is not touched."""
    from agf.geometry import Transform
    from agf.kinematics import axes_from_fork_in_truck

    with SimulatedWorld(CONFIG, SCENE) as world:
        world.on_cycle(world.positions())
        assert world.min_support_clearance > 0 and world.min_clearance > 0
        into = Transform(translation=[-0.05, 0.0, world.pallet.deck_bottom - 0.1])
        world.on_cycle(axes_from_fork_in_truck(world.pallet_in_truck @ into, world.mast))
        assert world.clearances[-1] > 0  # the pallet itself is clear
        assert world.min_support_clearance < -0.05 and world.min_clearance == world.min_support_clearance
        summary = pick_summary(world.controller().run(), world)
    assert summary["collision"] and summary["outcome"] == "collided" and summary["min_support_clearance_mm"] < -50
