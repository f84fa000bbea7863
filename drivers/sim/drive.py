"""A simulated CiA 402 position drive on canopen's ``LocalNode``: the twin of one fork-axis drive.

The drive takes an EDS as its object dictionary (``configs/eds/agf_axis.eds`` by default, or a real
device's file so it stands in for that device) and implements what canopen's ``LocalNode`` does not:

* the PDOs: it reads its own PDO communication and mapping parameters (as a master wrote them over
  SDO), decodes received RPDOs into the object dictionary (synchronous RPDOs are applied at the next
  SYNC) and sends its synchronous TPDOs after each SYNC;
* the whole CiA 402 power state machine (controlword / statusword), modes 8 (CSP) and 1 (PP);
* motion: the motor follows its set-point through a first-order lag whose time constant grows with
  the load (0x2000, percent of rated load), within the velocity (0x607F) and acceleration (0x60C5)
  limits; PP generates a trapezoidal profile (0x6081, 0x6083, 0x6084) first;
* faults, each announced by EMCY and ending in FAULT: following error (0x6065), limit switches, loss
  of the master's heartbeat (0x1016, the drive quick-stops then faults), injected faults;
* its own heartbeat (0x1017, by canopen's NmtSlave).

Time: the drive advances its motion by one cycle period (0x1006, else the ``cycle`` argument) on
every SYNC it receives, so a test that sends SYNCs gets exactly the same motion every run. When the
SYNCs stop during a stop ramp (the master is gone), the supervisor keeps stepping the ramp on its own
so the axis still comes to rest. Heartbeat, master-heartbeat supervision and that ramp keep the time
of an injected :class:`agf.clock.Clock`: the wall clock by default, or the simulated world's clock.

Run as a process: ``python -m drivers.sim.drive --node-id N --interface udp_multicast``. It serves
until SIGINT, SIGTERM or ``quit`` on standard input, and says which ended it; commands on standard
input are optional (``fault [CODE]``, ``load PERCENT``, ``limits LOW HIGH``, ``silent``, ``status``,
``quit``): started with ``< /dev/null`` or by a service manager it keeps serving.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import struct
import sys
import threading
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import can
import canopen

from agf.clock import Clock, Periodic, WallClock
from agf.errors import ConfigError
from drivers.can_bus import open_bus
from drivers.cia402_axis import (
    DEFAULT_EDS,
    ClockedNetwork,
    DriveSettings,
    NetworkSettings,
    load_object_dictionary,
    raise_priority,
    raise_receive_priority,
)

logger = logging.getLogger(__name__)

# statusword values of the power states (bit 4 voltage enabled, bit 9 remote)
STATUSWORDS = {
    "NOT READY TO SWITCH ON": 0x0000,
    "SWITCH ON DISABLED": 0x0040,
    "READY TO SWITCH ON": 0x0031,
    "SWITCHED ON": 0x0033,
    "OPERATION ENABLED": 0x0037,
    "QUICK STOP ACTIVE": 0x0017,
    "FAULT REACTION ACTIVE": 0x001F,
    "FAULT": 0x0008,
}
POWERED = ("OPERATION ENABLED", "QUICK STOP ACTIVE", "FAULT REACTION ACTIVE")
FOLLOWING_ERROR, LIMIT_SWITCH, MASTER_HEARTBEAT, INJECTED = 0x8611, 0x8612, 0x8130, 0xFF00
PDO_LENGTH = 0x8210  # CiA 301: PDO not processed due to length error
# A simulated drive stands in for a microcontroller of its own: its threads get a real-time priority
# where the OS allows it, so that load on the test bed's cores does not starve them (a property of
# the test bed, not of the truck). Below the master's (30).
DRIVE_PRIORITY = 25

_DEFAULTS = {  # used when the object dictionary in use has no such object (counts, counts/s, ...)
    0x6065: 5_000, 0x607F: 100_000, 0x6081: 50_000, 0x6083: 100_000,
    0x6084: 100_000, 0x6085: 400_000, 0x60C5: 200_000, 0x605A: 6,
}
_TARGET_WINDOW = 2.0  # counts: "target reached"
_UNREAD = object()  # a setting not read yet (SimDrive._param)


class DriveConnection:
    """One connection to the bus that the simulated drives of a process share (:func:`start_simulated_drives`).

    python-can's virtual bus copies every frame to each connection, and each connection's notifier thread
    wakes up for it (on the wall clock): with three drives, the master and the CAN tap on their own
    connections, each frame was copied four times; with the drives on one, twice (the CAN threads took
    12 % of a simulated pick's CPU). Each drive is still a node of its own on the bus. The network
    connects with the first drive to start and disconnects when the last one closes; a drive that closes
    (or goes silent) drops its own subscriptions only.
    """

    def __init__(self, bus: can.BusABC, clock: Clock) -> None:
        self.network = ClockedNetwork(bus, clock)
        self.network.NOTIFIER_CYCLE = 0.02  # how long closing waits for the receive thread (0.1 s: 0.4 s a pick)
        self._drives = 0
        self._lock = threading.Lock()

    def join(self) -> None:
        """A drive starts on the connection (the first one connects it)."""
        with self._lock:
            if self._drives == 0:
                self.network.connect()
                raise_receive_priority(self.network, DRIVE_PRIORITY)
            self._drives += 1

    def leave(self, owners: Sequence[object]) -> None:
        """A drive leaves: every subscription whose callback is bound to one of ``owners`` (the drive and its
        node's services) is dropped; the last drive to leave disconnects the network."""
        ids = {id(owner) for owner in owners}
        with self._lock:
            subscribers = self.network.subscribers
            for can_id, callbacks in list(subscribers.items()):
                kept = [c for c in callbacks if id(getattr(c, "__self__", None)) not in ids]
                if kept:
                    subscribers[can_id] = kept  # a new list: the receive thread may be iterating the old one
                else:
                    del subscribers[can_id]
            self._drives = max(self._drives - 1, 0)  # a drive closed before it started never joined
            if self._drives == 0 and self.network.bus is not None:
                self.network.disconnect()


class SimDrive:
    """One simulated CiA 402 drive on a CAN bus.

    Parameters
    ----------
    node_id : int
        CANopen node id, 1..127.
    bus : can.BusABC or DriveConnection
        Its own connection to the bus (closed by :meth:`close`), or one it shares with other drives.
    eds : path, optional
        Object dictionary; default ``configs/eds/agf_axis.eds``.
    cycle : float
        Motion step (s) per SYNC when the master has not written 0x1006.
    lag : float
        Time constant (s) of the position loop at no load; it grows linearly with the load.
    clock : Clock, optional
        The time its heartbeat and supervision keep; the wall clock by default.
    """

    def __init__(self, node_id: int, bus: can.BusABC | DriveConnection, eds: str | Path = DEFAULT_EDS, *,
                 cycle: float = 0.01, lag: float = 0.02, clock: Clock | None = None) -> None:
        self.node = canopen.LocalNode(node_id, load_object_dictionary(eds, node_id))
        self.clock = clock or WallClock()
        self._connection = bus if isinstance(bus, DriveConnection) else DriveConnection(bus, self.clock)
        self.network = self._connection.network
        self.network.add_node(self.node)
        self._lock = threading.RLock()
        self._cycle, self._lag = cycle, lag
        self.state = "SWITCH ON DISABLED"
        self.mode = 0
        self.position = 0.0  # counts
        self.velocity = 0.0  # counts/s
        self.error_code = 0
        self.limit_switches: tuple[float, float] | None = None
        self._setpoint = 0.0  # what the position loop follows (counts)
        self._target = 0  # 0x607A as received
        self._controlword = 0
        self._load_percent = 0.0  # carried load, percent of rated (0x2000)
        self._pp_goal: float | None = None
        self._pp_velocity = 0.0
        self._ack = False
        self._halt = False
        self._sync_count = 0
        self._last_sync = 0.0
        self._master_id = 0
        self._master_timeout = 0.0
        self._master_seen: float | None = None
        self._rpdos: dict[int, tuple[int, list]] = {}
        self._tpdos: list[tuple[int, int, list]] = []
        self._pending: dict[int, bytes] = {}
        self._last_sent: dict[int, bytes] = {}
        self._pdo_dirty = True
        self._sdo_faults: dict[int, tuple[str, int]] = {}  # index -> (timeout | abort, how many more times)
        self._params: dict[tuple[int, int], int | None] = {}  # (index, subindex) -> value, None: none (_param)
        self._stop = threading.Event()
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self.network.subscribe(0x80, self._on_sync)
        self.network.subscribe(0, self._on_nmt)
        self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        self.network.subscribe(self.node.sdo.rx_cobid, self._on_sdo_request)
        if 0x1006 in self.node.object_dictionary:  # our cycle until a master writes its own
            self.node.data_store[0x1006] = {0: struct.pack("<I", round(cycle * 1e6))}
        self.mode = self._param(0x6060, 0, 0) if self._param(0x6060, 0, 0) in (1, 8) else 0
        self._supervisor: Periodic | None = None

    @classmethod
    def open(cls, node_id: int, bus: can.BusABC | DriveConnection, **kwargs: Any) -> SimDrive:
        """Create the drive, connect it and boot it (boot-up message, PRE-OPERATIONAL)."""
        drive = cls(node_id, bus, **kwargs)
        drive.start()
        return drive

    def start(self) -> None:
        """Connect to the bus and boot: boot-up message, PRE-OPERATIONAL, heartbeat from 0x1017."""
        self._connection.join()
        self._boot()
        self._supervised_at = self.clock.monotonic()
        self._supervisor = self.clock.every(0.005, self._supervise, f"sim-drive-{self.node.id}")
        thread = getattr(self._supervisor, "thread", None)  # the wall clock's thread
        if thread is not None:
            raise_priority(thread, DRIVE_PRIORITY)

    def _boot(self) -> None:
        self._configure_master_heartbeat(self._param(0x1016, 1, 0))
        self.node.nmt.send_command(0x81)  # INITIALISING: boot-up message
        self.node.nmt.send_command(0x80)  # PRE-OPERATIONAL: starts the heartbeat producer
        self._raise_heartbeat_priority()

    def _raise_heartbeat_priority(self) -> None:
        task = getattr(getattr(self.node.nmt, "_send_task", None), "_task", None)  # python-can's cyclic task
        if isinstance(getattr(task, "thread", None), threading.Thread):
            raise_priority(task.thread, DRIVE_PRIORITY)

    def close(self) -> None:
        """Stop everything and leave the bus (its own connection closes; a shared one, with its last drive).
        Closing again does nothing (a drive that went silent is closed with its network later)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self.node.nmt.stop_heartbeat()
        if self._supervisor is not None:
            self._supervisor.cancel()
        node = self.node
        self._connection.leave([self, node, node.nmt, node.sdo, node.emcy, node.tpdo, node.rpdo])

    # -- fault injection and test hooks ------------------------------------------------------------
    def inject_fault(self, code: int = INJECTED) -> None:
        """Raise a fault with EMCY error code ``code`` (e.g. 0x2310 over-current, 0x4310 over-temperature)."""
        self._fault(code)

    def set_load(self, percent: float) -> None:
        """Set the carried load in percent of the rated load (it slows the position loop down)."""
        with self._lock:
            self._load_percent = float(percent)

    def set_limit_switches(self, low: float | None, high: float | None) -> None:
        """Place the limit switches (counts); ``None`` removes them."""
        with self._lock:
            self.limit_switches = None if low is None or high is None else (float(low), float(high))

    def go_silent(self) -> None:
        """Lose the CAN connection (power cut): no heartbeat, no PDO, no SDO from now on."""
        self.close()

    def emcy(self, code: int) -> None:
        """Send an EMCY with error code ``code`` and stay in the present state (a warning, e.g. 0x4210)."""
        self.node.emcy.send(code, 0x01, b"\0" * 5)

    def place(self, counts: float) -> None:
        """Put the motor at rest at ``counts``, as if it had been moved there before the bus came up (a
        simulated truck that arrives with its forks raised). Only while the drive is not enabled.

        Raises
        ------
        RuntimeError
            When the drive is enabled: a motor that is holding a position does not jump.
        """
        with self._lock:
            if self.state in POWERED:
                raise RuntimeError(f"node {self.node.id}: cannot place the motor of a drive that is {self.state}")
            self.position = self._setpoint = float(counts)
            self.velocity = 0.0

    def reboot(self) -> None:
        """Reset of the drive's electronics: the motor stops where it is (brake), the object dictionary
        returns to its defaults (PDO mapping, heartbeat, mode, limits), boot-up message, PRE-OPERATIONAL."""
        self.node.nmt.stop_heartbeat()
        with self._lock:
            self.state, self.velocity, self.error_code = "SWITCH ON DISABLED", 0.0, 0
            self._setpoint, self._controlword, self._pp_goal, self._pp_velocity = self.position, 0, None, 0.0
            self.node.data_store.clear()
            self._params.clear()
            if 0x1006 in self.node.object_dictionary:
                self.node.data_store[0x1006] = {0: struct.pack("<I", round(self._cycle * 1e6))}
            self.mode = self._param(0x6060, 0, 0) if self._param(0x6060, 0, 0) in (1, 8) else 0
            for cob_id in self._rpdos:
                self.network.unsubscribe(cob_id, self._on_rpdo)
            self._rpdos, self._tpdos, self._pending, self._pdo_dirty = {}, [], {}, True
        logger.info("node %d: reboot", self.node.id)
        self._boot()

    def fail_sdo(self, index: int, kind: str = "timeout", times: int = 1) -> None:
        """The next ``times`` SDO requests on object ``index`` get no answer (``timeout``) or an abort."""
        if kind not in ("timeout", "abort"):
            raise ValueError(f"kind must be timeout or abort, got {kind!r}")
        with self._lock:
            self._sdo_faults[index] = (kind, times)

    def _on_sdo_request(self, can_id: int, data: bytes, timestamp: float) -> None:
        command = data[0] >> 5 if data else 0
        index = struct.unpack_from("<H", data, 1)[0] if command in (1, 2) and len(data) >= 4 else None
        with self._lock:
            kind, times = self._sdo_faults.get(index, ("", 0))
            if times:
                self._sdo_faults[index] = (kind, times - 1)
        if not times:
            self.node.sdo.on_request(can_id, data, timestamp)
        elif kind == "abort":  # 0x08000020: data cannot be transferred or stored to the application
            self.network.send_message(self.node.sdo.tx_cobid, struct.pack("<BHBI", 0x80, index, data[3], 0x08000020))

    # -- object dictionary -------------------------------------------------------------------------
    def _param(self, index: int, subindex: int = 0, default: int | None = None) -> int:
        """A setting of the object dictionary (not one :meth:`_on_read` answers), else ``default`` (else ours).

        Settings change only when written, and :meth:`_on_write` keeps each value read: the motion reads six
        of them on every SYNC, and reading one from the object dictionary was most of the cost of a step."""
        value = self._params.get((index, subindex), _UNREAD)
        if value is _UNREAD:
            with self._lock:  # a write stores its value first: the dictionary's older one must not replace it
                value = self._params.get((index, subindex), _UNREAD)
                if value is _UNREAD:
                    value = self._params[index, subindex] = self._stored(index, subindex)
        if value is None:
            return _DEFAULTS.get(index, 0) if default is None else default
        return value

    def _stored(self, index: int, subindex: int) -> int | None:
        if index not in self.node.object_dictionary:
            return None
        try:
            return self._decode(index, subindex)
        except canopen.SdoAbortedError:
            return None

    def _cycle_period(self) -> float:
        return self._param(0x1006, 0, 0) / 1e6 or self._cycle

    def _decode(self, index: int, subindex: int) -> int:
        od = self.node._find_object(index, subindex)
        return od.decode_raw(self.node.get_data(index, subindex))

    def _on_read(self, index: int, subindex: int, od: Any) -> int | None:
        # a chain of tests, not a table of getters built per call: it answers every object the drive reads
        # (about 12 a SYNC: its TPDOs, limits and cycle period), and the table was most of its cost
        if index == 0x6041:
            return self._statusword()
        if index == 0x6064:
            return round(self.position)
        if index == 0x606C:
            return round(self.velocity)
        if index == 0x6061:
            return self.mode
        if index == 0x603F:
            return self.error_code
        if index == 0x1001:
            return 0x81 if self.error_code else 0  # generic + manufacturer-specific error
        if index == 0x6502:
            return od.default if od.default is not None else 0x81  # PP and CSP
        return None

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        value = od.decode_raw(data) if od.data_type in canopen.objectdictionary.NUMBER_TYPES else None
        if value is not None:
            with self._lock:  # what _param reads from now on (the node stores the data after this callback)
                self._params[index, subindex] = value
        if index == 0x6040:
            self._on_controlword(value)
        elif index == 0x6060:
            with self._lock:
                supported = self._param(0x6502, 0, 0x81)
                self.mode = value if value in (1, 8) and supported >> (value - 1) & 1 else self.mode
        elif index == 0x607A:
            self._target = value
        elif index == 0x1016 and subindex == 1:
            self._configure_master_heartbeat(value)
        elif index == 0x1017:  # canopen's NmtSlave has just (re)started the heartbeat producer
            self._raise_heartbeat_priority()
        elif index == 0x2000:
            self._load_percent = float(value)
        elif index == 0x2001 and value:
            self._fault(value)
        elif 0x1400 <= index <= 0x1BFF:
            self._pdo_dirty = True

    def _configure_master_heartbeat(self, value: int) -> None:
        if self._master_id:
            self.network.unsubscribe(0x700 + self._master_id, self._on_master_heartbeat)
        self._master_id, self._master_timeout = (value >> 16) & 0x7F, (value & 0xFFFF) / 1000.0
        self._master_seen = None  # supervision starts with the first heartbeat (CiA 301)
        if self._master_id and self._master_timeout:
            self.network.subscribe(0x700 + self._master_id, self._on_master_heartbeat)

    # -- PDOs (a LocalNode's PDOs are not tied to its data store: done here) -----------------------
    def _load_pdos(self) -> None:
        for cob_id in self._rpdos:
            self.network.unsubscribe(cob_id, self._on_rpdo)
        self._rpdos = {cob: (tt, entries) for cob, tt, entries in self._pdo_list(0x1400, 0x1600)}
        self._tpdos = self._pdo_list(0x1800, 0x1A00)
        for cob_id in self._rpdos:
            self.network.subscribe(cob_id, self._on_rpdo)
        self._pdo_dirty = False

    def _pdo_list(self, com: int, mapping: int) -> list[tuple[int, int, list]]:
        pdos = []
        for n in range(512):
            if com + n not in self.node.object_dictionary:
                break
            cob_id = self._decode(com + n, 1)
            if cob_id & 0x80000000:
                continue
            entries = []
            for sub in range(1, self._decode(mapping + n, 0) + 1):
                value = self._decode(mapping + n, sub)
                entries.append((value >> 16, (value >> 8) & 0xFF, (value & 0xFF) // 8))
            pdos.append((cob_id & 0x7FF, self._decode(com + n, 2), entries))
        return pdos

    def _on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        if self.node.nmt.state != "OPERATIONAL" or can_id not in self._rpdos:
            return
        trans_type, _ = self._rpdos[can_id]
        if trans_type <= 240:
            self._pending[can_id] = bytes(data)  # synchronous: applied at the next SYNC
        else:
            self._apply_rpdo(can_id, bytes(data))

    def _apply_rpdo(self, can_id: int, data: bytes) -> None:
        expected = sum(size for _, _, size in self._rpdos[can_id][1])
        if len(data) != expected:  # CiA 301: not processed, EMCY 0x8210
            logger.warning("node %d: RPDO 0x%X with %d bytes, mapping %d: not processed", self.node.id, can_id,
                           len(data), expected)
            self.node.emcy.send(PDO_LENGTH, 0x11, b"\0" * 5)
            return
        fields, offset = [], 0
        for index, subindex, size in self._rpdos[can_id][1]:
            if index > 7:  # dummy entries (index 1..7) only take room
                fields.append((index, subindex, data[offset:offset + size]))
            offset += size
        # a PDO is applied as a whole: the controlword last, so a new set-point sees its target
        for index, subindex, payload in sorted(fields, key=lambda f: f[0] == 0x6040):
            try:
                self.node.set_data(index, subindex, payload)
            except canopen.SdoAbortedError as exc:
                logger.warning("node %d: RPDO 0x%X entry 0x%04X: %s", self.node.id, can_id, index, exc)

    def _send_tpdos(self) -> None:
        # synchronous TPDOs (1..240) every n-th SYNC; event-driven ones (254, 255) when their content
        # changed since last sent (checked at each SYNC: this drive's only clock)
        for cob_id, trans_type, entries in self._tpdos:
            data = b"".join(self.node.get_data(i, s)[:size] for i, s, size in entries)
            if 1 <= trans_type <= 240:
                due = self._sync_count % trans_type == 0
            else:
                due = trans_type >= 254 and self._last_sent.get(cob_id) != data
            if due:
                self._last_sent[cob_id] = data
                self.network.send_message(cob_id, data)

    # -- SYNC, NMT, heartbeat --------------------------------------------------------------------
    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        if self.node.nmt.state == "OPERATIONAL" and self._pdo_dirty:
            self._load_pdos()

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        if self._stop.is_set():
            return
        self._last_sync = self.clock.monotonic()
        if self.node.nmt.state != "OPERATIONAL":
            return
        if self._pdo_dirty:
            self._load_pdos()
        pending, self._pending = self._pending, {}
        for cob_id, payload in pending.items():
            self._apply_rpdo(cob_id, payload)
        self._sync_count += 1
        self.step(self._cycle_period())
        self._send_tpdos()

    def _on_master_heartbeat(self, can_id: int, data: bytes, timestamp: float) -> None:
        self._master_seen = self.clock.monotonic()

    def _supervise(self) -> None:
        """Every 5 ms: the master's heartbeat, and the stop ramp when the SYNCs have stopped."""
        now = self.clock.monotonic()
        # time this thread was not scheduled (the test bed's CPU busy, the GIL held) is not the
        # master's silence: a drive's own microcontroller is never starved like that
        stalled, self._supervised_at = max(0.0, now - self._supervised_at - 0.02), now
        if stalled and self._master_seen is not None:
            self._master_seen += stalled
        seen, timeout = self._master_seen, self._master_timeout
        if seen is not None and timeout and now - seen > timeout:
            self._master_seen = None
            self._fault(MASTER_HEARTBEAT)
        if self.state not in ("QUICK STOP ACTIVE", "FAULT REACTION ACTIVE"):
            return  # reading the cycle period from the object dictionary was 85 % of this, 600 times a second
        cycle = self._cycle_period()
        if now - self._last_sync > 3 * cycle:
            self.step(cycle)  # no SYNC any more: finish the stop ramp on our own clock
            self._last_sync = now - 2 * cycle

    # -- CiA 402 power state machine ----------------------------------------------------------------
    def _on_controlword(self, word: int) -> None:
        with self._lock:
            previous, self._controlword = self._controlword, word
            self._halt = bool(word & 0x100)
            reset = self.state == "FAULT" and bool(word & 0x80) and not previous & 0x80  # transition 15
            if reset:
                self.error_code = 0
                self.state = "SWITCH ON DISABLED"
            elif self.state != "FAULT":
                self._power_transition(word)
            if self.state == "OPERATION ENABLED" and self.mode == 1:
                self._pp_handshake(word, previous)
        if reset:
            self.node.emcy.reset()

    def _power_transition(self, word: int) -> None:
        state = self.state
        command = _command(word)
        if state == "QUICK STOP ACTIVE" and command == "quick stop":
            return  # the same command again (a master repeats it every cycle): stay
        if command == "disable voltage" or (command == "quick stop" and state != "OPERATION ENABLED"):
            if state not in ("FAULT REACTION ACTIVE", "NOT READY TO SWITCH ON"):
                self.state = "SWITCH ON DISABLED"
        elif command == "quick stop":
            self.state = "QUICK STOP ACTIVE"  # transition 11
        elif command == "shutdown" and state in ("SWITCH ON DISABLED", "SWITCHED ON", "OPERATION ENABLED"):
            self.state = "READY TO SWITCH ON"
        elif command == "switch on" and state in ("READY TO SWITCH ON", "OPERATION ENABLED"):
            self.state = "SWITCHED ON"
        elif command == "enable operation" and state in ("READY TO SWITCH ON", "SWITCHED ON", "QUICK STOP ACTIVE"):
            self._enter_operation_enabled()
        if self.state not in POWERED:
            self.velocity = 0.0

    def _enter_operation_enabled(self) -> None:
        if self.state != "QUICK STOP ACTIVE":
            self._setpoint = self.position
            self._pp_goal, self._pp_velocity = None, 0.0
        self.state = "OPERATION ENABLED"

    def _pp_handshake(self, word: int, previous: int) -> None:
        if word & 0x10 and not previous & 0x10:  # new set-point
            goal = float(self._target) + (self._pp_goal if word & 0x40 and self._pp_goal is not None else 0.0)
            self._pp_goal = self._clamp(goal)
            self._ack = True
        elif not word & 0x10:
            self._ack = False

    def _statusword(self) -> int:
        word = STATUSWORDS[self.state] | 0x0200
        if self.state == "OPERATION ENABLED":
            if self.mode == 8:
                word |= 0x1000  # drive follows the command value
            elif self._ack:
                word |= 0x1000  # set-point acknowledge
            goal = self._target if self.mode == 8 else self._pp_goal
            if goal is not None and abs(goal - self.position) < _TARGET_WINDOW and abs(self.velocity) < 1.0:
                word |= 0x0400
        if self.error_code == FOLLOWING_ERROR:
            word |= 0x2000
        return word

    # -- faults ------------------------------------------------------------------------------------
    def _fault(self, code: int) -> None:
        with self._lock:
            if self.state in ("FAULT", "FAULT REACTION ACTIVE") or self._stop.is_set():
                return
            self.error_code = code
            self.state = "FAULT REACTION ACTIVE" if self.state in POWERED else "FAULT"
            if self.state == "FAULT":
                self.velocity = 0.0
        logger.info("node %d: fault 0x%04X", self.node.id, code)
        self.node.emcy.send(code, 0x81 if code != MASTER_HEARTBEAT else 0x11, b"\0" * 5)

    # -- motion ------------------------------------------------------------------------------------
    def step(self, dt: float) -> None:
        """Advance the motor by ``dt`` seconds (called on every SYNC)."""
        fault = None
        with self._lock:
            load = 1.0 + max(self._load_percent, 0.0) / 100.0
            if self.state == "OPERATION ENABLED" and not self._halt:
                self._advance_setpoint(dt, load)
                fault = self._follow(dt, load)
            elif self.state in POWERED:  # halt (bit 8) ramps at the profile deceleration, stops at the quick-stop one
                self._ramp_down(dt, self._param(0x6084 if self.state == "OPERATION ENABLED" else 0x6085, 0))
            if fault is None and self.state in POWERED and self.limit_switches is not None:
                low, high = self.limit_switches
                fault = LIMIT_SWITCH if not low <= self.position <= high else None
        if fault is not None:
            self._fault(fault)

    def _advance_setpoint(self, dt: float, load: float) -> None:
        if self.mode == 8:
            self._setpoint = self._clamp(float(self._target))
        elif self._pp_goal is not None:  # PP: trapezoidal profile towards the goal
            speed, accel = self._param(0x6081, 0), self._param(0x6083, 0) / load
            decel = self._param(0x6084, 0) / load
            remaining = self._pp_goal - self._setpoint
            wanted = math.copysign(min(speed, math.sqrt(2 * decel * abs(remaining))), remaining)
            change = accel if abs(wanted) > abs(self._pp_velocity) else decel
            self._pp_velocity += max(-change * dt, min(change * dt, wanted - self._pp_velocity))
            self._setpoint += self._pp_velocity * dt
            if abs(self._pp_goal - self._setpoint) < 0.5 and abs(self._pp_velocity) < change * dt:
                self._setpoint, self._pp_velocity = self._pp_goal, 0.0

    def _follow(self, dt: float, load: float) -> int | None:
        tau = self._lag * load  # the heavier the load, the slower the loop
        vmax, amax = self._param(0x607F, 0), self._param(0x60C5, 0) / load
        wanted = max(-vmax, min(vmax, (self._setpoint - self.position) / max(tau, dt)))
        self.velocity += max(-amax * dt, min(amax * dt, wanted - self.velocity))
        self.position += self.velocity * dt
        window = self._param(0x6065, 0)
        return FOLLOWING_ERROR if window and abs(self._setpoint - self.position) > window else None

    def _ramp_down(self, dt: float, decel: float) -> None:
        self.velocity -= math.copysign(min(abs(self.velocity), decel * dt), self.velocity)
        self.position += self.velocity * dt
        if self.velocity == 0.0:
            self._setpoint = self.position
            if self.state == "FAULT REACTION ACTIVE":
                self.state = "FAULT"
            elif self.state == "QUICK STOP ACTIVE" and self._param(0x605A, 0) in (1, 2, 3, 4):
                self.state = "SWITCH ON DISABLED"

    def _clamp(self, counts: float) -> float:
        if 0x607D not in self.node.object_dictionary:
            return counts
        low, high = self._param(0x607D, 1), self._param(0x607D, 2)
        return max(low, min(high, counts)) if low < high else counts


def start_simulated_drives(
    drives: Sequence[DriveSettings], bus_mapping: Any, settings: NetworkSettings, where: str,
    clock: Clock | None = None,
) -> list[SimDrive]:
    """A simulated drive per configured axis, in this process, all on one connection to the bus
    (:class:`DriveConnection`; a :data:`drivers.cia402_axis.DriveStarter`: the default configuration's
    ``plugins.drives``), keeping ``clock``'s time (the wall clock by default)."""
    clock = clock or WallClock()
    connection = DriveConnection(open_bus(bus_mapping, f"{where} bus"), clock)
    return [SimDrive.open(d.node_id, connection, eds=d.eds, cycle=settings.cycle, clock=clock) for d in drives]


def _command(word: int) -> str:
    """Decode the device-control command of a controlword (CiA 402 table)."""
    if not word & 0x02:
        return "disable voltage"
    if not word & 0x04:
        return "quick stop"
    if word & 0x0F == 0x06:
        return "shutdown"
    if word & 0x0F == 0x07:
        return "switch on"
    if word & 0x0F == 0x0F:
        return "enable operation"
    return "none"


# --------------------------------------------------------------------------------------------------
# command line


def main(argv: list[str] | None = None) -> int:
    """Run one simulated drive until SIGINT, SIGTERM or ``quit`` on standard input."""
    parser = argparse.ArgumentParser(prog="python -m drivers.sim.drive", description=__doc__.splitlines()[0])
    parser.add_argument("--node-id", type=int, required=True)
    parser.add_argument("--interface", default="udp_multicast")
    parser.add_argument("--channel", default=None,
                        help="bus channel (default: python-can's group for udp_multicast, agf for virtual, can0)")
    parser.add_argument("--port", type=int, default=None, help="udp_multicast port (python-can's default when omitted)")
    parser.add_argument("--eds", default=str(DEFAULT_EDS))
    parser.add_argument("--cycle-ms", type=float, default=10.0, help="motion step per SYNC until 0x1006 is written")
    parser.add_argument("--load-percent", type=float, default=0.0)
    parser.add_argument("--limit-switches", type=float, nargs=2, metavar=("LOW", "HIGH"), help="counts")
    parser.add_argument("--fault-after", nargs=2, metavar=("SECONDS", "CODE"),
                        help="inject the fault with EMCY code CODE (e.g. 0x4310) SECONDS after start")
    args = parser.parse_args(argv)
    if not 1 <= args.node_id <= 127:
        parser.error(f"--node-id must be 1..127, got {args.node_id}")
    if not Path(args.eds).is_file():
        parser.error(f"--eds: file {args.eds} not found")
    bus_mapping: dict[str, Any] = {"interface": args.interface}
    if args.channel is not None:
        bus_mapping["channel"] = args.channel
    if args.port is not None:
        bus_mapping["port"] = args.port
    try:
        drive = SimDrive.open(args.node_id, open_bus(bus_mapping, "--interface/--channel"), eds=args.eds,
                              cycle=args.cycle_ms / 1000.0)
    except ConfigError as exc:
        parser.error(str(exc))
    drive.set_load(args.load_percent)
    if args.limit_switches:
        drive.set_limit_switches(*args.limit_switches)
    if args.fault_after:
        seconds, code = float(args.fault_after[0]), int(args.fault_after[1], 0)
        timer = threading.Timer(seconds, drive.inject_fault, args=(code,))
        timer.daemon = True
        timer.start()
    ended = _Ending()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda number, _: ended.set(signal.Signals(number).name))
    print(f"ready node {args.node_id}", flush=True)
    threading.Thread(target=_read_commands, args=(drive, ended), name="commands", daemon=True).start()
    try:
        while not ended.wait(0.5):  # a timed wait lets the signal handlers run
            pass
    finally:
        drive.close()
    print(f"stopped node {args.node_id} at {datetime.now(UTC):%Y-%m-%d %H:%M:%S} UTC: {ended.reason}", flush=True)
    return 0


class _Ending(threading.Event):
    """Set once, with the reason the drive stops (the first one wins)."""

    reason = "unknown"

    def set(self, reason: str = "unknown") -> None:  # type: ignore[override]
        if not self.is_set():
            self.reason = reason
        super().set()


def _read_commands(drive: SimDrive, ended: _Ending) -> None:
    """Commands from standard input until ``quit``; at its end the drive keeps serving."""
    for line in sys.stdin:
        if not _command_line(drive, line.split()):
            ended.set("quit on standard input")
            return
    print("standard input closed; serving until SIGINT or SIGTERM", flush=True)


_USAGE = "fault [CODE] | load PERCENT | limits LOW HIGH | silent | status | quit"


def _command_line(drive: SimDrive, words: list[str]) -> bool:
    if not words:
        return True
    verb, values = words[0], words[1:]
    if verb == "quit":
        return False
    try:
        _run_command(drive, verb, values)
    except (ValueError, IndexError):
        print(f"bad arguments for {verb!r}: {_USAGE}", flush=True)
    return True


def _run_command(drive: SimDrive, verb: str, values: list[str]) -> None:
    if verb == "fault":
        drive.inject_fault(int(values[0], 0) if values else INJECTED)
    elif verb == "load":
        drive.set_load(float(values[0]))
    elif verb == "limits":
        drive.set_limit_switches(float(values[0]), float(values[1]))
    elif verb == "silent":
        drive.go_silent()
    elif verb == "status":
        print(f"{drive.state} mode {drive.mode} position {drive.position:.1f} "
              f"error 0x{drive.error_code:04X}", flush=True)
    else:
        print(f"unknown command {verb!r}: {_USAGE}", flush=True)


if __name__ == "__main__":
    logging.basicConfig(level=logging.WARNING)
    raise SystemExit(main())
