"""`python -m drivers.sim.drive` as a service: it keeps serving when standard input is closed (started with
`< /dev/null` or by a service manager), ends on SIGINT, SIGTERM or `quit`, and says why."""

from __future__ import annotations

import ast
import os
import signal
import subprocess
import sys
import time

import canopen
import pytest

from agf.errors import ConfigError
from agf.paths import repo_path
from drivers.can_bus import open_bus
from drivers.cia402_axis import DEFAULT_EDS, load_object_dictionary

PORT = 43000 + os.getpid() % 1000  # a bus of this test's own


def start(node_id: int, stdin: int) -> subprocess.Popen:
    command = [sys.executable, "-m", "drivers.sim.drive", "--node-id", str(node_id), "--interface", "udp_multicast",
               "--port", str(PORT)]
    proc = subprocess.Popen(command, cwd=repo_path("."), stdin=stdin, stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(repo_path("."))})
    assert proc.stdout.readline().startswith(f"ready node {node_id}")
    return proc


def answers(network: canopen.Network, node_id: int) -> bool:
    """Whether the drive answers an SDO read of its device type (0x1000)."""
    node = network.add_node(canopen.RemoteNode(node_id, load_object_dictionary(DEFAULT_EDS, node_id)))
    node.sdo.RESPONSE_TIMEOUT = 1.0
    try:
        node.sdo.upload(0x1000, 0)
        return True
    except canopen.SdoCommunicationError:
        return False
    finally:
        del network[node_id]


@pytest.fixture
def network():
    try:
        bus = open_bus({"interface": "udp_multicast", "port": PORT}, "test")
    except ConfigError as exc:
        pytest.skip(f"udp_multicast unusable here: {exc}")
    network = canopen.Network(bus)
    network.connect()
    yield network
    network.disconnect()


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_drive_without_standard_input_serves_until_a_signal_and_says_so(network, signum) -> None:
    proc = start(41, subprocess.DEVNULL)
    try:
        time.sleep(1.0)  # standard input ended long ago
        assert proc.poll() is None, "the drive ended when its standard input closed"
        assert answers(network, 41)
        proc.send_signal(signum)
        out, _ = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0
    assert "stopped node 41" in out and signal.Signals(signum).name in out
    assert not answers(network, 41)


def test_quit_on_standard_input_stops_the_drive_and_says_so() -> None:
    proc = start(42, subprocess.PIPE)
    out, _ = proc.communicate("status\nquit\n", timeout=10)
    assert proc.returncode == 0
    assert "SWITCH ON DISABLED" in out and "stopped node 42" in out and "quit on standard input" in out


def test_the_real_driver_does_not_know_its_simulated_twin() -> None:
    """Which drives start is the configuration's choice (plugins.drives), not the CiA 402 driver's."""
    tree = ast.parse(repo_path("drivers/cia402_axis.py").read_text())
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    imported |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    assert not any(name.startswith("drivers.sim") for name in imported), imported
