"""`agf replay` on small logs written here: what it reads from the log alone, and how it reports
agreement, a difference and a log it cannot replay."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from agf.cli import main
from agf.config import load_config
from agf.errors import InputError
from agf.frames import Frame
from agf.paths import DEFAULT_CONFIG
from agf.recorder import McapRecorder, MeasurementSetup, read_log
from agf.replay import replay_log
from tests.unit.test_recorder import measurement

SETUP = MeasurementSetup.from_config(load_config(DEFAULT_CONFIG))


def log_of_one_frame(path: Path, image: np.ndarray, measured: bool) -> Path:
    """A log of one frame and its logged measurement: refused, or a (made-up) pose."""
    with McapRecorder(path, SETUP) as log:
        frame = Frame(image, time.monotonic(), 1)
        log.frame(frame)
        if measured:
            log.measurement("measuring", frame, measurement())
        else:
            log.measurement("measuring", frame, None, "no pallet front face found in the search volume")
    return path


BLACK = np.zeros((1920, 1920, 3), np.uint8)  # the default camera's size; no pallet in it


def test_a_refusal_replays_as_a_refusal(tmp_path: Path) -> None:
    result = replay_log(read_log(log_of_one_frame(tmp_path / "refused.mcap", BLACK, measured=False)))
    assert result["ok"] and result["measurements"][0]["same"]
    assert "no pallet front face" in result["measurements"][0]["replayed"]["refusal"]


def test_a_logged_pose_that_today_is_refused_is_a_difference(tmp_path: Path, capsys) -> None:
    path = log_of_one_frame(tmp_path / "posed.mcap", BLACK, measured=True)
    assert main(["replay", str(path), "--json"]) == 1
    result = json.loads(capsys.readouterr().out)
    row = result["measurements"][0]
    assert not result["ok"] and not row["same"]
    assert row["logged"]["pallet_in_fork"]["z_mm"] == pytest.approx(227.0) and not row["replayed"]["ok"]


def test_a_frame_of_the_wrong_size_is_named(tmp_path: Path) -> None:
    path = log_of_one_frame(tmp_path / "small.mcap", BLACK[:48, :64], measured=False)
    with pytest.raises(InputError, match="frame 1 is 64 x 48, the logged camera model's frames are 1920 x 1920"):
        replay_log(read_log(path))


def test_a_log_without_its_setup_cannot_be_replayed(tmp_path: Path, capsys) -> None:
    from mcap.writer import Writer

    path = tmp_path / "bare.mcap"
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start()
        channel = writer.register_channel("/measurement", "json", 0)
        writer.add_message(channel, 0, json.dumps({"stage": "measuring", "frame": 1, "ok": False}).encode(), 0)
        writer.finish()
    assert main(["replay", str(path), "--json"]) == 2
    assert "no 'agf.measurement_setup' metadata record" in json.loads(capsys.readouterr().out)["error"]
