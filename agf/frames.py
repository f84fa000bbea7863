"""The frame-source protocol: where fisheye frames come from (camera, file, replay, simulation).

``agf`` declares it; ``drivers/camera_source.py`` and the simulated world implement it. As with the
axis protocol, back ends override ``_read`` only; :meth:`FrameSource.read` checks what comes back.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from agf.errors import AgfError, NotAvailableError


class FrameLost(AgfError):
    """No usable frame arrived within the timeout (camera unplugged, replay exhausted, bad data)."""


# A frame this dark or this bright holds no edges to measure: refused before measuring (the lens
# covered, a light failed, the sun in the lens). Fisheye frames have black corners: the dark test
# looks at the brightest 1 %, the bright one at the share of saturated pixels.
DARK_LEVEL, BRIGHT_LEVEL, SATURATED_SHARE = 16, 250, 0.5


def exposure_problem(image: NDArray[np.uint8]) -> str | None:
    """Why ``image`` (H x W [x 3] uint8) cannot be measured: black or saturated; None if neither."""
    sample = image[::4, ::4]
    if np.percentile(sample, 99) < DARK_LEVEL:
        return f"black frame (99 % of the pixels below {DARK_LEVEL}): lens covered or no light"
    saturated = float(np.mean(sample >= BRIGHT_LEVEL))
    if saturated > SATURATED_SHARE:
        return f"saturated frame ({saturated:.0%} of the pixels at {BRIGHT_LEVEL} or more): overexposed"
    return None


class JpegImage(NamedTuple):
    """A frame as a camera sent it compressed: the ``image`` its JPEG ``data`` decode to (what is measured)."""

    image: NDArray[np.uint8]
    data: bytes


def pixels_sent(sent: NDArray[np.uint8] | JpegImage) -> NDArray[np.uint8]:
    """The pixels a receiver of a camera's output ``sent`` measures: a JPEG's decoding, else the pixels themselves."""
    return sent.image if isinstance(sent, JpegImage) else sent


@dataclass(frozen=True)
class Frame:
    """One fisheye frame: BGR or grey uint8 pixels, when it was taken (monotonic s), its number, and the JPEG
    the camera sent when it sent one (``image`` is its decoding: the recorder keeps the JPEG, exact and small)."""

    image: NDArray[np.uint8]
    timestamp: float
    index: int
    jpeg: bytes | None = None


class FrameSource(ABC):
    """A source of fisheye frames of one camera model's size."""

    # The exposure a source may be set to, as a multiple of its configured one.
    EXPOSURE_RANGE = (0.05, 1.0)

    def __init__(self, width: int, height: int) -> None:
        self.width, self.height = width, height
        self.exposure = 1.0  # a multiple of the configured exposure
        self._count = 0

    def read(self, timeout: float = 1.0) -> Frame:
        """The next frame; :class:`FrameLost` with the reason if none arrives, it has the wrong size, or it
        is black or saturated."""
        sent = self._read(timeout)
        image, jpeg = pixels_sent(sent), sent.data if isinstance(sent, JpegImage) else None
        if image is None:
            raise FrameLost(f"{self.describe()}: no frame within {timeout:.2f} s")
        if image.shape[:2] != (self.height, self.width) or image.dtype != np.uint8:
            raise FrameLost(
                f"{self.describe()}: frame is {image.shape[1]} x {image.shape[0]} {image.dtype}, "
                f"expected {self.width} x {self.height} uint8 (the camera model's size)"
            )
        problem = exposure_problem(image)
        if problem is not None:
            raise FrameLost(f"{self.describe()}: {problem}")
        self._count += 1
        return Frame(image, time.monotonic(), self._count, jpeg)

    def set_exposure(self, scale: float) -> None:
        """Expose the next frames ``scale`` times as long as configured (1: as configured; shorter only, in
        ``EXPOSURE_RANGE``): clipped highlights where the vision reads its edges are measured again darker.

        Raises
        ------
        ValueError
            If ``scale`` is outside ``EXPOSURE_RANGE``.
        NotAvailableError
            If the source cannot change its exposure (a file, a replay).
        """
        low, high = self.EXPOSURE_RANGE
        if not low <= scale <= high:
            raise ValueError(f"exposure scale: expected {low}..{high} (a multiple of the configured one), got {scale}")
        self._set_exposure(scale)
        self.exposure = scale

    def describe(self) -> str:
        return type(self).__name__

    def _set_exposure(self, scale: float) -> None:
        """Back ends that can change their exposure override this (see :meth:`set_exposure`)."""
        raise NotAvailableError(f"{self.describe()} cannot change its exposure")

    def close(self) -> None:  # noqa: B027 - optional hook: files and simulations hold nothing
        """Release the device or file."""

    @abstractmethod
    def _read(self, timeout: float) -> NDArray[np.uint8] | JpegImage | None:
        """One frame (a :class:`JpegImage` when the camera sent it compressed), or None when none is available
        within ``timeout`` s."""
