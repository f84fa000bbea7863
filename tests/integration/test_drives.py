"""CiA 402 axes against simulated drives: our driver, a third-party master, every fault, real EDS files.

Everything runs on python-can's in-process virtual bus (one channel per test), except the
udp_multicast test (three drives in separate processes) and the socketcan test (vcan0), which are
skipped with the reason where the machine cannot run them. Waits poll with generous timeouts; no
assertion depends on timing.
"""

from __future__ import annotations

import itertools
import math
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import canopen
import pytest

from agf.axis import AxisLimits, AxisState
from agf.errors import ConfigError, DriveFault
from drivers.can_bus import open_bus
from drivers.cia402_axis import (
    DEFAULT_EDS,
    Cia402Axis,
    Cia402Network,
    DriveSettings,
    NetworkSettings,
    axes_from_config,
    emcy_name,
    load_object_dictionary,
)
from drivers.lossy_bus import LossyBus
from drivers.sim.drive import SimDrive, start_simulated_drives

REPO = Path(__file__).resolve().parents[2]
REAL_EDS = REPO.parent / "shared" / "data" / "eds"
SCALE = 100_000.0  # counts per metre
LIMITS = AxisLimits(0.0, 3.0, 0.5, 1.0, 5.0)
_channels = itertools.count()


def wait_until(predicate: Callable[[], bool], timeout: float = 3.0) -> bool:
    """Poll ``predicate`` until true or ``timeout`` s; returns its last value."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return predicate()
        time.sleep(0.005)
    return True


class Rig:
    """One simulated drive and our master on a fresh virtual channel."""

    def __init__(self, mode: str = "csp", eds: Path = DEFAULT_EDS, node_id: int = 3) -> None:
        self.bus = {"interface": "virtual", "channel": f"test-drives-{os.getpid()}-{next(_channels)}"}
        self.drive = SimDrive.open(node_id, open_bus(self.bus, "test"), eds=eds)
        self.net = Cia402Network(open_bus(self.bus, "test"), NetworkSettings())
        self.axis: Cia402Axis = self.net.add_axis(
            DriveSettings("lift", node_id, eds, SCALE, LIMITS, 0.05, mode))  # type: ignore[arg-type]
        self.net.start()
        self.faults: list[tuple[str, DriveFault]] = []
        self.axis.add_fault_listener(lambda name, fault: self.faults.append((name, fault)))

    def move(self, goal: float, until_fault: bool = False) -> None:
        """Stream a cosine move from the actual position to ``goal`` at 80 % of the axis limits.

        With ``until_fault`` the move ends quietly when the axis refuses a setpoint for a fault.
        """
        start = self.axis.feedback().position
        distance, limits = abs(goal - start), self.axis.limits
        seconds = max(math.pi * distance / (1.6 * limits.max_velocity),
                      math.pi * math.sqrt(distance / (1.6 * limits.max_acceleration)), 0.05)
        steps = round(seconds / self.net.settings.cycle)
        for i in range(1, steps + 1):
            try:
                self.axis.send_setpoint(start + (goal - start) * (1 - math.cos(math.pi * i / steps)) / 2)
            except DriveFault:
                if not until_fault:
                    raise
                return
            self.axis.wait_for_feedback()

    def emcy_codes(self) -> list[int]:
        return [e.code for e in self.axis.node.emcy.log]

    def close(self) -> None:
        self.net.close()
        self.drive.close()


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()


@pytest.fixture
def pp_rig() -> Iterator[Rig]:
    r = Rig(mode="pp")
    yield r
    r.close()


# -- our driver ---------------------------------------------------------------------------------------


def test_csp_enable_move_disable(rig: Rig) -> None:
    rig.axis.enable()
    assert rig.axis.feedback().state is AxisState.ENABLED
    rig.move(0.15)
    assert wait_until(lambda: abs(rig.axis.feedback().position - 0.15) < 1e-4)
    assert rig.drive.mode == 8
    rig.axis.disable()
    assert wait_until(lambda: rig.axis.feedback().state is AxisState.DISABLED)
    assert rig.drive.state == "SWITCH ON DISABLED"
    assert rig.faults == []


def test_a_placed_motor_is_where_the_master_reads_it_and_cannot_be_placed_once_enabled(rig: Rig) -> None:
    rig.axis.enable()
    with pytest.raises(RuntimeError, match="cannot place"):
        rig.drive.place(0.2 * SCALE)
    rig.axis.disable()
    assert wait_until(lambda: rig.drive.state == "SWITCH ON DISABLED")
    rig.drive.place(0.2 * SCALE)
    assert wait_until(lambda: abs(rig.axis.feedback().position - 0.2) < 1 / SCALE)
    rig.axis.enable()  # holds where it was placed: no jump, no following error
    rig.move(0.25)
    assert wait_until(lambda: abs(rig.axis.feedback().position - 0.25) < 1e-4)
    assert rig.faults == []


def test_pp_enable_move_disable(pp_rig: Rig) -> None:
    pp_rig.axis.enable()
    pp_rig.axis.send_setpoint(0.08)
    assert wait_until(lambda: abs(pp_rig.axis.feedback().position - 0.08) < 1e-4)
    assert pp_rig.drive.mode == 1
    pp_rig.axis.disable()
    assert wait_until(lambda: pp_rig.axis.feedback().state is AxisState.DISABLED)


def test_setpoint_outside_limits_is_refused_before_sending(rig: Rig) -> None:
    rig.axis.enable()
    with pytest.raises(DriveFault, match="software limits"):
        rig.axis.send_setpoint(3.5)
    assert rig.drive._target == 0


def test_drive_limits_written_at_startup(rig: Rig) -> None:
    sdo = rig.axis.node.sdo
    assert sdo[0x607D][2].raw == 300_000
    assert sdo[0x607F].raw == 50_000
    assert sdo[0x1016][1].raw >> 16 == rig.net.settings.master_node_id


def test_quick_stop_then_reenable(rig: Rig) -> None:
    rig.axis.enable()
    rig.move(0.05)
    rig.axis.quick_stop()
    assert wait_until(lambda: rig.axis.feedback().state is AxisState.QUICK_STOP)
    assert wait_until(lambda: rig.drive.velocity == 0.0)
    rig.axis.enable()
    assert rig.axis.feedback().state is AxisState.ENABLED


def test_missing_drive_is_a_named_startup_fault() -> None:
    net = Cia402Network(open_bus({"interface": "virtual", "channel": f"empty-{os.getpid()}"}, "test"),
                        NetworkSettings())
    try:
        with pytest.raises(DriveFault, match=r"axis lift \(node 12\): start-up failed"):
            net.add_axis(DriveSettings("lift", 12, DEFAULT_EDS, SCALE, LIMITS, 0.05), timeout=0.5)
    finally:
        net.close()


class _FirstNmtStartLost(LossyBus):
    """The master's first NMT start command never reaches the bus (CAN has no acknowledge for it)."""

    lost_start = False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == 0 and msg.data[0] == 0x01 and not self.lost_start:
            self.lost_start = True
            return
        super().send(msg, timeout)


def test_lost_nmt_start_is_sent_again() -> None:
    """Regression: one lost NMT start left a drive PRE-OPERATIONAL, so enabling found no statusword
    (the fault matrix's 1 % loss pick failed at start-up)."""
    bus = {"interface": "virtual", "channel": f"nmt-start-{os.getpid()}"}
    drive = SimDrive.open(3, open_bus(bus, "test"), eds=DEFAULT_EDS)
    master = _FirstNmtStartLost(open_bus(bus, "test"))
    net = Cia402Network(master, NetworkSettings())
    try:
        axis = net.add_axis(DriveSettings("lift", 3, DEFAULT_EDS, SCALE, LIMITS, 0.05))
        net.start()
        axis.enable()
        assert master.lost_start and drive.node.nmt.state == "OPERATIONAL"
        assert axis.feedback().state is AxisState.ENABLED
    finally:
        net.close()
        drive.close()


def test_orderly_close_leaves_the_drive_disabled_not_faulted() -> None:
    rig = Rig()
    try:
        rig.axis.enable()
        rig.net.close()
        time.sleep(4 * rig.net.settings.heartbeat)  # longer than the drive's master-heartbeat timeout
        assert rig.drive.state == "SWITCH ON DISABLED" and rig.drive.error_code == 0
    finally:
        rig.drive.close()


# -- a third-party master: canopen's BaseNode402 used directly ------------------------------------------


@pytest.mark.parametrize("mode", ["PROFILED POSITION", "CYCLIC SYNCHRONOUS POSITION"])
def test_third_party_master_moves_the_simulated_drive(mode: str) -> None:
    channel = {"interface": "virtual", "channel": f"third-party-{os.getpid()}-{next(_channels)}"}
    drive = SimDrive.open(9, open_bus(channel, "test"))
    network = canopen.Network(can.Bus(**channel))
    network.connect()
    try:
        node = canopen.BaseNode402(9, str(DEFAULT_EDS))
        network.add_node(node)
        node.nmt.state = "PRE-OPERATIONAL"
        node.sdo[0x1017].raw = 100
        node.setup_402_state_machine()  # reads the EDS-default PDO mapping over SDO
        network.sync.start(0.01)
        node.rpdo[1].start(0.01)  # the controlword lives in a synchronous RPDO: send it every cycle
        node.nmt.state = "OPERATIONAL"
        node.op_mode = mode
        assert node.op_mode == mode
        node.rpdo[1][0x607A].raw = node.tpdo_values[0x6064]
        node.state = "OPERATION ENABLED"
        assert node.state == "OPERATION ENABLED"
        if mode == "PROFILED POSITION":
            node.rpdo[1][0x607A].raw = 4000
            node.controlword = 0x3F  # new set-point, change immediately
            assert wait_until(lambda: node.statusword & 0x1000)
            node.controlword = 0x0F
        else:
            for i in range(1, 61):
                node.rpdo[1][0x607A].raw = round(2000 * (1 - math.cos(math.pi * i / 60)))
                node.tpdo[1].wait_for_reception(1.0)
        assert wait_until(lambda: abs(node.tpdo_values[0x6064] - 4000) <= 1)
        assert wait_until(lambda: node.statusword & 0x0400)  # target reached
        node.state = "SWITCH ON DISABLED"
        assert drive.state == "SWITCH ON DISABLED"
    finally:
        network.sync.stop()
        network.disconnect()
        drive.close()


# -- faults: EMCY, the drive's FAULT state, a named DriveFault on our side, reset ------------------------


def _assert_fault(rig: Rig, code: int, name: str) -> None:
    assert wait_until(lambda: code in rig.emcy_codes()), rig.emcy_codes()
    assert wait_until(lambda: rig.drive.state == "FAULT"), rig.drive.state
    assert wait_until(lambda: rig.faults), "no fault reported"
    axis_name, fault = rig.faults[0]
    assert axis_name == "lift" and name in str(fault)
    assert rig.axis.feedback().state is AxisState.FAULT
    with pytest.raises(DriveFault, match=name):
        rig.axis.send_setpoint(0.01)


def test_following_error(rig: Rig) -> None:
    rig.axis.enable()
    rig.drive.set_load(3000)  # a heavy load makes the loop lag far behind
    rig.move(0.3, until_fault=True)
    _assert_fault(rig, 0x8611, "following error")
    assert rig.drive.node.sdo[0x6041].raw & 0x2000  # statusword: following error


def test_limit_switch(rig: Rig) -> None:
    rig.drive.set_limit_switches(-1000, 5000)  # a switch at 50 mm, inside the software limits
    rig.axis.enable()
    rig.move(0.1, until_fault=True)
    _assert_fault(rig, 0x8612, "limit switch")


def test_injected_fault_and_reset(rig: Rig) -> None:
    rig.axis.enable()
    rig.drive.inject_fault(0x4310)
    _assert_fault(rig, 0x4310, "over-temperature")
    rig.axis.fault_reset()
    assert rig.drive.state == "SWITCH ON DISABLED" and rig.drive.error_code == 0
    assert rig.axis.feedback().state is AxisState.DISABLED
    rig.axis.enable()
    rig.move(0.02)
    assert wait_until(lambda: abs(rig.axis.feedback().position - 0.02) < 1e-4)


def test_fault_injected_over_sdo(rig: Rig) -> None:
    rig.axis.node.sdo[0x2001].raw = 0x2310
    _assert_fault(rig, 0x2310, "over-current")


def test_lost_master_heartbeat(rig: Rig) -> None:
    rig.axis.enable()
    rig.net.stop_master_heartbeat()
    _assert_fault(rig, 0x8130, "master heartbeat lost")


def test_lost_drive_heartbeat(rig: Rig) -> None:
    rig.axis.enable()
    rig.drive.go_silent()
    assert wait_until(lambda: rig.faults)
    # whichever comes first: 2.5 heartbeat periods of silence, or 21 SYNCs without an answer
    assert any(words in str(rig.faults[0][1]) for words in ("heartbeat lost", "feedback lost"))
    assert rig.axis.feedback().state is AxisState.FAULT


# -- real EDS files ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["cia402-generic.eds", "maxon-epos-70-10.eds"])
def test_real_eds_drives_both_sides(name: str) -> None:
    path = REAL_EDS / name
    if not path.is_file():
        pytest.skip(f"{path} not present")
    od = load_object_dictionary(path, 4)
    assert 0x6040 in od and 0x6064 in od
    rig = Rig(eds=path, node_id=4)
    try:
        rig.axis.enable()
        rig.move(0.05)
        assert wait_until(lambda: abs(rig.axis.feedback().position - 0.05) < 1e-4)
    finally:
        rig.close()


def test_eds_that_cannot_be_read_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "broken.eds"
    bad.write_text("[1000]\nParameterName=x\nObjectType=0x7\nDataType=0x0007\nAccessType=zz\n[broken")
    with pytest.raises(ConfigError, match="broken.eds"):
        load_object_dictionary(bad, 1)


# -- configuration ---------------------------------------------------------------------------------------

SIM_DRIVES = {
    "cycle_ms": 10,
    "heartbeat_ms": 100,
    "axes": {
        "lift": {"node_id": 1, "counts_per_m": 100000, "minimum_mm": 0, "maximum_mm": 3000,
                 "max_velocity_mm_s": 400, "max_acceleration_mm_s2": 800, "max_jerk_mm_s3": 4000},
        "tilt": {"kind": "rotary", "node_id": 3, "counts_per_rad": 500000, "minimum_deg": -6, "maximum_deg": 6,
                 "max_velocity_deg_s": 4, "max_acceleration_deg_s2": 8, "max_jerk_deg_s3": 40, "mode": "pp"},
    },
}


def test_axes_from_config_with_simulated_drives() -> None:
    bus = {"interface": "virtual", "channel": f"config-{os.getpid()}"}
    net, axes = axes_from_config(SIM_DRIVES, bus, "agf.yaml:", start_drives=start_simulated_drives)
    try:
        assert set(axes) == {"lift", "tilt"}
        assert axes["tilt"].limits.maximum == pytest.approx(math.radians(6))
        axes["tilt"].enable()
        axes["tilt"].send_setpoint(math.radians(1.0))
        assert wait_until(lambda: abs(axes["tilt"].feedback().position - math.radians(1.0)) < 1e-5)
    finally:
        net.close()


def test_simulated_drives_share_one_connection_and_one_going_silent_leaves_the_others_answering() -> None:
    bus = {"interface": "virtual", "channel": f"shared-{os.getpid()}-{next(_channels)}"}
    drives = start_simulated_drives([DriveSettings(n, i, DEFAULT_EDS, SCALE, LIMITS, 0.05)
                                     for n, i in (("lift", 4), ("tilt", 5))], bus, NetworkSettings(), "test")
    network = canopen.Network(can.Bus(**bus))
    network.connect()
    try:
        assert drives[0].network is drives[1].network  # one connection, two nodes on it
        nodes = [network.add_node(canopen.RemoteNode(i, str(DEFAULT_EDS))) for i in (4, 5)]
        for node in nodes:
            node.sdo.RESPONSE_TIMEOUT = 0.2
        assert [node.sdo[0x1000].raw for node in nodes] == [drives[0].node.sdo[0x1000].raw] * 2
        drives[0].go_silent()
        with pytest.raises(canopen.SdoCommunicationError):
            nodes[0].sdo[0x1000].raw  # noqa: B018 - the read is the test
        assert nodes[1].sdo[0x1000].raw == drives[1].node.sdo[0x1000].raw
        assert drives[1].network.bus is not None  # still connected for the drive that is left
    finally:
        for drive in drives:
            drive.close()
        network.disconnect()
    assert drives[0].network.bus is None  # the last drive to close disconnected it


@pytest.mark.parametrize("change, message", [
    ({"node_id": 0}, "node_id must be 1..127"),
    ({"counts_per_m": 0}, "counts per unit"),
    ({"mode": "velocity"}, "expected one of"),
    ({"minimum_mm": 4000}, "minimum"),
    ({"kind": "angular"}, "kind"),
    ({"eds": "missing.eds"}, "does not exist"),
])
def test_bad_drive_config_is_named(change: dict, message: str) -> None:
    lift = {**SIM_DRIVES["axes"]["lift"], **change}
    with pytest.raises(ConfigError, match=message):
        axes_from_config({"axes": {"lift": lift}}, {"interface": "virtual"}, "agf.yaml:")


# -- separate processes: udp_multicast and socketcan ------------------------------------------------------


# Linux delivers a multicast datagram to every socket bound to its port, whatever group the socket
# joined: a port of its own keeps this run apart from other test runs and benches on the machine
UDP_BUS = {"interface": "udp_multicast", "port": 43200 + os.getpid() % 1000}


def _multicast_loopback_works() -> str | None:
    try:
        a, b = open_bus(UDP_BUS, "probe"), open_bus(UDP_BUS, "probe")
    except ConfigError as exc:
        return str(exc)
    try:
        a.send(can.Message(arbitration_id=0x7FF, data=b"probe", is_extended_id=False))
        return None if b.recv(1.0) is not None else "multicast frames are not looped back on this machine"
    finally:
        a.shutdown()
        b.shutdown()


def test_three_drive_processes_over_udp_multicast() -> None:
    reason = _multicast_loopback_works()
    if reason:
        pytest.skip(f"udp_multicast unusable here: {reason}")
    ids = {"lift": 21, "reach": 22, "tilt": 23}
    command = [sys.executable, "-m", "drivers.sim.drive", "--interface", "udp_multicast",
               "--port", str(UDP_BUS["port"])]
    procs = [subprocess.Popen([*command, "--node-id", str(n)], cwd=REPO, stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True) for n in ids.values()]
    net = None
    try:
        for proc in procs:
            assert proc.stdout.readline().startswith("ready")
        net = Cia402Network(open_bus(UDP_BUS, "test"), NetworkSettings())
        axes = {name: net.add_axis(DriveSettings(name, n, DEFAULT_EDS, SCALE, LIMITS, 0.05)) for name, n in ids.items()}
        net.start()
        goals = {"lift": 0.1, "reach": 0.05, "tilt": 0.02}
        for axis in axes.values():
            axis.enable()
        for i in range(1, 61):  # one coordinated move: all setpoints of a cycle go out before its SYNC
            for name, axis in axes.items():
                axis.send_setpoint(goals[name] * (1 - math.cos(math.pi * i / 60)) / 2)
            axes["lift"].wait_for_feedback()
        for name, axis in axes.items():
            assert wait_until(lambda a=axis, g=goals[name]: abs(a.feedback().position - g) < 1e-4), name
        procs[1].stdin.write("fault 0x3210\n")
        procs[1].stdin.flush()
        assert wait_until(lambda: axes["reach"].feedback().state is AxisState.FAULT)
        assert "over-voltage" in axes["reach"].feedback().fault
    finally:
        if net is not None:
            net.close()
        for proc in procs:
            proc.communicate("quit\n", timeout=10)


def test_socketcan_vcan0() -> None:
    if not Path("/sys/class/net/vcan0").exists():
        pytest.skip("no vcan0 interface (needs the vcan kernel module: ip link add dev vcan0 type vcan)")
    rig_bus = {"interface": "socketcan", "channel": "vcan0"}
    drive = SimDrive.open(30, open_bus(rig_bus, "test"))
    net = Cia402Network(open_bus(rig_bus, "test"), NetworkSettings())
    try:
        axis = net.add_axis(DriveSettings("lift", 30, DEFAULT_EDS, SCALE, LIMITS, 0.05))
        net.start()
        axis.enable()
        axis.send_setpoint(0.001)
        assert wait_until(lambda: abs(axis.feedback().position - 0.001) < 1e-4)
    finally:
        net.close()
        drive.close()


def test_master_gone_entirely_drive_stops_on_its_own_clock(rig: Rig) -> None:
    rig.axis.enable()
    for i in range(1, 16):  # accelerate, then vanish mid-move: no SYNC, no heartbeat
        rig.axis.send_setpoint(0.2 * (1 - math.cos(math.pi * i / 100)) / 2)
        rig.axis.wait_for_feedback()
    assert rig.drive.velocity > 0
    rig.net.stop_sync()
    rig.net.stop_master_heartbeat()
    assert wait_until(lambda: rig.drive.state == "FAULT")
    assert rig.drive.velocity == 0.0 and rig.drive.error_code == 0x8130


def test_emcy_names() -> None:
    assert emcy_name(0x8611) == "following error"
    assert emcy_name(0x3300) == "voltage"  # CiA 301 error class when the code is not ours
