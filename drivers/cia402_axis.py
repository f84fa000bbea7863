"""One fork axis over CANopen CiA 402: canopen's ``BaseNode402`` behind the :class:`agf.axis.Axis` protocol.

:class:`Cia402Network` owns what exists once per bus: the ``canopen.Network``, the SYNC producer at
the control cycle, the master's heartbeat and the watchdog that supervises every drive's heartbeat
and TPDO stream. It creates the axes (:class:`Cia402Axis`), one per drive.

Start-up of one axis, all over SDO while the drive is PRE-OPERATIONAL: producer heartbeat (0x1017),
consumer heartbeat of the master (0x1016), cycle period (0x1006), the PDO mapping (RPDO1 controlword +
target position, TPDO1 statusword + position actual, TPDO2 velocity actual + mode display + error
code, all synchronous), the mode of operation (8, CSP, or 1, PP) checked on 0x6061, the drive's own
limits (0x607D, 0x607F, 0x6081, 0x6083, 0x6084, 0x6085, 0x6065) from the configured SI limits; then
NMT OPERATIONAL.

canopen traps handled here (see issue 7): the master has no heartbeat-timeout callback (our watchdog
thread), ``BaseNode402``'s state setter does not transmit a controlword mapped into a synchronous RPDO
and ``reset_from_fault`` never confirms (we sequence the 402 transitions ourselves and check the
statusword), and nothing inside a CAN callback blocks on SDO.
"""

from __future__ import annotations

import collections
import configparser
import functools
import io
import logging
import math
import os
import pickle
import queue
import re
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import can
import canopen
from canopen.emcy import EmcyError
from canopen.nmt import NmtError
from canopen.objectdictionary import ObjectDictionaryError
from canopen.profiles.p402 import BaseNode402, State402
from canopen.sdo.exceptions import SdoAbortedError, SdoError

from agf.axis import Axis, AxisFeedback, AxisLimits, AxisState
from agf.clock import Clock, Periodic, SimulatedClock, WallClock
from agf.config import child, section_from_mapping, unit
from agf.errors import ConfigError, DriveFault
from drivers.can_bus import handle_waiting, open_bus

logger = logging.getLogger(__name__)


class _ModeSetOnceBySdo(logging.Filter):
    """canopen warns, per node and pick, that the operation mode (0x6060/0x6061) is not in a PDO. This
    master sets the mode once at start-up by SDO and never mid-motion, so the PDOs stay small on purpose."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("Operation Mode")


logging.getLogger("canopen.profiles.p402").addFilter(_ModeSetOnceBySdo())

DEFAULT_EDS = Path(__file__).resolve().parents[1] / "configs" / "eds" / "agf_axis.eds"

#: EMCY error codes (CiA 301 / CiA 402) the drives of this project report, by name.
EMCY_NAMES: dict[int, str] = {
    0x1000: "generic error",
    0x2310: "continuous over-current",
    0x3210: "DC link over-voltage",
    0x3220: "DC link under-voltage",
    0x4310: "drive over-temperature",
    0x5441: "enable input (safe torque off) open",
    0x7121: "motor blocked",
    0x7305: "position encoder fault",
    0x8130: "master heartbeat lost (life guard / heartbeat error)",
    0x8611: "following error",
    0x8612: "limit switch reached",
    0xFF00: "injected fault (simulation)",
}

MODES = {"csp": 8, "pp": 1}

SDO_ATTEMPTS = 3  # tries per SDO request at start-up: a lost answer is retried, a dead drive is not waited on
# Feedback supervision while a motion is streamed, counted in SYNC cycles (exact, whatever the
# load): more than FEEDBACK_MISSING of FEEDBACK_WINDOW SYNCs without a TPDO1 answer is a fault; an
# answer may be FEEDBACK_GRACE cycles late. A single lost frame passes; 20 cycles of silence (a
# 200 ms burst at a 10 ms cycle) or 10 % frame loss does not.
FEEDBACK_WINDOW, FEEDBACK_MISSING, FEEDBACK_GRACE = 100, 10, 10
# SCHED_RR priorities (1..99) of the master's threads where the OS allows it: above every ordinary
# process, far below the kernel's own interrupt threads (50)
PRODUCER_PRIORITY, RECEIVE_PRIORITY, WATCHDOG_PRIORITY = 30, 29, 28
#: Wall seconds, on a simulated clock, that an SDO answer may take: the drives answer in this process,
#: at once (:class:`ClockedNetwork`), unless another thread drives the clock and settles it later.
SIMULATED_WAIT = 30.0

_STATUS_MASKS = {  # statusword -> collapsed axis state, order matters (fault bits first)
    AxisState.FAULT: ((0x4F, 0x08), (0x4F, 0x0F)),
    AxisState.ENABLED: ((0x6F, 0x27),),
    AxisState.QUICK_STOP: ((0x6F, 0x07),),
}


def raise_priority(thread: threading.Thread, priority: int) -> str:
    """Give a started ``thread`` real-time round-robin ``priority`` where the OS allows it, else nice -10.

    Linux schedules threads, not processes, so only that thread is raised. Returns what it got
    (``"SCHED_RR 30"``, ``"nice -10"`` or ``"normal"``); the last is logged once per thread.
    """
    tid = thread.native_id
    if tid is None:
        raise ValueError(f"thread {thread.name} is not started")
    try:
        os.sched_setscheduler(tid, os.SCHED_RR, os.sched_param(priority))
        return f"SCHED_RR {priority}"
    except (AttributeError, OSError):  # not Linux, or no CAP_SYS_NICE
        pass
    try:
        os.setpriority(os.PRIO_PROCESS, tid, -10)
        return "nice -10"
    except (AttributeError, OSError):
        logger.info("thread %s runs at normal priority (the OS refused a higher one)", thread.name)
        return "normal"


def raise_receive_priority(network: canopen.Network, priority: int = RECEIVE_PRIORITY) -> None:
    """Raise the priority of the thread(s) python-can's notifier reads ``network``'s bus with."""
    for reader in getattr(network.notifier, "_readers", []):
        if isinstance(reader, threading.Thread):
            raise_priority(reader, priority)


def _sdo_reason(exc: Exception) -> str:
    if isinstance(exc, SdoAbortedError):
        return f"SDO abort 0x{exc.code:08X} ({exc})"
    if isinstance(exc, SdoError) and "response" in str(exc).lower():
        return f"SDO timeout, no answer after {SDO_ATTEMPTS} attempts ({exc})"
    return str(exc)


def emcy_name(code: int) -> str:
    """Human name of an EMCY error code: ours first, then CiA 301's error class."""
    if code in EMCY_NAMES:
        return EMCY_NAMES[code]
    return EmcyError(code, 0, b"", 0.0).get_desc().lower() or "unknown error"


def _error_code_reason(code: int) -> str | None:
    """The drive's own error code (0x603F, in TPDO2): why it is in FAULT when its EMCY was lost."""
    return f"error code 0x{code:04X} {emcy_name(code)}" if code else None


def axis_state(statusword: int) -> AxisState:
    """Collapse a CiA 402 statusword into an :class:`AxisState`."""
    for state, masks in _STATUS_MASKS.items():
        if any(statusword & mask == value for mask, value in masks):
            return state
    return AxisState.DISABLED


# --------------------------------------------------------------------------------------------------
# object dictionaries


def load_object_dictionary(source: str | Path, node_id: int) -> canopen.ObjectDictionary:
    """Import an EDS, tolerating what vendor tools often write and canopen refuses.

    A DOMAIN object without ``DataType`` gets DOMAIN (0x000F) and a warning; a variable whose type
    cannot be known is dropped with a warning. Anything else raises a :class:`ConfigError` naming
    the file and the object.
    """
    path = Path(source)
    if not path.is_file():
        raise ConfigError(f"EDS file {path} not found")
    try:
        return pickle.loads(_imported_od(str(path), node_id, path.read_bytes()))
    except (configparser.Error, ObjectDictionaryError, KeyError, ValueError) as exc:
        logger.warning("%s: canopen refuses the EDS as it is (%s); importing it tolerantly", path, exc)
    parser = configparser.RawConfigParser()
    parser.optionxform = str  # EDS keys are case-sensitive for canopen
    try:
        parser.read_string(path.read_text(encoding="latin-1"))
    except configparser.Error as exc:
        raise ConfigError(f"EDS file {path}: not an INI file ({exc})") from exc
    _repair_eds(parser, path)
    text = io.StringIO()
    parser.write(text)
    text.seek(0)
    text.name = str(path)  # import_od picks the format from the name
    try:
        return canopen.import_od(text, node_id)
    except (configparser.Error, ObjectDictionaryError, KeyError, ValueError) as exc:
        raise ConfigError(f"EDS file {path}: cannot import object {exc}") from exc


@functools.lru_cache(maxsize=32)
def _imported_od(path: str, node_id: int, content: bytes) -> bytes:
    """canopen's import of the EDS at ``path`` (whose bytes are ``content``, so an edited file is imported
    anew), pickled: every node still gets a dictionary of its own, as from an import of its own. A simulated
    pick imports the EDS six times (three axes, three drives): 7 ms each, 0.4 ms to unpickle."""
    return pickle.dumps(canopen.import_od(path, node_id))


def _repair_eds(parser: configparser.RawConfigParser, path: Path) -> None:
    for section in parser.sections():
        if not re.fullmatch(r"[0-9A-Fa-f]{4}(sub[0-9A-Fa-f]+)?", section):
            continue
        entry = parser[section]
        object_type = int(entry.get("ObjectType", "0x7"), 0)
        if "DataType" in entry or object_type not in (0x2, 0x7):
            continue
        if object_type == 0x2:
            logger.warning("%s: object 0x%s (DOMAIN) has no DataType; using DOMAIN", path.name, section)
            entry["DataType"] = "0x000F"
            entry.setdefault("AccessType", "rw")
        else:
            logger.warning("%s: object 0x%s has no DataType; ignoring it", path.name, section)
            parser.remove_section(section)


# --------------------------------------------------------------------------------------------------
# configuration


@dataclass(frozen=True)
class LinearDriveSection:
    """One linear axis (lift, reach, side shift) in the ``drives.axes`` section; lengths in mm."""

    node_id: int
    counts_per_m: float
    minimum: float = unit("mm")
    maximum: float = unit("mm")
    max_velocity: float = unit("mm_s")
    max_acceleration: float = unit("mm_s2")
    max_jerk: float = unit("mm_s3")
    following_error: float = unit("mm", 0.05)
    kind: Literal["linear"] = "linear"
    eds: str | None = None
    mode: Literal["csp", "pp"] = "csp"

    @property
    def counts_per_unit(self) -> float:
        return self.counts_per_m


@dataclass(frozen=True)
class RotaryDriveSection:
    """One rotary axis (tilt) in the ``drives.axes`` section; angles in degrees."""

    node_id: int
    counts_per_rad: float
    minimum: float = unit("deg")
    maximum: float = unit("deg")
    max_velocity: float = unit("deg_s")
    max_acceleration: float = unit("deg_s2")
    max_jerk: float = unit("deg_s3")
    following_error: float = unit("deg", math.radians(2.0))
    kind: Literal["rotary"] = "rotary"
    eds: str | None = None
    mode: Literal["csp", "pp"] = "csp"

    @property
    def counts_per_unit(self) -> float:
        return self.counts_per_rad


@dataclass(frozen=True)
class DriveSettings:
    """One drive as the driver uses it: SI limits, scaling and where its EDS is."""

    name: str
    node_id: int
    eds: Path
    counts_per_unit: float
    limits: AxisLimits
    following_error: float
    mode: Literal["csp", "pp"] = "csp"

    def __post_init__(self) -> None:
        if not 1 <= self.node_id <= 127:
            raise ValueError(f"node_id must be 1..127, got {self.node_id}")
        if not (math.isfinite(self.counts_per_unit) and self.counts_per_unit != 0):
            raise ValueError(f"counts per unit must be finite and non-zero, got {self.counts_per_unit}")
        if not self.following_error > 0:
            raise ValueError(f"following_error must be positive, got {self.following_error}")


@dataclass(frozen=True)
class NetworkSettings:
    """What is shared by all drives of one bus (the ``drives`` section's top-level keys)."""

    cycle: float = unit("ms", 0.010)
    heartbeat: float = unit("ms", 0.100)
    master_node_id: int = 127

    def __post_init__(self) -> None:
        if not 0.001 <= self.cycle <= 0.1:
            raise ValueError(f"cycle_ms must be within 1..100 ms, got {self.cycle * 1e3} ms")
        if not 0.01 <= self.heartbeat <= 10.0:
            raise ValueError(f"heartbeat_ms must be within 10..10000 ms, got {self.heartbeat * 1e3} ms")
        if not 1 <= self.master_node_id <= 127:
            raise ValueError(f"master_node_id must be 1..127, got {self.master_node_id}")


def drive_settings_from_mapping(name: str, data: Any, where: str, base_dir: Path | None = None) -> DriveSettings:
    """Parse one entry of ``drives.axes`` (``kind: linear`` in mm, ``kind: rotary`` in degrees)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    kind = data.get("kind", "linear")
    sections = {"linear": LinearDriveSection, "rotary": RotaryDriveSection}
    if kind not in sections:
        raise ConfigError(f"{child(where, 'kind')}: expected one of {sorted(sections)}, got {kind!r}")
    section = section_from_mapping(sections[kind], data, where, base_dir)
    eds = DEFAULT_EDS if section.eds is None else Path(section.eds)
    if not eds.is_absolute() and base_dir is not None:
        eds = base_dir / eds
    if not eds.is_file():
        raise ConfigError(f"{child(where, 'eds')}: file {eds} does not exist")
    try:
        limits = AxisLimits(section.minimum, section.maximum, section.max_velocity,
                            section.max_acceleration, section.max_jerk)
        return DriveSettings(name, section.node_id, eds, section.counts_per_unit, limits,
                             section.following_error, section.mode)
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from exc


# --------------------------------------------------------------------------------------------------
# network


class ClockedNetwork(canopen.Network):
    """A ``canopen.Network`` whose periodic messages (SYNC, heartbeats) keep the given clock's time.

    On the wall clock they are python-can's periodic sends, and a notifier thread hands the frames
    received to canopen, as in canopen. On a simulated clock they are events of that clock, and the
    network has no notifier thread: the clock's settling hands every frame waiting on the bus (python-
    can's virtual bus) to canopen (:meth:`canopen.Network.notify`), in the thread that drives the clock,
    after each event and after each frame sent outside one. Every SYNC thus moves each drive one step
    and brings its TPDOs back before time moves on, and an SDO request has its answer when it returns,
    with no hand-off between threads (two a SYNC cycle were the largest cost of a simulated pick's
    control loop).
    """

    def __init__(self, bus: can.BusABC, clock: Clock) -> None:
        super().__init__(bus)
        self.clock = clock
        self._simulated = clock if isinstance(clock, SimulatedClock) else None
        self._settler: Periodic | None = None
        if self._simulated is not None:
            if not isinstance(getattr(bus, "queue", None), queue.Queue):
                raise ConfigError(f"a simulated clock needs python-can's virtual bus, not {bus.channel_info}")

    def connect(self, *args: Any, **kwargs: Any) -> ClockedNetwork:
        if self._simulated is None:
            return super().connect(*args, **kwargs)
        if self._settler is None:
            self._settler = self._simulated.add_settler(self._settle)
        return self

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        super().send_message(can_id, data, remote)
        if self._simulated is not None:
            self._simulated.settle()  # outside an event the frame is handled now, else when the event ends

    def send_periodic(self, can_id: int, data: bytes, period: float, remote: bool = False) -> Any:
        if self.clock.realtime:
            return super().send_periodic(can_id, data, period, remote)
        return _ClockedMessage(self, can_id, data, period)

    def disconnect(self) -> None:
        if self._settler is not None:
            self._settler.cancel()
            self._settler = None
        super().disconnect()

    def _settle(self) -> bool:
        """Hand every frame this node has received to canopen; whether there was none."""
        bus = self.bus  # None once disconnected, maybe by another thread (a drive going silent)
        return bus is None or handle_waiting(bus, self.listeners)


class _ClockedMessage:
    """canopen's ``PeriodicMessageTask`` interface (``stop``, ``update``) on a clock's events."""

    def __init__(self, network: canopen.Network, can_id: int, data: bytes, period: float) -> None:
        self._network, self._can_id, self.data = network, can_id, bytes(data)
        self._event = network.clock.every(period, self._send, f"can-0x{can_id:03X}")

    def _send(self) -> None:
        if self._network.bus is not None:
            self._network.send_message(self._can_id, self.data)

    def stop(self) -> None:
        self._event.cancel()

    def update(self, data: bytes) -> None:
        self.data = bytes(data)


class Cia402Network:
    """One CAN bus with its CiA 402 drives: canopen network, SYNC, master heartbeat, watchdog.

    Parameters
    ----------
    bus : can.BusABC
        An open python-can bus (see :func:`drivers.can_bus.open_bus`); closed by :meth:`close`.
    settings : NetworkSettings
        Cycle (SYNC period, s), heartbeat period (s) of master and drives, master node id.
    clock : Clock, optional
        The time SYNC, heartbeats and the watchdog keep; the wall clock by default (see
        :class:`ClockedNetwork` for a simulated one).
    """

    def __init__(self, bus: can.BusABC, settings: NetworkSettings, clock: Clock | None = None) -> None:
        self.settings = settings
        self.clock = clock or WallClock()
        self.network = ClockedNetwork(bus, self.clock)
        self.network.NOTIFIER_CYCLE = 0.02  # how long closing waits for the receive thread (0.1 s: 0.4 s a pick)
        self.network.connect()
        raise_receive_priority(self.network)
        self.axes: dict[str, Cia402Axis] = {}
        self.sim_drives: list[Any] = []  # drives started for it by a DriveStarter (simulated twins)
        self.syncs = 0  # SYNC frames sent
        self.bus_error: str | None = None  # why the bus failed, once it has
        self._heartbeat_on = self._sync_on = False
        self._stream: tuple[Callable[[float], Mapping[str, float]], int] | None = None  # (motion.at, first SYNC)
        self._stop = threading.Event()
        self._producer: threading.Thread | None = None
        self._clocked: list[Periodic] = []  # on a simulated clock: its SYNC, heartbeat and watchdog events
        # canopen gives the master no heartbeat-timeout callback: check every quarter heartbeat
        # period, so a silent drive is reported within 2.5 + 0.25 periods (< 3).
        watch_period = min(settings.heartbeat / 4, 0.05)
        if self.clock.realtime:
            self._watchdog: threading.Thread | None = threading.Thread(
                target=self._watch, args=(watch_period,), name="cia402-watchdog", daemon=True)
            self._watchdog.start()
            raise_priority(self._watchdog, WATCHDOG_PRIORITY)
        else:  # simulated time: the clock's events, run in the controller's thread; nothing stalls
            self._watchdog = None
            self._clocked.append(self.clock.every(watch_period, self._check_axes, "cia402-watchdog"))

    def add_axis(self, drive: DriveSettings, timeout: float = 5.0) -> Cia402Axis:
        """Configure drive ``drive`` over SDO, start it (NMT OPERATIONAL) and return its axis."""
        if drive.name in self.axes:
            raise ConfigError(f"drives: axis {drive.name!r} defined twice")
        axis = Cia402Axis(self, drive, timeout)
        self.axes[drive.name] = axis
        return axis

    def start(self) -> None:
        """Start the master heartbeat and the SYNC producer (once all axes are configured)."""
        self._heartbeat_on = self._sync_on = True
        if not self.clock.realtime:
            if not self._clocked[1:]:  # SYNC and heartbeat as events of the simulated clock
                every = self.clock.every
                self._clocked += [every(self.settings.cycle, self._clocked_step(self._send_sync), "cia402-sync"),
                                  every(self.settings.heartbeat, self._clocked_step(self._send_heartbeat),
                                        "cia402-heartbeat")]
            return
        if self._producer is None:
            self._producer = threading.Thread(target=self._produce, name="cia402-sync", daemon=True)
            self._producer.start()
            raise_priority(self._producer, PRODUCER_PRIORITY)

    def stop_master_heartbeat(self) -> None:
        """Stop sending the master's heartbeat (the drives will then quick-stop): for tests and shutdown."""
        self._heartbeat_on = False

    def stream(self, setpoints: Callable[[float], Mapping[str, float]] | None) -> None:
        """Send ``setpoints(t)`` (axis name -> m or rad) before every SYNC from now on, ``t`` counted in
        SYNC cycles from this call (s); None stops it, the targets stay where they are.

        The set-points of a motion are computed in the SYNC thread, so a busy controller thread (a
        measurement, a loaded CPU) never makes a drive's target stop and then jump. A fault on any
        axis ends the stream at once.
        """
        self._stream = None if setpoints is None else (setpoints, self.syncs)

    def stop_sync(self) -> None:
        """Stop sending SYNC (and with it the cyclic RPDOs): for tests and shutdown."""
        self._sync_on = False

    def close(self) -> None:
        """Disable every axis, stop SYNC and heartbeat, release the bus and simulated drives.

        The drives stop watching the master's heartbeat first, so an orderly shutdown leaves them
        disabled rather than faulted.
        """
        for axis in self.axes.values():
            axis.close()
        self._stop.set()
        for event in self._clocked:
            event.cancel()
        if self._producer is not None:
            self._producer.join(timeout=1.0)
        if self._watchdog is not None:
            self._watchdog.join(timeout=1.0)
        self.network.disconnect()
        for drive in self.sim_drives:
            drive.close()

    def _produce(self) -> None:
        # SYNC, the cyclic RPDOs and the master heartbeat from one thread of raised priority, on
        # absolute deadlines: a late cycle is skipped, never sent twice in a burst (the drives would
        # take two steps at once). It counts the SYNCs, so each axis knows how many feedback PDOs it
        # should have had; python-can's cyclic tasks give neither the count nor the priority.
        cycle, heartbeat = self.settings.cycle, self.settings.heartbeat
        next_sync = next_heartbeat = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                if now >= next_heartbeat:
                    self._send_heartbeat()
                    next_heartbeat = max(next_heartbeat + heartbeat, now)
                if now >= next_sync:
                    self._send_sync()
                    next_sync = max(next_sync + cycle, now)
            except can.CanError as exc:
                self._bus_failed(exc)
                return
            self._stop.wait(max(0.0, min(next_sync, next_heartbeat) - time.monotonic()))

    def _send_heartbeat(self) -> None:
        if self._heartbeat_on:
            self.network.send_message(0x700 + self.settings.master_node_id, [0x05])

    def _send_sync(self) -> None:
        if not self._sync_on:
            return
        self._stream_setpoints()
        for axis in list(self.axes.values()):
            axis._before_sync()
        self.network.send_message(0x80, b"")
        self.syncs += 1
        for axis in list(self.axes.values()):
            axis._after_sync()

    def _clocked_step(self, send: Callable[[], None]) -> Callable[[], None]:
        """``send`` as a simulated clock's event: a bus that fails ends SYNC and heartbeat."""
        def step() -> None:
            if self.bus_error is not None:
                return
            try:
                send()
            except can.CanError as exc:
                self._bus_failed(exc)
        return step

    def _stream_setpoints(self) -> None:
        stream = self._stream
        if stream is None:
            return
        setpoints, first = stream
        try:
            for name, value in setpoints((self.syncs - first) * self.settings.cycle).items():
                self.axes[name].send_setpoint(value)
        except DriveFault as exc:  # out of limits, or the axis is in fault: stop every axis' stream
            self._stream = None
            logger.warning("set-point stream stopped: %s", exc)

    def _bus_failed(self, exc: Exception) -> None:
        """The bus cannot send any more (adapter unplugged, bus-off): every axis is in fault."""
        if self.bus_error is None:
            self.bus_error = f"CAN bus gone ({exc})"
            logger.error("%s: no SYNC, no heartbeat, no set-point can be sent", self.bus_error)
        for axis in list(self.axes.values()):
            axis._raise_fault(self.bus_error)

    def _watch(self, period: float) -> None:
        # Time this thread was not scheduled (the process stalled: a loaded CPU, a long call holding
        # the GIL) is the master's silence, not the drive's: it is not counted against the drive.
        last = time.monotonic()
        while not self._stop.wait(period):
            now = time.monotonic()
            stalled, last = max(0.0, now - last - 2 * period), now
            self._check_axes(now, stalled)

    def _check_axes(self, now: float | None = None, stalled: float = 0.0) -> None:
        now = self.clock.monotonic() if now is None else now
        for axis in list(self.axes.values()):
            axis._check_alive(now, stalled)


# --------------------------------------------------------------------------------------------------
# axis


class Cia402Axis(Axis):
    """One CiA 402 drive as an :class:`Axis`; created by :meth:`Cia402Network.add_axis`."""

    def __init__(self, net: Cia402Network, drive: DriveSettings, timeout: float) -> None:
        super().__init__(drive.name, drive.limits)
        self.drive = drive
        self._net = net
        self._scale = drive.counts_per_unit
        self._fault: str | None = None
        self._last_heartbeat: float | None = None
        self._last_tpdo: float | None = None
        self._supervised = False
        self._pp_pending = False
        self._first_sync: int | None = None  # the SYNC the first TPDO1 answered
        self._tpdos = 0  # TPDO1s received since
        self._deficits: collections.deque[tuple[int, int]] = collections.deque(maxlen=FEEDBACK_WINDOW + 1)
        self._rejected = 0  # feedback PDOs of the wrong length or with an impossible position
        self._accepted: tuple[float, int] | None = None  # (time, position counts) of the last TPDO1 used
        self._silent = False  # the drive stopped answering: no orderly shutdown over SDO
        self._rpdo_lock = threading.Lock()  # RPDO1 is written by the caller and by the TPDO callback (PP)
        self._tpdo_arrived = threading.Event()
        self._heartbeat_arrived = threading.Event()
        od = load_object_dictionary(drive.eds, drive.node_id)
        self.node = BaseNode402(drive.node_id, od)
        net.network.add_node(self.node)
        self.node.nmt.add_heartbeat_callback(self._on_heartbeat)
        self.node.emcy.add_callback(self._on_emcy)
        self._step = "start-up"
        try:
            self._configure(timeout)
        except (SdoError, NmtError) as exc:
            raise DriveFault(f"axis {self.name} (node {drive.node_id}): start-up failed at {self._step}: "
                             f"{_sdo_reason(exc)}") from exc
        except can.CanError as exc:
            raise DriveFault(f"axis {self.name} (node {drive.node_id}): start-up failed, CAN bus gone ({exc})") from exc
        self._supervised = True

    # -- start-up (SDO, PRE-OPERATIONAL) -----------------------------------------------------------
    def _configure(self, timeout: float) -> None:
        node, settings = self.node, self._net.settings
        node.nmt.state = "PRE-OPERATIONAL"
        node.sdo.RESPONSE_TIMEOUT = max(0.3, min(timeout, 1.0)) if self._net.clock.realtime else SIMULATED_WAIT
        node.sdo.MAX_RETRIES = SDO_ATTEMPTS  # a lost SDO answer is asked again; canopen logs each retry
        self._step = "reading 0x1000 (device type)"
        device_type = node.sdo[0x1000].raw
        if device_type & 0xFFFF != 402:
            logger.warning("node %d: device type 0x%08X is not a CiA 402 drive", node.id, device_type)
        self._step = "writing 0x1017 (producer heartbeat)"
        node.sdo[0x1017].raw = round(settings.heartbeat * 1000)
        self._step = "waiting for its heartbeat"
        self._await_heartbeat(timeout)
        self._write_optional(0x1016, 1, settings.master_node_id << 16 | round(3 * settings.heartbeat * 1000))
        self._write_optional(0x1006, 0, round(settings.cycle * 1e6))
        self._step = "mapping the PDOs"
        self._map_pdos()
        self._write_drive_limits()
        self._step = f"setting the mode of operation (0x6060 = {MODES[self.drive.mode]})"
        self._set_mode(MODES[self.drive.mode], timeout)
        for pdo in (node.tpdo[1], node.tpdo[2]):
            pdo.callbacks.insert(0, self._check_frame)  # before BaseNode402 decodes it
        node.tpdo[1].add_callback(self._on_tpdo)
        self._step = "NMT OPERATIONAL"
        self._go_operational(timeout)
        self._last_tpdo = None

    def _go_operational(self, timeout: float) -> None:
        """NMT start, confirmed by the drive's own heartbeat: the command is unacknowledged, so a lost
        frame would leave the drive PRE-OPERATIONAL (no PDO ever) unless it is sent again."""
        node = self.node
        for _ in range(SDO_ATTEMPTS):
            node.nmt.state = "OPERATIONAL"
            for _ in range(2):  # the first heartbeat may have left before the command arrived
                self._await_heartbeat(timeout)
            if node.nmt.state == "OPERATIONAL":
                return
            logger.warning("axis %s: drive still %s after NMT start; sending it again", self.name, node.nmt.state)
        raise NmtError(f"the drive stayed {node.nmt.state} after {SDO_ATTEMPTS} NMT start commands")

    def _write_optional(self, index: int, subindex: int, value: int) -> None:
        od = self.node.object_dictionary
        if index not in od:
            logger.warning("axis %s: object 0x%04X not in the EDS; not written", self.name, index)
            return
        is_variable = isinstance(od[index], canopen.objectdictionary.ODVariable)
        entry = od[index] if is_variable else od[index][subindex]
        if not entry.writable:
            logger.warning("axis %s: object 0x%04X:%d is read-only; not written", self.name, index, subindex)
            return
        low, high = _type_range(entry)
        low = low if entry.min is None else max(low, entry.min)
        high = high if entry.max is None else min(high, entry.max)
        if not low <= value <= high:
            logger.warning("axis %s: 0x%04X:%d = %d outside the EDS range [%d, %d]; clamped",
                           self.name, index, subindex, value, low, high)
        variable = self.node.sdo[index] if is_variable else self.node.sdo[index][subindex]
        self._step = f"writing 0x{index:04X}:{subindex}"
        variable.raw = int(min(max(value, low), high))

    def _read_optional(self, index: int) -> int | None:
        if index not in self.node.object_dictionary:
            return None
        try:
            return self.node.sdo[index].raw
        except SdoAbortedError as exc:
            logger.warning("axis %s: cannot read 0x%04X (%s); not checked", self.name, index, exc)
            return None

    def _map_pdos(self) -> None:
        node = self.node
        node.rpdo.read()
        node.tpdo.read()
        layout = {  # (PDO map, objects) -- all synchronous: RPDO applied, TPDO sent, on each SYNC
            node.rpdo[1]: (0x6040, 0x607A),
            node.tpdo[1]: (0x6041, 0x6064),
            node.tpdo[2]: tuple(i for i in (0x606C, 0x6061, 0x603F) if i in node.object_dictionary),
        }
        for maps in (node.rpdo, node.tpdo):
            for number, pdo in maps.map.items():
                if number > 4:
                    continue
                objects = layout.get(pdo)
                pdo.enabled = objects is not None
                if objects is None:
                    continue
                pdo.clear()
                for index in objects:
                    pdo.add_variable(index)
                pdo.trans_type = 1
                pdo.cob_id = pdo.cob_id or ((0x200 if maps is node.rpdo else 0x180) + 0x100 * (number - 1) + node.id)
        node.rpdo.save()
        node.tpdo.save()
        node.setup_402_state_machine(read_pdos=False)

    def _write_drive_limits(self) -> None:
        limits, scale = self.limits, abs(self._scale)
        low, high = sorted((limits.minimum * self._scale, limits.maximum * self._scale))
        self._write_optional(0x607D, 1, math.floor(low))
        self._write_optional(0x607D, 2, math.ceil(high))
        self._write_optional(0x607F, 0, math.ceil(limits.max_velocity * scale))
        self._write_optional(0x6081, 0, math.ceil(limits.max_velocity * scale))
        self._write_optional(0x6083, 0, math.ceil(limits.max_acceleration * scale))
        self._write_optional(0x6084, 0, math.ceil(limits.max_acceleration * scale))
        self._write_optional(0x6085, 0, math.ceil(2 * limits.max_acceleration * scale))
        self._write_optional(0x60C5, 0, math.ceil(limits.max_acceleration * scale))
        self._write_optional(0x6065, 0, math.ceil(self.drive.following_error * scale))
        self._write_optional(0x605A, 0, 6)  # quick stop: ramp down, then hold in QUICK STOP ACTIVE

    def _set_mode(self, mode: int, timeout: float) -> None:
        # BaseNode402.op_mode's setter only logs a failed switch: write, then read back 0x6061 ourselves
        supported = self._read_optional(0x6502)
        if supported is not None:
            if not supported >> (mode - 1) & 1:
                raise DriveFault(f"axis {self.name}: drive does not support mode {mode} (0x6502 = 0x{supported:X})")
        self.node.sdo[0x6060].raw = mode
        clock = self._net.clock
        deadline = clock.monotonic() + timeout
        while self.node.sdo[0x6061].raw != mode:
            if clock.monotonic() > deadline:
                raise DriveFault(f"axis {self.name}: drive did not switch to mode {mode} (0x6061)")
            clock.sleep(0.01)

    # -- Axis back end -------------------------------------------------------------------------------
    def _enable(self, timeout: float) -> None:
        statusword = self._fresh_statusword(timeout)
        if axis_state(statusword) is AxisState.FAULT:
            raise DriveFault(f"axis {self.name}: cannot enable, drive in fault ({self._fault or 'unknown'})")
        self._write_target(self.node.tpdo_values.get(0x6064, 0))  # hold the actual position
        path = {
            "SWITCH ON DISABLED": ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"),
            "READY TO SWITCH ON": ("SWITCHED ON", "OPERATION ENABLED"),
            "SWITCHED ON": ("OPERATION ENABLED",),
            "QUICK STOP ACTIVE": ("OPERATION ENABLED",),
            "OPERATION ENABLED": (),
        }
        current = self.node.state
        if current not in path:
            raise DriveFault(f"axis {self.name}: cannot enable from drive state {current}")
        for state in path[current]:
            self._transition(State402.CW_COMMANDS_CODE[state], state, timeout)
        self._fault = None
        self._silent = False
        self._first_sync, self._tpdos = None, 0
        self._deficits.clear()

    def _disable(self) -> None:
        self._controlword(State402.CW_DISABLE_VOLTAGE)

    def _quick_stop(self) -> None:
        self._controlword(State402.CW_QUICK_STOP)  # transition 11, not halt (bit 8)

    def _fault_reset(self, timeout: float) -> None:
        # reset_from_fault in canopen never confirms: raise bit 7 on a rising edge and check ourselves
        if axis_state(self._fresh_statusword(timeout)) is not AxisState.FAULT:
            return
        self._controlword(State402.CW_DISABLE_VOLTAGE)  # bit 7 low first, so the next write is an edge
        for _ in range(2):  # a TPDO already on its way may predate that write: wait for the one after
            self._fresh_statusword(timeout)
        self._transition(State402.CW_SWITCH_ON_DISABLED, "SWITCH ON DISABLED", timeout)
        self._fault = None

    def _send_setpoint(self, position: float) -> None:
        if self._fault is not None:
            raise DriveFault(f"axis {self.name}: in fault ({self._fault}); setpoint refused")
        self._write_target(round(position * self._scale))
        if self.drive.mode == "pp":
            # bit 4 (new set-point) must be seen rising at a SYNC: it stays high until the drive
            # acknowledges (statusword bit 12), then _on_tpdo drops it; bit 5 = change immediately
            self._pp_pending = True
            self._controlword(State402.CW_OPERATION_ENABLED | 0x0030)
        # CSP: the network sends RPDO1 with this target just before the next SYNC

    def _feedback(self) -> AxisFeedback:
        values = self.node.tpdo_values
        state = AxisState.FAULT if self._fault else axis_state(values.get(0x6041, 0))
        return AxisFeedback(
            position=values.get(0x6064, 0) / self._scale,
            velocity=values.get(0x606C, 0) / self._scale,
            state=state,
            timestamp=self._last_tpdo if self._last_tpdo is not None else math.nan,
            fault=self._fault or (_error_code_reason(values.get(0x603F, 0)) if state is AxisState.FAULT else None),
        )

    def wait_for_feedback(self, timeout: float = 1.0) -> AxisFeedback:
        """Block until the next TPDO1 arrives (one control cycle) and return the feedback."""
        self._await_tpdo(timeout)
        return self._feedback()

    def _close(self) -> None:
        self._supervised = False
        if self._silent or self._net.bus_error:
            return
        try:
            self._disable()
            for _ in range(2):  # the drive applies it at the next SYNC; its TPDO after that confirms
                self._await_tpdo(5 * self._net.settings.cycle)
            self._write_optional(0x1016, 1, 0)
        except (can.CanError, SdoError, DriveFault) as exc:
            logger.warning("axis %s: orderly shutdown incomplete: %s", self.name, exc)

    # -- helpers -----------------------------------------------------------------------------------
    def _write_target(self, counts: int) -> None:
        with self._rpdo_lock:
            self.node.rpdo[1][0x607A].raw = int(counts)

    def _controlword(self, value: int) -> None:
        # the controlword shares RPDO1 with the target; the drive applies it at the next SYNC. Sent
        # now, and again before every SYNC (_before_sync), so a lost frame costs one cycle
        try:
            with self._rpdo_lock:
                self.node.rpdo[1][0x6040].raw = value
                self.node.rpdo[1].transmit()
        except can.CanError as exc:
            self._net._bus_failed(exc)
            raise DriveFault(f"axis {self.name}: CAN bus gone, controlword 0x{value:04X} not sent ({exc})") from exc

    def _transition(self, controlword: int, state: str, timeout: float) -> None:
        self._controlword(controlword)
        deadline = self._net.clock.monotonic() + timeout
        while self.node.state != state:
            if self._net.clock.monotonic() > deadline:
                raise DriveFault(f"axis {self.name}: drive did not reach {state} (it is {self.node.state})")
            self._fresh_statusword(timeout)

    def _fresh_statusword(self, timeout: float) -> int:
        if not self._await_tpdo(timeout):
            raise DriveFault(f"axis {self.name}: no statusword from node {self.node.id} within {timeout} s")
        return self.node.statusword

    def _await_heartbeat(self, timeout: float) -> None:
        """Wait (on the network's clock) for the drive's next heartbeat; NmtError if none within ``timeout`` s."""
        self._heartbeat_arrived.clear()
        if not self._net.clock.wait(self._heartbeat_arrived, timeout):
            raise NmtError(f"no heartbeat within {timeout} s")

    def _await_tpdo(self, timeout: float) -> bool:
        """Wait (on the network's clock) for the next TPDO1; whether one came within ``timeout`` s."""
        self._tpdo_arrived.clear()
        return self._net.clock.wait(self._tpdo_arrived, timeout)

    # -- from the network's SYNC thread ---------------------------------------------------------------
    def _before_sync(self) -> None:
        if self._supervised:  # RPDO1 every cycle, as CSP masters do: the latest target and controlword
            with self._rpdo_lock:
                self.node.rpdo[1].transmit()

    def _after_sync(self) -> None:
        # Each SYNC is answered by one TPDO1. An answer may come late (a loaded machine, a busy bus):
        # only SYNCs older than FEEDBACK_GRACE cycles are expected to be answered. The deficit
        # (expected - received) grows by one per lost frame and never shrinks back.
        if not self._supervised or self._fault is not None or self._first_sync is None:
            return
        if self._net._stream is None:
            # at rest the heartbeat watchdog supervises the drive: a CPU-bound controller thread
            # (measuring; rendering in the simulated world) may delay feedback, not lose it
            self._deficits.clear()
            return
        expected = self._net.syncs - FEEDBACK_GRACE - self._first_sync
        self._deficits.append((expected - self._tpdos, self._tpdos))
        (first_deficit, first_count), (deficit, count) = self._deficits[0], self._deficits[-1]
        missing = deficit - first_deficit
        if missing <= FEEDBACK_MISSING:
            return
        rejected = (f", {self._rejected} rejected for their length or an impossible position"
                    if self._rejected else "")
        silent_since = self._deficits[-missing][1] if missing < len(self._deficits) else first_count
        if silent_since == count:  # one run of silence, not scattered losses
            self._silent = True
            age = self._net.clock.monotonic() - (self._last_heartbeat or math.nan)
            self._raise_fault(f"feedback lost: no TPDO for {missing + FEEDBACK_GRACE} SYNC cycles, last heartbeat "
                              f"{age * 1e3:.0f} ms ago (the drive silent or the bus interrupted){rejected}")
        else:
            self._raise_fault(f"CAN frames lost: {missing} of the last {len(self._deficits) - 1} SYNCs got no "
                              f"feedback PDO{rejected}")

    # -- callbacks (from the CAN notifier thread: never block, never SDO) -----------------------
    def _on_heartbeat(self, state: int) -> None:
        self._last_heartbeat = self._net.clock.monotonic()
        self._heartbeat_arrived.set()
        if state == 0 and self._supervised and self._fault is None:
            self._raise_fault("drive rebooted (boot-up message): its configuration and power state are lost")

    def _check_frame(self, pdo: Any) -> None:
        """Reject a feedback PDO of the wrong length, or one whose position the axis cannot have reached
        since the last one used (a corrupted or foreign frame of the right length). Raising stops
        canopen's callbacks: no value of a rejected frame reaches the feedback."""
        expected = sum(variable.length for variable in pdo.map) // 8
        if len(pdo.data) != expected:
            self._rejected += 1
            raise ValueError(f"axis {self.name}: TPDO 0x{pdo.cob_id:X} has {len(pdo.data)} bytes, its mapping "
                             f"{expected}: rejected")
        position = next((variable.raw for variable in pdo.map if variable.index == 0x6064), None)
        if position is None:
            return
        now = self._net.clock.monotonic()
        if self._accepted is not None:
            then, last = self._accepted
            # twice the top speed over the time since, plus two cycles: a frame a cycle late still passes
            reach = abs(self._scale) * 2 * self.limits.max_velocity * (max(now - then, 0.0)
                                                                       + 2 * self._net.settings.cycle)
            if abs(position - last) > reach + 1:
                self._rejected += 1
                raise ValueError(f"axis {self.name}: TPDO 0x{pdo.cob_id:X} position {position} counts is "
                                 f"{abs(position - last)} from the last ({last}), more than the axis can move "
                                 f"in {now - then:.3f} s: rejected")
        self._accepted = (now, position)

    def _on_tpdo(self, pdo: Any) -> None:
        self._last_tpdo = self._net.clock.monotonic()
        if self._first_sync is None:
            self._first_sync = self._net.syncs
        self._tpdos += 1
        if self._pp_pending and self.node.tpdo_values.get(0x6041, 0) & 0x1000:
            self._pp_pending = False
            self._controlword(State402.CW_OPERATION_ENABLED)
        self._tpdo_arrived.set()

    def _on_emcy(self, emcy: EmcyError) -> None:
        if emcy.code & 0xFF00 == 0:
            return  # error reset
        self._raise_fault(f"EMCY 0x{emcy.code:04X} {emcy_name(emcy.code)}")

    def _check_alive(self, now: float, stalled: float = 0.0) -> None:
        if not self._supervised or self._fault is not None:
            return
        if stalled and self._last_heartbeat is not None:
            self._last_heartbeat += stalled
        if stalled and self._last_tpdo is not None:
            self._last_tpdo += stalled
        heartbeat = self._net.settings.heartbeat
        if self._last_heartbeat is not None and now - self._last_heartbeat > 2.5 * heartbeat:
            silence = now - self._last_heartbeat
            if self._last_tpdo is not None and self._last_tpdo - self._last_heartbeat > 1.5 * heartbeat:
                # TPDOs sent after the next heartbeat was due: the drive talks, its heartbeats were lost
                self._raise_fault(f"CAN frames lost: no heartbeat for {silence:.3f} s while the drive's TPDOs "
                                  "still arrive")
                return
            self._silent = True
            self._raise_fault(f"heartbeat lost (silent for {silence:.3f} s)")
            return
        tpdo_timeout = max(10 * self._net.settings.cycle, 2.5 * heartbeat)
        if self._net._stream is not None and self._last_tpdo is not None and now - self._last_tpdo > tpdo_timeout:
            self._raise_fault(f"TPDO feedback lost (none for {now - self._last_tpdo:.3f} s)")

    def _raise_fault(self, reason: str) -> None:
        self._net._stream = None  # no further set-point for any axis; the controller quick-stops them
        self._fault = reason
        fault = DriveFault(f"axis {self.name} (node {self.node.id}): {reason}")
        logger.warning("%s", fault)
        self._report_fault(fault)


def _type_range(entry: canopen.objectdictionary.ODVariable) -> tuple[int, int]:
    bits = len(entry)
    if entry.data_type in canopen.objectdictionary.SIGNED_TYPES:
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


# --------------------------------------------------------------------------------------------------
# factory


#: Starts drives for a network before the master configures them (the config's ``plugins.drives``):
#: ``(drives, bus mapping, network settings, where[, clock=]) -> started drives``, each with ``close()``;
#: ``clock`` is passed only when it is a simulated one (only drives simulated in this process keep it).
DriveStarter = Callable[..., list[Any]]


def axes_from_config(
    drives_mapping: Any,
    bus_mapping: Any,
    where: str,
    base_dir: Path | None = None,
    timeout: float = 5.0,
    start_drives: DriveStarter | None = None,
    bus_wrapper: Callable[[can.BusABC], can.BusABC] | None = None,
    clock: Clock | None = None,
) -> tuple[Cia402Network, dict[str, Axis]]:
    """Open the bus, configure the drives of the ``drives`` section and return the network and its axes.

    ``start_drives`` (the configuration's ``plugins.drives``; the default config names
    ``drivers.sim.drive:start_simulated_drives``) starts the drives first; a truck's drives are
    powered on their own and need none. The network closes what it started.
    ``bus_wrapper`` wraps the master's connection (e.g. :class:`drivers.lossy_bus.LossyBus`).
    Master and started drives keep ``clock``'s time (the wall clock by default); a simulated clock
    needs drives started in this process on python-can's virtual bus, unwrapped.
    """
    if not isinstance(drives_mapping, Mapping):
        raise ConfigError(f"{where} drives: expected a mapping, got {type(drives_mapping).__name__}")
    axes_data = drives_mapping.get("axes")
    if not isinstance(axes_data, Mapping) or not axes_data:
        raise ConfigError(f"{child(where + ' drives', 'axes')}: expected a mapping of axis name -> drive")
    top = {k: v for k, v in drives_mapping.items() if k != "axes"}
    settings = section_from_mapping(NetworkSettings, top, f"{where} drives", base_dir)
    drives = [drive_settings_from_mapping(str(name), data, child(f"{where} drives.axes", name), base_dir)
              for name, data in axes_data.items()]
    ids = [d.node_id for d in drives] + [settings.master_node_id]
    if len(set(ids)) != len(ids):
        raise ConfigError(f"{where} drives: node ids must be unique (master included), got {ids}")
    clock = clock or WallClock()
    if not clock.realtime and (start_drives is None or bus_wrapper is not None):
        raise ConfigError(f"{where} drives: a simulated clock needs drives simulated in this process (plugins.drives) "
                          "on an unwrapped bus")
    started = {} if clock.realtime else {"clock": clock}
    sim_drives = start_drives(drives, bus_mapping, settings, where, **started) if start_drives is not None else []
    bus = open_bus(bus_mapping, f"{where} bus")
    net = Cia402Network(bus if bus_wrapper is None else bus_wrapper(bus), settings, clock)
    net.sim_drives = sim_drives
    try:
        for drive in drives:
            net.add_axis(drive, timeout)
        net.start()
    except Exception:
        net.close()
        raise
    return net, dict(net.axes)
