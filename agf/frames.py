"""The frame-source protocol: where fisheye frames come from (camera, file, replay, simulation).

``agf`` declares it; ``drivers/camera_source.py`` and the simulated world implement it. As with the
axis protocol, back ends override ``_read`` only; :meth:`FrameSource.read` checks what comes back.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agf.errors import AgfError


class FrameLost(AgfError):
    """No usable frame arrived within the timeout (camera unplugged, replay exhausted, bad data)."""


@dataclass(frozen=True)
class Frame:
    """One fisheye frame: BGR or grey uint8 pixels, when it was taken (monotonic s), its number."""

    image: NDArray[np.uint8]
    timestamp: float
    index: int


class FrameSource(ABC):
    """A source of fisheye frames of one camera model's size."""

    def __init__(self, width: int, height: int) -> None:
        self.width, self.height = width, height
        self._count = 0

    def read(self, timeout: float = 1.0) -> Frame:
        """The next frame; :class:`FrameLost` with the reason if none arrives or it has the wrong size."""
        image = self._read(timeout)
        if image is None:
            raise FrameLost(f"{self.describe()}: no frame within {timeout:.2f} s")
        if image.shape[:2] != (self.height, self.width) or image.dtype != np.uint8:
            raise FrameLost(
                f"{self.describe()}: frame is {image.shape[1]} x {image.shape[0]} {image.dtype}, "
                f"expected {self.width} x {self.height} uint8 (the camera model's size)"
            )
        self._count += 1
        return Frame(image, time.monotonic(), self._count)

    def describe(self) -> str:
        return type(self).__name__

    def close(self) -> None:  # noqa: B027 - optional hook: files and simulations hold nothing
        """Release the device or file."""

    @abstractmethod
    def _read(self, timeout: float) -> NDArray[np.uint8] | None:
        """One frame, or None when none is available within ``timeout`` s."""
