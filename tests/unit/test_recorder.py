"""The MCAP recorder: what a log holds, that Foxglove's schemas describe it, that a killed writer leaves
a readable file, and the retention rule of the log folder."""

from __future__ import annotations

import base64
import fcntl
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import cv2
import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from agf.axis import AxisFeedback, AxisState
from agf.config import load_config
from agf.errors import ConfigError, InputError
from agf.frames import Frame, FrameSource, JpegImage
from agf.geometry import Transform
from agf.insertion import InsertionPlan
from agf.measurement import PalletMeasurement
from agf.paths import DEFAULT_CONFIG, repo_path
from agf.recorder import (
    McapRecorder,
    MeasurementSetup,
    decode_frame,
    enforce_retention,
    open_pick_log,
    read_log,
)
from drivers.sim.render import jpeg_sent
from tests.config_copy import config_copy

CONFIG = load_config(DEFAULT_CONFIG)
SETUP = MeasurementSetup.from_config(CONFIG)
PALLET = Transform.from_euler(0.25, 0.01, 0.227, 0.0, math.radians(1.65), math.radians(0.5))


def measurement() -> PalletMeasurement:
    camera_in_fork = SETUP.camera_in_fork
    return PalletMeasurement(camera_in_fork.inverse() @ PALLET, PALLET, loaded=False, sigma_z=0.001,
                             sigma_pitch=math.radians(0.05), scores={"loaded": 0.1, "unloaded": 0.8},
                             timing_ms={"total": 900.0})


def feedback(position: float) -> dict[str, AxisFeedback]:
    return {"lift": AxisFeedback(position, 0.1, AxisState.ENABLED, time.monotonic()),
            "tilt": AxisFeedback(0.01, 0.0, AxisState.ENABLED, time.monotonic())}


def write_pick(path: Path) -> np.ndarray:
    image = np.random.default_rng(3).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    plan = InsertionPlan(True, None, {"lift": 0.8, "tilt": 0.02}, {"lift": 0.8, "tilt": 0.02}, 12.0, 0.9, PALLET)
    with McapRecorder(path, SETUP, context={"command": "test"}, flush_period=0.05,
                      fork_in_truck=lambda p: Transform.from_euler(0.0, 0.0, p["lift"], 0.0, p["tilt"], 0.0)) as log:
        log.state("connecting", "start")
        frame = Frame(image, time.monotonic(), 1)
        log.frame(frame)
        log.measurement("measuring", frame, measurement())
        log.plan(plan)
        for k in range(5):
            log.cycle("aligning", {"lift": 0.6 + k * 0.01, "tilt": 0.01}, feedback(0.6 + k * 0.009))
        log.can_frame(time.time(), 0x181, b"\x27\x12\x00\x00")
        log.measurement("verifying", frame, None, "no pallet edges found")
        log.state("fault", "abort", "verifying: no pallet edges found")
    return image


class _JpegCamera(FrameSource):
    """A camera that sends JPEG: the frame it sends is the decoding of its JPEG."""

    def __init__(self, pixels: np.ndarray) -> None:
        super().__init__(pixels.shape[1], pixels.shape[0])
        self.sent = jpeg_sent(pixels, 80)

    def _read(self, timeout: float) -> JpegImage:
        return self.sent


def test_a_frame_the_camera_sent_as_jpeg_is_logged_as_that_jpeg_and_decodes_to_the_pixels_measured(
    tmp_path: Path,
) -> None:
    pixels = cv2.GaussianBlur(np.random.default_rng(5).integers(0, 255, (96, 128, 3), dtype=np.uint8), (0, 0), 2.0)
    camera = _JpegCamera(pixels)
    frame = camera.read()
    assert frame.jpeg == camera.sent.data and frame.image is camera.sent.image
    assert not np.array_equal(frame.image, pixels)  # JPEG is lossy: what is measured is the decoding
    with McapRecorder(tmp_path / "pick.mcap", SETUP, context={"command": "test"}) as log:
        log.frame(frame)
    [logged] = read_log(tmp_path / "pick.mcap").on("/camera/image")
    assert logged.data["format"] == "jpeg"
    assert base64.b64decode(logged.data["data"]) == camera.sent.data
    assert np.array_equal(decode_frame(logged), frame.image)


def test_a_log_holds_every_event_and_foxglove_schemas_describe_it(tmp_path: Path) -> None:
    image = write_pick(tmp_path / "pick.mcap")
    with (tmp_path / "pick.mcap").open("rb") as stream:  # the seeking reader needs the footer: a closed log has it
        reader = make_reader(stream)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert topics["/camera/image"].name == "foxglove.CompressedImage"
        assert topics["/log"].name == "foxglove.Log" and topics["/tf"].name == "foxglove.FrameTransform"
        assert all(s.encoding == "jsonschema" for s in summary.schemas.values())
        assert all(c.message_encoding == "json" for c in summary.channels.values())
        for schema, _channel, message in reader.iter_messages():
            jsonschema.validate(json.loads(message.data), json.loads(schema.data))
    log = read_log(tmp_path / "pick.mcap")
    assert log.complete
    assert np.array_equal(decode_frame(log.on("/camera/image")[0]), image)  # lossless
    first, refused = (m.data for m in log.on("/measurement"))
    assert first["ok"] and first["pallet_in_fork"]["z_mm"] == pytest.approx(227.0)
    assert not refused["ok"] and refused["refusal"] == "no pallet edges found"
    assert [m.data["state"] for m in log.on("/state")] == ["connecting", "fault"]
    assert log.on("/state")[-1].data["reason"] == "verifying: no pallet edges found"
    assert any(m.data["level"] == 4 and "no pallet edges" in m.data["message"] for m in log.on("/log"))
    assert [m.data["setpoint"]["lift"] for m in log.on("/axes")] == pytest.approx([0.6, 0.61, 0.62, 0.63, 0.64])
    assert log.on("/plan")[0].data["align"] == {"lift": 0.8, "tilt": 0.02}
    assert log.on("/can")[0].data["id"] == 0x181 and log.on("/can")[0].data["data"] == "27120000"
    frames = {(m.data["parent_frame_id"], m.data["child_frame_id"]) for m in log.on("/tf")}
    assert frames == {("fork", "camera"), ("fork", "pallet"), ("truck", "fork")}
    assert log.metadata["agf.measurement_setup"]["pallet_type"] == CONFIG.vision.pallet_type
    assert log.attachments[f"camera/{CONFIG.vision.camera.name}"] == CONFIG.vision.camera.read_bytes()


def test_pallet_transform_quaternion_matches_the_pose(tmp_path: Path) -> None:
    write_pick(tmp_path / "pick.mcap")
    (pallet,) = [m.data for m in read_log(tmp_path / "pick.mcap").on("/tf") if m.data["child_frame_id"] == "pallet"]
    q = pallet["rotation"]
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    assert np.allclose(R, PALLET.rotation, atol=1e-9)
    assert [pallet["translation"][k] for k in "xyz"] == pytest.approx(PALLET.translation)


WRITER = textwrap.dedent("""
    import sys, time
    from agf.config import load_config
    from agf.paths import DEFAULT_CONFIG
    from agf.recorder import McapRecorder, MeasurementSetup
    log = McapRecorder(sys.argv[1], MeasurementSetup.from_config(load_config(DEFAULT_CONFIG)), flush_period=0.2)
    k = 0
    while True:
        log.note("info", f"{k} {time.time()}")
        print(k, time.time(), flush=True)
        k += 1
        time.sleep(0.005)
""")


def test_a_writer_killed_with_sigkill_leaves_its_log_readable_to_the_last_flush(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True,
                            cwd=repo_path("."), env={**os.environ, "PYTHONPATH": str(repo_path("."))})
    try:
        lines = [proc.stdout.readline() for _ in range(300)]  # 1.5 s or more of writing
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    killed_at = float(lines[-1].split()[1])
    log = read_log(path)
    assert not log.complete  # no footer: it was killed
    notes = [float(m.data["message"].split()[1]) for m in log.on("/log")]
    assert notes and notes == sorted(notes)
    assert killed_at - notes[-1] < 1.0  # flushed every 0.2 s; a loaded machine gets some slack


def test_a_file_that_is_not_mcap_is_a_clear_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(InputError, match="bad.mcap: not a readable MCAP log"):
        read_log(bad)


def make_logs(folder: Path, sizes: list[int]) -> list[Path]:
    paths = []
    for k, size in enumerate(sizes):
        path = folder / f"log-{k}.mcap"
        path.write_bytes(b"\0" * size)
        os.utime(path, (1_000_000 + k, 1_000_000 + k))  # log-0 the oldest
        paths.append(path)
    return paths


def test_retention_deletes_the_oldest_logs_first_down_to_the_cap(tmp_path: Path) -> None:
    logs = make_logs(tmp_path, [400, 300, 200, 100])
    (tmp_path / "notes.txt").write_bytes(b"\0" * 5000)  # not a log: never touched
    assert enforce_retention(tmp_path, 350) == logs[:2]
    assert sorted(tmp_path.glob("*.mcap")) == logs[2:]
    assert enforce_retention(tmp_path, 350) == []
    assert (tmp_path / "notes.txt").exists()


def test_retention_never_deletes_the_log_being_written(tmp_path: Path) -> None:
    logs = make_logs(tmp_path, [400, 300, 200])
    with logs[1].open("rb") as held:  # another recorder writing it
        fcntl.flock(held, fcntl.LOCK_EX)
        deleted = enforce_retention(tmp_path, 100, keep=logs[2])
    assert deleted == [logs[0]]
    assert logs[1].exists() and logs[2].exists()


def test_a_new_pick_log_makes_room_in_the_configured_folder(tmp_path: Path) -> None:
    config = load_config(config_copy(tmp_path, recorder={"folder": "logs", "max_total_mb": 0.0005}))
    (tmp_path / "logs").mkdir()
    old = make_logs(tmp_path / "logs", [800, 800])
    with open_pick_log(config, "run", MeasurementSetup.from_config(config)) as log:
        assert log.path.parent == tmp_path / "logs" and log.path.name.endswith("_run.mcap")
        assert not any(p.exists() for p in old)  # each alone is over the 500-byte cap
    assert read_log(log.path).complete


def test_a_log_folder_that_cannot_be_written_is_named(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("a file where the folder should be")
    config = load_config(config_copy(tmp_path, recorder={"folder": "file/logs"}))
    with pytest.raises(ConfigError, match="recorder.folder: cannot write a log in .*file/logs"):
        open_pick_log(config, "run", MeasurementSetup.from_config(config))


@pytest.mark.parametrize("recorder, message", [
    ({"flush_period_ms": 5000}, "recorder: flush_period_ms must be within 10..1000 ms"),
    ({"max_total_mb": 0}, "recorder: max_total_mb: must be positive"),
    ({"folder_mm": 3}, r"recorder: unknown key\(s\) \['folder_mm'\]"),
])
def test_bad_recorder_settings_are_named(tmp_path: Path, recorder: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(config_copy(tmp_path, recorder=recorder))
