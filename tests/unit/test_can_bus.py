"""drivers.can_bus: buses from configuration mappings, errors naming the key, udp_multicast echo filter."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from agf.config import read_yaml, section_from_mapping
from agf.errors import ConfigError
from drivers.can_bus import OwnEchoFilter, open_bus
from drivers.cia402_axis import NetworkSettings, drive_settings_from_mapping

EXAMPLE = Path(__file__).resolve().parents[2] / "configs" / "examples" / "reach-truck.yaml"


def test_virtual_buses_on_one_channel_see_each_other() -> None:
    a = open_bus({"interface": "virtual", "channel": "unit-can-bus"}, "bus")
    b = open_bus({"interface": "virtual", "channel": "unit-can-bus", "bitrate": 500000}, "bus")
    try:
        a.send(can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False))
        msg = b.recv(1.0)
        assert msg is not None and msg.arbitration_id == 0x181 and bytes(msg.data) == b"\x01\x02"
    finally:
        a.shutdown()
        b.shutdown()


@pytest.mark.parametrize("mapping, message", [
    ("virtual", "expected a mapping"),
    ({"channel": "x"}, "bus.interface"),
    ({"interface": "no_such_can"}, "unknown python-can interface 'no_such_can'"),
    ({"interface": "virtual", "bitrate": 123}, "bus.bitrate"),
    ({"interface": "virtual", "bitrate": True}, "bus.bitrate"),
    ({"interface": "virtual", "channel": [1]}, "bus.channel"),
    ({"interface": "socketcan", "channel": "nocan9"}, "cannot open socketcan bus on channel 'nocan9'"),
])
def test_bad_bus_mapping_is_named(mapping: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        open_bus(mapping, "agf.yaml: bus")


class _LoopBus(can.BusABC):
    """A medium that echoes what is sent and also carries other senders' frames."""

    def __init__(self) -> None:
        self.queue: list[can.Message] = []
        super().__init__(channel="loop")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.queue.append(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return (self.queue.pop(0) if self.queue else None), False


def test_own_echo_is_dropped_but_same_frame_from_another_sender_is_kept() -> None:
    loop = _LoopBus()
    bus = OwnEchoFilter(loop)
    frame = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
    bus.send(frame)  # our SYNC, echoed by the medium
    loop.queue.append(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))  # someone else's
    assert bus.recv(0.0) is not None  # the first is ours and dropped; the second comes through
    assert bus.recv(0.0) is None
    bus.shutdown()


def test_reach_truck_example_parses() -> None:
    data = read_yaml(EXAMPLE)
    drives = data["drives"]
    settings = section_from_mapping(NetworkSettings, {k: v for k, v in drives.items() if k != "axes"}, "drives")
    assert settings.cycle == pytest.approx(0.004)
    axes = {name: drive_settings_from_mapping(name, d, f"drives.axes.{name}", EXAMPLE.parent)
            for name, d in drives["axes"].items()}
    assert axes["tilt"].limits.maximum == pytest.approx(0.10472, abs=1e-5)
    assert axes["lift"].limits.maximum == pytest.approx(2.95)
    assert axes["tilt"].mode == "pp" and axes["lift"].eds.is_file()
    assert data["bus"] == {"interface": "socketcan", "channel": "can0", "bitrate": 500000}
