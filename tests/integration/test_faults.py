"""The fault matrix (issue 18): each fault injected while the forks move in the simulated world.

Every FAULT row asserts the same outcome: the state machine ends in FAULT with a reason naming the
fault, every simulated drive comes to rest (measured on the drives themselves) and never moves
again, no drive is left in OPERATION ENABLED, the controller stays in FAULT (no automatic restart)
and the forks never touch the pallet. Rows where a real truck goes on (1 % frame loss, foreign
frames, one bad camera frame, one lost SDO answer) assert that it does, and how it says so.

Picks replay two frames rendered once per machine (drivers/sim/fault_bench.pick_frames) through the
camera source of logged picks, so each costs its motion and two measurements, not two renders.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from agf.errors import DriveFault
from drivers.can_bus import open_bus
from drivers.cia402_axis import DEFAULT_EDS, Cia402Network, DriveSettings, NetworkSettings
from drivers.lossy_bus import drop, flood
from drivers.sim.drive import SimDrive
from drivers.sim.fault_bench import SCENARIOS, FaultPick, Reaction, pick_frames, replay_folder, run_scenario
from tests.integration.test_drives import LIMITS, SCALE, wait_until

# one pytest-xdist worker runs them all: its session fixture renders the pick's frames into pytest's cache once
pytestmark = pytest.mark.xdist_group("test_faults")


@pytest.fixture(scope="session")
def rendered(request) -> dict[str, Path]:
    """``start``, ``aligned`` and ``bumped`` frames, rendered once and kept in pytest's cache."""
    return pick_frames(Path(request.config.cache.mkdir("agf-fault-frames")))


@pytest.fixture
def pick_folder(rendered, tmp_path) -> Path:
    """The frames of an undisturbed pick: start, then aligned."""
    return replay_folder(tmp_path / "frames", [rendered["start"], rendered["aligned"]])


def assert_fault_at_rest(reaction: Reaction, pattern: str) -> None:
    assert reaction.injected, "the fault was never injected (the motion ended first)"
    result = reaction.result
    assert result.state == "fault" and re.search(pattern, result.reason or ""), result.reason
    assert reaction.reaction_s is not None, "an axis was still moving when watching ended"
    assert reaction.moved_after_rest < 10, f"moved {reaction.moved_after_rest} counts after coming to rest"
    assert reaction.state_later == "fault", "left FAULT without a reset"
    assert reaction.enabled_later == (), f"{reaction.enabled_later} still in OPERATION ENABLED"
    assert not reaction.collision and reaction.min_clearance_mm > 0


# -- faults that end the pick ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_fault_mid_motion(pick_folder: Path, name: str) -> None:
    """can_loss_10pct, can_burst_200ms, heartbeats_lost, tpdo_wrong_length, tpdo_garbled, can_bus_gone,
    drive_reboot, emcy_warning, emcy_fault (while aligning), following_error, limit_switch (while inserting)."""
    reaction = run_scenario(pick_folder, name)
    assert_fault_at_rest(reaction, SCENARIOS[name][2])
    if SCENARIOS[name][1] == "inserting":
        assert reaction.result.durations.get("inserting", 0) > 0


def test_drive_fault_whose_emcy_was_lost_is_named_by_its_error_code(pick_folder: Path) -> None:
    """A drive faults and its EMCY never arrives (lost, as 10 % frame loss did in CI on 3dbd68e): the
    reason still says why, from the error code (0x603F) its feedback PDO carries, not just "fault state"."""

    def inject(pick: FaultPick) -> None:
        pick.bus.mangle(drop(0x80 + pick.world.axes["lift"].drive.node_id))
        pick.drives["lift"].inject_fault(0x2310)

    with FaultPick(pick_folder) as pick:
        reaction = pick.run(inject, "aligning")
    assert_fault_at_rest(reaction, "drive fault on lift: .*error code 0x2310 continuous over-current")


def _bad_frame(kind: str, aligned: Path, folder: Path) -> Path:
    image = cv2.imread(str(aligned))
    path = folder / f"bad-{kind}.png"
    if kind == "black":
        cv2.imwrite(str(path), np.zeros_like(image))
    elif kind == "saturated":
        cv2.imwrite(str(path), np.full_like(image, 255))
    elif kind == "wrong_size":
        cv2.imwrite(str(path), image[: image.shape[0] // 2])
    else:  # a JPEG whose transfer stopped half-way
        path = path.with_suffix(".jpg")
        data = cv2.imencode(".jpg", image)[1].tobytes()
        path.write_bytes(data[: len(data) // 2])
    return path


CAMERA_FAULTS = {"timeout": "no frame within", "black": "black frame", "saturated": "saturated frame",
                 "truncated_jpeg": "truncated JPEG", "wrong_size": "expected 1920 x 1920"}


@pytest.mark.parametrize("kind", list(CAMERA_FAULTS))
def test_camera_fault_at_verification(rendered, tmp_path: Path, kind: str) -> None:
    """Every read of the verification frame fails the same way: refused before measuring, FAULT."""
    frames = [rendered["start"]]
    if kind != "timeout":  # timeout: the replay has no frame left, as a camera that stopped sending
        frames += [_bad_frame(kind, rendered["aligned"], tmp_path)] * 3
    with FaultPick(replay_folder(tmp_path / "frames", frames)) as pick:
        reaction = pick.run()
    assert_fault_at_rest(reaction, CAMERA_FAULTS[kind])
    assert reaction.result.reason.startswith("verifying:") and len(reaction.result.measurements) == 1


# -- faults a truck rides through ------------------------------------------------------------------------


def test_one_percent_frame_loss_is_ridden_through(pick_folder: Path, caplog) -> None:
    """1 % of all frames lost, both ways, from start-up (SDO) to the end of the insertion."""
    with FaultPick(pick_folder, loss=0.01, seed=5) as pick:
        reaction = pick.run()
        lost = pick.bus.lost
    assert reaction.result.ok, reaction.result.reason
    assert lost > 10 and not reaction.collision


def test_foreign_and_malformed_frames_are_ignored(pick_folder: Path, caplog) -> None:
    """200 frames from COB-IDs no node uses, and three malformed feedback PDOs mid-motion: two of the
    wrong length and one of the right length whose position is 1.5e9 counts off (the CI failure of
    2026-11-25: that frame reached the log as a 15.7 km jump of the reach). (A flood long enough to
    keep the drives' frames off a real bus is lost feedback: the rows can_burst_200ms and can_loss_10pct.)"""

    def inject(pick: FaultPick) -> None:
        node = pick.world.axes["reach"].drive.node_id
        pick.bus.inject(flood(range(0x10, 0x80), 200) + flood([0x180 + node], 3, seed=1))

    with FaultPick(pick_folder) as pick:
        reaction = pick.run(inject)
        rejected = pick.world.axes["reach"]._rejected
    assert reaction.result.ok, reaction.result.reason
    assert rejected == 3 and "rejected" in caplog.text
    log = reaction.result.log
    reach, t = np.array([row["actual"]["reach"] for row in log]), np.array([row["t"] for row in log])
    limits = pick.world.axes["reach"].limits
    # No jump from a bad value. The feedback a log row holds may be up to a few cycles old when the
    # machine is busy, so each step is allowed at least 0.1 s of travel at full speed (25 mm here); a
    # malformed PDO read as a position would jump by far more, or leave the stroke.
    steps = np.abs(np.diff(reach))
    assert np.all(steps <= 1.2 * limits.max_velocity * np.maximum(np.diff(t), 0.1) + 1e-3), steps.max()
    assert np.all((reach >= limits.minimum - 1e-3) & (reach <= limits.maximum + 1e-3))


def test_one_bad_camera_frame_is_read_again(rendered, tmp_path: Path, caplog) -> None:
    frames = [rendered["start"], _bad_frame("truncated_jpeg", rendered["aligned"], tmp_path), rendered["aligned"]]
    with FaultPick(replay_folder(tmp_path / "frames", frames)) as pick:
        with caplog.at_level(logging.WARNING, logger="agf.controller"):
            reaction = pick.run()
    assert reaction.result.ok, reaction.result.reason
    assert "truncated JPEG" in caplog.text and "reading again, 2 of 3" in caplog.text


def test_pallet_bumped_after_measuring_is_caught_before_inserting(rendered, tmp_path: Path) -> None:
    """A neighbour pushes the pallet 30 mm sideways while the forks align: the verification frame
    shows it, the pick re-plans from there (or refuses), and never inserts on the old plan."""
    from drivers.sim.fault_bench import BUMP

    frames = replay_folder(tmp_path / "frames", [rendered["start"], rendered["bumped"], rendered["bumped"]])
    with FaultPick(frames) as pick:
        world = pick.world
        reaction = pick.run(lambda p: setattr(world, "pallet_in_truck", BUMP @ world.pallet_in_truck))
    result = reaction.result
    assert reaction.injected and len(result.measurements) >= 3, "inserted without re-planning"
    shift = result.measurements[1].pallet_in_fork.translation[1] - result.measurements[0].pallet_in_fork.translation[1]
    assert shift == pytest.approx(0.03, abs=0.005)  # the verification measured the bump
    assert not reaction.collision
    assert result.ok or "refused" in result.reason, result.reason


# -- start-up: SDO faults while configuring (before any motion: the axes hold) ---------------------------


@pytest.fixture
def lone_drive(request):
    bus = {"interface": "virtual", "channel": f"faults-sdo-{os.getpid()}-{request.node.name}"}
    drive = SimDrive.open(5, open_bus(bus, "test"))
    net = Cia402Network(open_bus(bus, "test"), NetworkSettings())
    yield drive, net
    net.close()
    drive.close()


def _add_axis(net: Cia402Network):
    return net.add_axis(DriveSettings("lift", 5, DEFAULT_EDS, SCALE, LIMITS, 0.05), timeout=1.0)


def test_one_lost_sdo_answer_is_retried(lone_drive, caplog) -> None:
    drive, net = lone_drive
    drive.fail_sdo(0x6083, "timeout", times=1)
    with caplog.at_level(logging.WARNING):
        axis = _add_axis(net)
    assert "No SDO response received" in caplog.text  # canopen's line for the retry
    assert axis.node.sdo[0x6083].raw == round(LIMITS.max_acceleration * SCALE)


@pytest.mark.parametrize("kind, words", [("timeout", "SDO timeout"), ("abort", "SDO abort 0x08000020")])
def test_sdo_fault_at_startup_names_the_object(lone_drive, kind: str, words: str) -> None:
    drive, net = lone_drive
    drive.fail_sdo(0x6083, kind, times=10)
    with pytest.raises(DriveFault, match=rf"axis lift \(node 5\): start-up failed at writing 0x6083:0: {words}"):
        _add_axis(net)
    assert drive.state == "SWITCH ON DISABLED" and drive.velocity == 0.0  # held, never enabled


def test_drive_rebooted_between_picks_must_be_configured_again(lone_drive) -> None:
    """A reboot while enabled: the drive is back in PRE-OPERATIONAL with default objects; the master
    says so at once (boot-up message), not 2.5 heartbeat periods later."""
    drive, net = lone_drive
    axis = _add_axis(net)
    net.start()
    axis.enable()
    drive.reboot()
    assert wait_until(lambda: axis.feedback().fault is not None)
    assert "rebooted" in axis.feedback().fault
    assert drive.node.nmt.state == "PRE-OPERATIONAL" and drive._param(0x1017) == 0


def test_bad_frame_files_are_refused_by_the_folder_source(rendered, tmp_path: Path) -> None:
    from agf.frames import FrameLost
    from drivers.camera_source import Folder

    shutil.copy(rendered["aligned"], tmp_path / "b.png")
    _bad_frame("truncated_jpeg", rendered["aligned"], tmp_path).rename(tmp_path / "a.jpg")
    source = Folder(tmp_path, 1920, 1920)
    with pytest.raises(FrameLost, match="a.jpg: truncated JPEG"):
        source.read()
    assert source.read().index == 1  # the next file, not the bad one again
