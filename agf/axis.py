"""The axis protocol: what the controller needs from one fork axis (lift, reach, tilt, side shift).

``agf`` declares it; ``drivers/cia402_axis.py`` implements it over CANopen, and the simulated world
uses the same driver against simulated drives. As in python-can's ``BusABC``, the public methods do
the checks once for every back end (software limits, fault bookkeeping) and a back end overrides
the private ``_`` methods only.

Units are SI: metres for linear axes, radians for tilt.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

from agf.errors import DriveFault


class AxisState(enum.Enum):
    """Power state of an axis, collapsed from the CiA 402 state machine."""

    DISABLED = "disabled"
    ENABLED = "enabled"
    QUICK_STOP = "quick_stop"
    FAULT = "fault"


@dataclass(frozen=True)
class AxisLimits:
    """Software limits of one axis, SI units (m, m/s, ... or rad, rad/s, ...)."""

    minimum: float
    maximum: float
    max_velocity: float
    max_acceleration: float
    max_jerk: float

    def __post_init__(self) -> None:
        values = (self.minimum, self.maximum, self.max_velocity, self.max_acceleration, self.max_jerk)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"axis limits must be finite, got {self}")
        if self.minimum >= self.maximum:
            raise ValueError(f"axis limits: minimum {self.minimum} must be below maximum {self.maximum}")
        if min(self.max_velocity, self.max_acceleration, self.max_jerk) <= 0:
            raise ValueError(f"axis limits: velocity, acceleration and jerk must be positive, got {self}")

    def contains(self, position: float) -> bool:
        return self.minimum <= position <= self.maximum

    def scaled(self, share: float) -> AxisLimits:
        """These limits with velocity, acceleration and jerk cut to ``share`` (0..1] of theirs: what a
        plan may ask, so that a drive that lost a cycle still has headroom to catch up."""
        if not 0 < share <= 1:
            raise ValueError(f"motion share must be in (0, 1], got {share}")
        return dataclasses.replace(self, max_velocity=share * self.max_velocity,
                                   max_acceleration=share * self.max_acceleration, max_jerk=share * self.max_jerk)


@dataclass(frozen=True)
class AxisFeedback:
    """One reading of an axis: actual position and velocity (SI), its state, and when (monotonic s)."""

    position: float
    velocity: float
    state: AxisState
    timestamp: float
    fault: str | None = None


FaultListener = Callable[[str, DriveFault], None]


class Axis(ABC):
    """One fork axis. Back ends implement the ``_`` methods; the public ones check and dispatch."""

    def __init__(self, name: str, limits: AxisLimits) -> None:
        self.name = name
        self.limits = limits
        self._listeners: list[FaultListener] = []
        self._lock = threading.Lock()

    # -- public API -------------------------------------------------------------------------------
    def enable(self, timeout: float = 2.0) -> None:
        """Bring the axis to OPERATION ENABLED holding its actual position; raise DriveFault if it cannot."""
        self._enable(timeout)

    def disable(self) -> None:
        """Remove power from the axis (brakes engage on a real truck)."""
        self._disable()

    def quick_stop(self) -> None:
        """Stop with the drive's quick-stop deceleration and hold; no further motion until re-enabled."""
        self._quick_stop()

    def fault_reset(self, timeout: float = 2.0) -> None:
        """Acknowledge a fault; the axis ends in a disabled state, never moving by itself."""
        self._fault_reset(timeout)

    def send_setpoint(self, position: float) -> None:
        """Stream one position setpoint (m or rad), refused before anything is sent if out of limits."""
        if not math.isfinite(position):
            raise DriveFault(f"axis {self.name}: setpoint {position} is not a finite number")
        if not self.limits.contains(position):
            raise DriveFault(
                f"axis {self.name}: setpoint {position:.4f} outside software limits "
                f"[{self.limits.minimum:.4f}, {self.limits.maximum:.4f}]"
            )
        self._send_setpoint(position)

    def feedback(self) -> AxisFeedback:
        """The latest actual position, velocity and state."""
        return self._feedback()

    def add_fault_listener(self, listener: FaultListener) -> None:
        """Call ``listener(axis_name, fault)`` from the back end's thread whenever a fault is seen."""
        with self._lock:
            self._listeners.append(listener)

    def close(self) -> None:
        """Release the back end's resources; the axis is not usable afterwards."""
        self._close()

    # -- for back ends ----------------------------------------------------------------------------
    def _report_fault(self, fault: DriveFault) -> None:
        with self._lock:
            listeners = list(self._listeners)
        for listener in listeners:
            listener(self.name, fault)

    @abstractmethod
    def _enable(self, timeout: float) -> None: ...

    @abstractmethod
    def _disable(self) -> None: ...

    @abstractmethod
    def _quick_stop(self) -> None: ...

    @abstractmethod
    def _fault_reset(self, timeout: float) -> None: ...

    @abstractmethod
    def _send_setpoint(self, position: float) -> None: ...

    @abstractmethod
    def _feedback(self) -> AxisFeedback: ...

    def _close(self) -> None:  # noqa: B027 - optional hook, most back ends hold nothing to release
        """Nothing to release by default."""
