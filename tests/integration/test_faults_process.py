"""Faults of the controller's process: killed with kill -9 mid-motion, and starved of CPU (on the wall
clock, as a truck; and on the simulated clock, where load must change nothing).

The kill test runs ``agf run`` as a process of its own, with the three drives as processes of their
own on ``udp_multicast`` (a bus between processes, as the truck's CAN bus), kills the controller
while the forks move and watches the drives through their ``status`` command: they must stop by
themselves (their consumer of the master's heartbeat, 0x1016) and never move again.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from agf.clock import SimulatedClock
from agf.config import load_config
from agf.paths import DEFAULT_CONFIG
from agf.scene import load_scene
from drivers.sim.fault_bench import SCENE_PATH, FaultPick, replay_folder
from drivers.sim.world import SimulatedWorld
from tests.integration.test_drives import UDP_BUS, _multicast_loopback_works
from tests.integration.test_faults import rendered  # noqa: F401 - the session fixture

REPO = Path(__file__).resolve().parents[2]
STATUS = re.compile(r"^(?P<state>[A-Z ]+) mode \d+ position (?P<position>-?[\d.]+) error 0x(?P<error>[0-9A-F]+)")


def _config(tmp_path: Path) -> Path:
    """configs/agf.yaml with the bus on udp_multicast and the drives not started in-process."""
    config = yaml.safe_load((REPO / "configs" / "agf.yaml").read_text())
    base = REPO / "configs"
    vision = config["vision"]
    for key in ("camera", "calibration", "pallets"):
        vision[key] = str(base / vision[key])
    for axis in config["drives"]["axes"].values():
        axis["eds"] = str(base / axis["eds"])
    config["bus"] = {"interface": "udp_multicast", "port": UDP_BUS["port"] + 1}
    config["plugins"].pop("drives", None)  # the drives run in their own processes
    config["recorder"]["folder"] = str(tmp_path / "logs")
    path = tmp_path / "agf.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


class DriveProcess:
    """``python -m drivers.sim.drive`` with its ``status`` command."""

    def __init__(self, node_id: int, port: int) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "drivers.sim.drive", "--node-id", str(node_id), "--interface", "udp_multicast",
             "--port", str(port)], cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout.readline().startswith("ready")

    def status(self) -> dict[str, str]:
        self.proc.stdin.write("status\n")
        self.proc.stdin.flush()
        match = STATUS.match(self.proc.stdout.readline())
        assert match, "no status line"
        return {"state": match["state"], "position": float(match["position"]), "error": match["error"]}

    def close(self) -> None:
        self.proc.communicate("quit\n", timeout=10)


def test_controller_killed_mid_motion_drives_stop_by_themselves(tmp_path: Path) -> None:
    reason = _multicast_loopback_works()
    if reason:
        pytest.skip(f"udp_multicast unusable here: {reason}")
    config = _config(tmp_path)
    port = UDP_BUS["port"] + 1
    drives = [DriveProcess(n, port) for n in (1, 2, 3)]
    run = subprocess.Popen([sys.executable, "-m", "agf.cli", "run", "--config", str(config)], cwd=REPO,
                           env={**os.environ, "PYTHONPATH": str(REPO)}, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    try:
        lift = drives[0]
        start = lift.status()["position"]
        deadline = time.monotonic() + 60
        while abs(lift.status()["position"] - start) < 2000:  # 20 mm into the move to the start pose
            assert run.poll() is None and time.monotonic() < deadline, "agf run ended or never moved"
            time.sleep(0.01)
        run.send_signal(signal.SIGKILL)
        killed = time.monotonic()
        trace = []
        while time.monotonic() - killed < 2.0:
            trace.append((time.monotonic() - killed, [d.status() for d in drives]))
            time.sleep(0.02)
        last = trace[-1][1]
        rest = next(t for t, statuses in trace if all(abs(s["position"] - e["position"]) < 1
                                                      for s, e in zip(statuses, last, strict=True)))
        print(f"kill -9 -> every drive at rest: {rest * 1e3:.0f} ms")  # docs/reliability.md
        assert all(s["state"] == "FAULT" and s["error"] == "8130" for s in last), last  # master heartbeat lost
        for t, statuses in trace:  # no motion in the last second
            if t > 1.0:
                assert all(abs(s["position"] - e["position"]) < 1 for s, e in zip(statuses, last, strict=True))
    finally:
        run.kill()
        run.wait()
        for drive in drives:
            drive.close()


class Starved:
    """One busy process per core while the ``with`` block runs."""

    def __enter__(self) -> Starved:
        busy = [sys.executable, "-c", "while True: pass"]
        self.burners = [subprocess.Popen(busy) for _ in range(os.cpu_count() or 2)]
        return self

    def __exit__(self, *exc: object) -> None:
        for burner in self.burners:
            burner.kill()
            burner.wait()


def test_cpu_starvation_does_not_fault_a_pick(rendered, tmp_path: Path) -> None:  # noqa: F811
    """Wall-clock time, as on a truck: with every core kept busy for the whole pick it must still end in DONE."""
    with Starved(), FaultPick(replay_folder(tmp_path / "frames", [rendered["start"], rendered["aligned"]])) as pick:
        reaction = pick.run()
    assert reaction.result.ok, reaction.result.reason
    assert not reaction.collision


def _simulated_pick() -> tuple[bool, float, list[tuple]]:
    with SimulatedWorld(load_config(DEFAULT_CONFIG), load_scene(SCENE_PATH), SimulatedClock()) as world:
        result = world.controller().run()
    rows = [(row["state"], row["t"], row["setpoint"], row["actual"]) for row in result.log]
    return result.ok, world.min_clearance, rows


def test_cpu_starvation_leaves_a_simulated_pick_bit_for_bit_unchanged() -> None:
    """Simulated time (``agf simulate``): load is a property of the test bed, not of the truck, so a
    starved machine must give the same pick, every set-point and feedback at the same simulated time."""
    idle = _simulated_pick()
    with Starved():
        starved = _simulated_pick()
    assert idle[0], "the default pick must insert"
    assert starved == idle
