"""``agf bench`` cases of the CAN control loop (group ``control``): SYNC jitter and set-point latency.

Both run the real arrangement of a truck's bus on this machine: three simulated drives, each its own
process (``python -m drivers.sim.drive``), on ``udp_multicast``, and our master
(:class:`drivers.cia402_axis.Cia402Network`) in this process producing SYNC. The figures therefore
include Python scheduling of four processes and the UDP loopback, not a CAN controller's timing; a
real socketcan bus is measured with the same cases by pointing them at it (not done here).

Add ``drivers.sim.drive_bench`` to ``bench.modules`` in the configuration to run them.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import numpy as np

from agf.axis import AxisLimits
from agf.bench import bench_case
from drivers.can_bus import open_bus
from drivers.cia402_axis import DEFAULT_EDS, Cia402Axis, Cia402Network, DriveSettings, NetworkSettings

REPO = Path(__file__).resolve().parents[2]
# Linux hands a multicast datagram to every socket on its port whatever group it joined: the bench
# uses a port of its own so it never talks to a test's drives
PORT = 43199
NODE_IDS = {"lift": 41, "reach": 42, "tilt": 43}
SCALE = 100_000.0  # counts per metre
LIMITS = AxisLimits(0.0, 3.0, 0.5, 1.0, 5.0)


@contextlib.contextmanager
def _bench_bus(cycle: float) -> Iterator[tuple[Cia402Network, dict[str, Cia402Axis]]]:
    """Three drive processes and a started master network at ``cycle`` s."""
    procs = [subprocess.Popen([sys.executable, "-m", "drivers.sim.drive", "--node-id", str(n), "--interface",
                               "udp_multicast", "--port", str(PORT), "--cycle-ms", str(cycle * 1e3)],
                              cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
             for n in NODE_IDS.values()]
    net = None
    try:
        for proc in procs:
            if not proc.stdout.readline().startswith("ready"):
                raise RuntimeError("a simulated drive process did not start")
        net = Cia402Network(open_bus({"interface": "udp_multicast", "port": PORT}, "bench"),
                            NetworkSettings(cycle=cycle))
        axes = {name: net.add_axis(DriveSettings(name, n, DEFAULT_EDS, SCALE, LIMITS, 0.05))
                for name, n in NODE_IDS.items()}
        net.start()
        yield net, axes
    finally:
        if net is not None:
            net.close()
        for proc in procs:
            proc.communicate("quit\n", timeout=10)


def _percentiles_us(samples_s: np.ndarray) -> dict[str, float]:
    us = np.abs(samples_s) * 1e6
    return {"p50": float(np.percentile(us, 50)), "p99": float(np.percentile(us, 99)), "max": float(us.max()),
            "n": int(us.size)}


def _sync_jitter(cycle: float, seconds: float) -> dict[str, float]:
    """SYNC arrival-interval deviation from ``cycle``, seen by a separate receiver socket (kernel stamps)."""
    listener = can.Bus(interface="udp_multicast", port=PORT, fd=False)
    try:
        with _bench_bus(cycle) as (_, axes):
            for axis in axes.values():
                axis.enable()
            while listener.recv(0.0) is not None:
                pass  # start-up traffic
            stamps = []
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                msg = listener.recv(0.1)
                if msg is not None and msg.arbitration_id == 0x80:
                    stamps.append(msg.timestamp)
    finally:
        listener.shutdown()
    if len(stamps) < 10:
        raise RuntimeError(f"only {len(stamps)} SYNC frames received in {seconds} s")
    return _percentiles_us(np.diff(np.asarray(stamps)) - cycle)


@bench_case("control.sync_jitter_us", "control")
def sync_jitter_us(quick: bool) -> dict[str, Any]:
    """|SYNC interval - cycle| in µs at 10 ms and 4 ms cycles, three drive processes on udp_multicast."""
    seconds = 2.0 if quick else 10.0
    return {"cycle_10ms": _sync_jitter(0.010, seconds), "cycle_4ms": _sync_jitter(0.004, seconds),
            "drives": len(NODE_IDS), "interface": "udp_multicast", "seconds_each": seconds}


@bench_case("control.setpoint_latency_us", "control")
def setpoint_latency_us(quick: bool) -> dict[str, Any]:
    """From ``send_setpoint`` to the first TPDO whose position shows the drive acting on it, µs.

    It includes the wait for the next SYNC (the drive applies a synchronous RPDO there, CiA 301), so
    it lies between one transfer time and one cycle plus that; cycle 10 ms, three drive processes.
    """
    samples = []
    with _bench_bus(0.010) as (_, axes):
        axis = axes["lift"]
        axis.enable()
        target = axis.feedback().position
        for _ in range(20 if quick else 200):
            for _ in range(3):  # settle, and start at a random phase of the cycle
                axis.wait_for_feedback()
            time.sleep(float(np.random.default_rng(len(samples)).uniform(0.0, 0.010)))
            before = axis.feedback().position
            target += 2e-4
            start = time.monotonic()
            axis.send_setpoint(target)
            while True:
                feedback = axis.wait_for_feedback()
                if feedback.position > before + 1e-6 or time.monotonic() - start > 1.0:
                    break
            if feedback.position <= before + 1e-6:
                raise RuntimeError("the drive did not act on a setpoint within 1 s")
            samples.append(feedback.timestamp - start)
    return {**_percentiles_us(np.asarray(samples)), "cycle_ms": 10, "interface": "udp_multicast"}


if __name__ == "__main__":
    import json

    print(json.dumps({"sync": sync_jitter_us(True), "latency": setpoint_latency_us(True)}, indent=1))
