"""Frame sources read real files through OpenCV; bad sources and wrong sizes are named errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from agf.errors import ConfigError, NotAvailableError
from agf.frames import FrameLost
from drivers.camera_source import Folder, ImageFile, Video, frame_source_from_config, split_dual_fisheye


def frame(value: int, w: int = 64, h: int = 48) -> np.ndarray:
    image = np.full((h, w, 3), value, np.uint8)
    image[:, : w // 2, 0] = 10  # tell the halves of a dual-fisheye frame apart
    return image


def test_folder_replays_in_order_then_reports_frame_lost(tmp_path):
    for i, value in enumerate((50, 100, 150)):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), frame(value))
    source = Folder(tmp_path, 64, 48)
    assert [int(source.read().image[0, -1, 1]) for _ in range(3)] == [50, 100, 150]
    with pytest.raises(FrameLost, match="no frame"):
        source.read()


def test_image_of_the_wrong_size_is_frame_lost(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), frame(80))
    with pytest.raises(FrameLost, match="expected 100 x 100"):
        ImageFile(tmp_path / "a.png", 100, 100).read()


def test_dual_fisheye_halves():
    both = frame(90, w=128, h=64)
    assert split_dual_fisheye(both, "front").shape == (64, 64, 3)
    assert split_dual_fisheye(both, "front")[0, 0, 0] == 10
    assert split_dual_fisheye(both, "back")[0, 0, 0] == 90


def test_video_file_frames(tmp_path):
    path = tmp_path / "pick.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for value in (40, 120, 200):
        writer.write(frame(value))
    writer.release()
    source = Video(str(path), 64, 48)
    values = [int(source.read().image[0, -1, 1]) for _ in range(3)]
    assert values == pytest.approx([40, 120, 200], abs=6)  # MJPEG is lossy
    with pytest.raises(FrameLost):
        source.read()
    source.close()


def one_frame_video(tmp_path) -> Video:
    path = tmp_path / "pick.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    writer.write(frame(100))
    writer.release()
    return Video(str(path), 64, 48)


def test_a_video_file_cannot_change_its_exposure(tmp_path):
    source = one_frame_video(tmp_path)
    with pytest.raises(NotAvailableError, match="cannot change its exposure"):
        source.set_exposure(0.6)
    assert source.exposure == 1.0
    source.close()


class ExposureDevice:
    """Stands in for a V4L2 device's capture (none on this machine): its CAP_PROP_EXPOSURE, set or refused."""

    def __init__(self, exposure: float, settable: bool = True) -> None:
        self.exposure, self.settable, self.written = exposure, settable, []

    def get(self, prop):
        assert prop == cv2.CAP_PROP_EXPOSURE
        return self.exposure

    def set(self, prop, value):
        self.written.append((prop, value))
        if self.settable:
            self.exposure = value
        return self.settable


def test_a_video_device_sets_its_exposure_as_a_multiple_of_the_commissioned_one_and_back(tmp_path):
    source = one_frame_video(tmp_path)
    source.capture.release()
    source.capture = ExposureDevice(250.0)
    source.set_exposure(0.6)
    source.set_exposure(0.36)
    source.set_exposure(1.0)
    assert source.capture.written == [(cv2.CAP_PROP_EXPOSURE, pytest.approx(v)) for v in (150.0, 90.0, 250.0)]
    assert source.exposure == 1.0
    source.capture = ExposureDevice(250.0, settable=False)
    source._configured_exposure = None
    with pytest.raises(NotAvailableError, match=r"CAP_PROP_EXPOSURE 250"):
        source.set_exposure(0.6)


def test_missing_video_device_is_not_available():
    with pytest.raises(NotAvailableError, match="cannot be opened"):
        Video("/nonexistent/video.mp4", 64, 48)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"kind": "webcam"}, "kind: expected"),
        ({"kind": "image"}, "path: missing"),
        ({"kind": "image", "path": "nope.png"}, "does not exist"),
        ({"kind": "folder", "path": ".", "fps": 3}, "unknown"),
        ({"kind": "image", "path": ".", "lens": "left"}, "lens: expected"),
    ],
)
def test_bad_camera_source_config_names_the_key(tmp_path, data, message):
    with pytest.raises(ConfigError, match=message):
        frame_source_from_config(data, "agf.yaml: camera_source", 64, 48, base_dir=tmp_path)
