"""A real pick's log: `agf run` in its own process, killed with SIGKILL while the forks move; its log read
back up to the kill, and `agf replay` on it (the same measurement, and a tampered one caught)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.writer import Writer

from agf.cli import main
from agf.paths import repo_path
from agf.recorder import SCHEMAS, TOPICS, PickLog, read_log
from agf.replay import replay_log
from tests.config_copy import config_copy, default_config

# one pytest-xdist worker runs them all: they share one killed pick
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("test_recorder_pick")]


def run_until_moving(config: Path) -> tuple[subprocess.Popen, list[str]]:
    """`agf run` in its own process, returned once the forks start aligning (or once it has ended)."""
    env = {**os.environ, "PYTHONPATH": str(repo_path("."))}
    proc = subprocess.Popen([sys.executable, "-m", "agf.cli", "run", "--config", str(config)], cwd=repo_path("."),
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if "agf run: aligning" in line:
            break
    return proc, lines


@pytest.fixture(scope="module")
def killed_pick(tmp_path_factory) -> tuple[PickLog, float]:
    """`agf run` killed 1.5 s into the align motion; its log and when it was killed (s since the epoch).

    This test is about the log of a moving pick, not about the drives' supervision, which today faults
    when other processes starve the simulated drives' threads: the drives get a 1 s heartbeat and wide
    following-error windows, and a pick that faults before moving anyway is run again (three times at most).
    """
    drives = default_config()["drives"]
    drives["heartbeat_ms"] = 1000
    for axis in drives["axes"].values():
        axis.update({"following_error_deg": 5} if axis["kind"] == "rotary" else {"following_error_mm": 500})
    for attempt in range(3):
        folder = tmp_path_factory.mktemp(f"pick{attempt}")
        config = config_copy(folder, drives=drives,
                             recorder={"folder": "logs", "max_total_mb": 500, "flush_period_ms": 200})
        proc, lines = run_until_moving(config)
        try:
            moving = bool(lines) and "agf run: aligning" in lines[-1]
            if moving:
                time.sleep(1.5)
        finally:
            killed_at = time.time()
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        if moving:
            (path,) = (folder / "logs").glob("*_run.mcap")
            return read_log(path), killed_at
    pytest.fail("agf run ended before moving the forks three times; the last time:\n" + "".join(lines))


def test_a_pick_killed_mid_motion_leaves_its_log_readable_up_to_the_kill(killed_pick) -> None:
    log, killed_at = killed_pick
    assert not log.complete
    assert [m.data["state"] for m in log.on("/state")][:4] == ["connecting", "acquiring", "measuring", "planning"]
    assert log.on("/measurement")[0].data["ok"] and log.on("/plan")[0].data["safe"]
    moving = [m for m in log.on("/axes") if m.data["state"] == "aligning"]
    assert len(moving) > 20  # cycles of the motion that was under way
    assert killed_at - moving[-1].log_time * 1e-9 < 1.0  # flushed every 0.2 s
    can = log.on("/can")
    assert {0x80, 0x77F} <= {m.data["id"] for m in can}  # SYNC and the master's heartbeat
    assert killed_at - can[-1].log_time * 1e-9 < 1.0


def test_replay_reproduces_the_logged_measurement(killed_pick) -> None:
    log, _ = killed_pick
    assert log.on("/camera/image")[0].data["format"] == "jpeg"  # as the simulated camera sent it
    result = replay_log(log)
    assert result["ok"], result
    assert result["measurements"][0]["stage"] == "measuring"
    assert result["max_difference"]["position_mm"] <= 0.05


def tampered(log: PickLog, out: Path, dz_mm: float) -> Path:
    """The log rewritten with its first measurement's height moved by ``dz_mm``."""
    with out.open("wb") as stream:
        writer = Writer(stream)
        writer.start()
        for name, data in log.metadata.items():
            writer.add_metadata(name, data)
        for name, data in log.attachments.items():
            writer.add_attachment(0, 0, name, "application/octet-stream", data)
        channels: dict[str, int] = {}
        first = True
        for m in log.messages:
            if m.topic not in channels:
                name = TOPICS[m.topic]
                schema = writer.register_schema(name, "jsonschema", json.dumps(SCHEMAS[name]).encode())
                channels[m.topic] = writer.register_channel(m.topic, "json", schema)
            data = m.data
            if m.topic == "/measurement" and first:
                pose = data["pallet_in_fork"]
                data = {**data, "pallet_in_fork": {**pose, "z_mm": pose["z_mm"] + dz_mm}}
                first = False
            writer.add_message(channels[m.topic], m.log_time, json.dumps(data).encode(), m.log_time, m.sequence)
        writer.finish()
    return out


def test_replay_catches_a_measurement_that_differs_from_the_log(killed_pick, tmp_path: Path, capsys) -> None:
    log, _ = killed_pick
    path = tampered(log, tmp_path / "tampered.mcap", dz_mm=0.5)
    assert main(["replay", str(path), "--json"]) == 1
    result = json.loads(capsys.readouterr().out)
    assert not result["ok"] and result["measurements"][0]["difference"]["z_mm"] == pytest.approx(-0.5, abs=0.05)


def test_replay_draws_the_pick_from_the_log_alone(killed_pick, tmp_path: Path, capsys) -> None:
    log, _ = killed_pick
    assert main(["replay", str(log.path), "--plots", str(tmp_path / "plots"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    names = sorted(Path(p).name for p in result["plots"])
    assert names[0].startswith("measurement-1-frame-") and "pick_axes.png" in names
    assert all(Path(p).stat().st_size > 10_000 for p in result["plots"])
