"""Frame sources: an image file, a folder (replay of a logged pick), a video file, a V4L2/UVC device.

360 cameras such as the Ricoh Theta deliver both fisheyes side by side in one frame ("dual-fisheye"):
``lens: front | back`` takes the half the camera model was calibrated for.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from agf.config import child
from agf.errors import ConfigError, NotAvailableError
from agf.frames import FrameLost, FrameSource

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}


class ImageFile(FrameSource):
    """The same image file on every read (a still camera, for ``agf run`` on one logged frame)."""

    def __init__(self, path: Path, width: int, height: int, lens: str | None = None) -> None:
        super().__init__(width, height)
        self.path, self.lens = Path(path), lens

    def describe(self) -> str:
        return f"image {self.path}"

    def _read(self, timeout: float) -> NDArray[np.uint8] | None:
        return split_dual_fisheye(read_image(self.path), self.lens)


class Folder(FrameSource):
    """The images of a folder in name order, once: the replay of a logged pick."""

    def __init__(self, path: Path, width: int, height: int, lens: str | None = None) -> None:
        super().__init__(width, height)
        self.path, self.lens = Path(path), lens
        self.files = sorted(p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        self._next = 0
        if not self.files:
            raise ConfigError(f"{self.path}: no images ({', '.join(sorted(IMAGE_SUFFIXES))}) to replay")

    def describe(self) -> str:
        return f"folder {self.path}"

    def _read(self, timeout: float) -> NDArray[np.uint8] | None:
        if self._next >= len(self.files):
            return None
        self._next += 1  # a bad file is skipped, not read again: a retry takes the next frame
        return split_dual_fisheye(read_image(self.files[self._next - 1]), self.lens)


class Video(FrameSource):
    """Frames of a video file (``path``) or a V4L2/UVC device (``device`` index or /dev/videoN)."""

    def __init__(
        self,
        source: str | int,
        width: int,
        height: int,
        lens: str | None = None,
        capture_size: tuple[int, int] | None = None,
    ) -> None:
        super().__init__(width, height)
        self.source, self.lens = source, lens
        self._configured_exposure: float | None = None  # read at the first change (see _set_exposure)
        self.capture = cv2.VideoCapture(source)
        if not self.capture.isOpened():
            raise NotAvailableError(f"video source {source!r} cannot be opened (no such file or device)")
        if capture_size is not None:
            self.capture.set(cv2.CAP_PROP_FRAME_WIDTH, capture_size[0])
            self.capture.set(cv2.CAP_PROP_FRAME_HEIGHT, capture_size[1])

    def describe(self) -> str:
        return f"video {self.source}"

    def _set_exposure(self, scale: float) -> None:
        """The device's exposure (``CAP_PROP_EXPOSURE``, in the driver's units) at ``scale`` times the one it had
        at the first change: the one commissioning set. Its auto exposure must be off for this to act."""
        if self._configured_exposure is None:
            self._configured_exposure = float(self.capture.get(cv2.CAP_PROP_EXPOSURE))
        if self._configured_exposure <= 0 or not self.capture.set(
            cv2.CAP_PROP_EXPOSURE, self._configured_exposure * scale
        ):
            raise NotAvailableError(f"{self.describe()} cannot change its exposure (CAP_PROP_EXPOSURE "
                                    f"{self._configured_exposure:g}; a file, or a device in auto exposure)")

    def _read(self, timeout: float) -> NDArray[np.uint8] | None:
        ok, image = self.capture.read()
        return split_dual_fisheye(image, self.lens) if ok else None

    def close(self) -> None:
        self.capture.release()


def read_image(path: Path) -> NDArray[np.uint8]:
    """Decode an image file; :class:`FrameLost` naming the file if it is unreadable or a truncated JPEG.

    OpenCV decodes a JPEG cut short (a transfer interrupted) into a grey-filled image with only a
    warning: the end-of-image marker is checked first so such a frame never reaches the measurement.
    """
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FrameLost(f"{path}: cannot be read ({exc.strerror})") from exc
    if path.suffix.lower() in (".jpg", ".jpeg") and not data.rstrip(b"\0").endswith(b"\xff\xd9"):
        raise FrameLost(f"{path}: truncated JPEG ({len(data)} bytes, no end-of-image marker)")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise FrameLost(f"{path}: not a decodable image")
    return image


def split_dual_fisheye(image: NDArray[np.uint8], lens: str | None) -> NDArray[np.uint8]:
    """One lens of a side-by-side dual-fisheye frame: ``front`` is the left half, ``back`` the right."""
    if lens is None:
        return image
    half = image.shape[1] // 2
    return np.ascontiguousarray(image[:, :half] if lens == "front" else image[:, half:])


def frame_source_from_config(
    data: Mapping[str, Any], where: str, width: int, height: int, base_dir: Path | None = None
) -> FrameSource:
    """``camera_source: {kind: image | folder | video | v4l2, path | device, lens, capture_size}``."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping with 'kind'")
    kinds = ("image", "folder", "video", "v4l2")
    kind = data.get("kind")
    if kind not in kinds:
        raise ConfigError(f"{child(where, 'kind')}: expected one of {list(kinds)}, got {kind!r}")
    allowed = {"kind", "lens", "path" if kind != "v4l2" else "device", "capture_size"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; expected some of {sorted(allowed)}")
    lens = data.get("lens")
    if lens not in (None, "front", "back"):
        raise ConfigError(f"{child(where, 'lens')}: expected front or back (dual-fisheye frames), got {lens!r}")
    if kind == "v4l2":
        device = data.get("device", 0)
        size = data.get("capture_size")
        return Video(device, width, height, lens, tuple(size) if size else None)
    if "path" not in data:
        raise ConfigError(f"{child(where, 'path')}: missing")
    path = Path(data["path"])
    path = path if path.is_absolute() or base_dir is None else base_dir / path
    if not path.exists():
        raise ConfigError(f"{child(where, 'path')}: {path} does not exist")
    if kind == "image":
        return ImageFile(path, width, height, lens)
    if kind == "folder":
        return Folder(path, width, height, lens)
    return Video(str(path), width, height, lens)
