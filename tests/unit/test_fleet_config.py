"""The fleet section of the configuration, the broker password and the pick's search volume."""

from __future__ import annotations

import dataclasses
import re
import shutil
from pathlib import Path

import pytest
import yaml

from agf.config import load_config
from agf.errors import ConfigError
from agf.fleet.messages import RejectedMessage, parse_incoming, timestamp
from agf.fleet.pick import search_at_height
from agf.pallets import load_pallets
from agf.paths import REPO_ROOT
from drivers.mqtt_fleet import broker_password

CONFIGS = REPO_ROOT / "configs"
CONFIG = load_config(CONFIGS / "agf.yaml")


def _config_with(tmp_path: Path, change) -> Path:
    target = tmp_path / "configs"
    shutil.copytree(CONFIGS, target)
    path = target / "agf.yaml"
    data = yaml.safe_load(path.read_text())
    change(data["fleet"])
    path.write_text(yaml.safe_dump(data))
    return path


def test_fleet_section_loads_in_si_units():
    fleet = CONFIG.fleet
    assert (fleet.interface_name, fleet.state_period, fleet.height_window) == ("uagv", 30.0, pytest.approx(0.1))
    assert fleet.broker.port == 1883 and fleet.broker.keepalive == 15.0 and not fleet.broker.tls


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda f: f["broker"].update(password="secret"), r"fleet\.broker: unknown key\(s\) \['password'\]"),
        (lambda f: f.update(serial_number="truck/7"), r"fleet: serial_number: 'truck/7' may hold only"),
        (lambda f: f.update(state_period_s=60), r"fleet: state_period_s: .* at least every 30 s"),
        (lambda f: f["broker"].update(password_env="X"), r"fleet\.broker: a password needs a username"),
        (lambda f: f["broker"].update(port=70000), r"fleet\.broker: port: expected 1\.\.65535"),
    ],
)
def test_bad_fleet_keys_are_named(tmp_path, change, message):
    with pytest.raises(ConfigError, match=message):
        load_config(_config_with(tmp_path, change))


def test_password_comes_from_the_environment_or_a_file(tmp_path, monkeypatch):
    secret = tmp_path / "password"
    secret.write_text("s3cret\n")
    path = _config_with(tmp_path, lambda f: f["broker"].update(username="truck", password_file=str(secret)))
    assert broker_password(load_config(path).fleet.broker) == "s3cret"
    path = _config_with(tmp_path / "env", lambda f: f["broker"].update(username="truck", password_env="AGF_TEST_PW"))
    broker = load_config(path).fleet.broker
    monkeypatch.delenv("AGF_TEST_PW", raising=False)
    with pytest.raises(ConfigError, match="AGF_TEST_PW is not set"):
        broker_password(broker)
    monkeypatch.setenv("AGF_TEST_PW", "from-env")
    assert broker_password(broker) == "from-env"


def test_height_narrows_the_vertical_search_around_the_pallet_it_implies():
    pallet = load_pallets(CONFIG.vision.pallets)["jis-t11"]
    # The default scene: forks 0.65 m up, the pallet's front-face centre 227 mm above them, so its
    # underside (77 mm below that centre) is 0.800 m above the floor.
    search = search_at_height(CONFIG.vision.search, pallet, 0.800, 0.65, 0.1)
    assert (search.z_min, search.z_max) == (pytest.approx(0.127), pytest.approx(0.327))
    assert (search.x_min, search.yaw_max) == (CONFIG.vision.search.x_min, CONFIG.vision.search.yaw_max)
    clipped = search_at_height(CONFIG.vision.search, pallet, 1.05, 0.65, 0.1)  # near the top of the volume
    assert clipped.z_max == CONFIG.vision.search.z_max
    with pytest.raises(ValueError, match="outside the search volume"):
        search_at_height(CONFIG.vision.search, pallet, 3.0, 0.65, 0.1)


def test_regression_a_height_narrowed_search_follows_the_forks_as_they_rise():
    """CI, session 23: a fleet pick with a ``height`` was refused at verifying, "measured at z 0.0 mm, outside the
    search volume (z 127..327 mm)": the volume narrowed at the forks' start height stayed put in the fork frame
    while the forks rose level with the pallet."""
    pallet = load_pallets(CONFIG.vision.pallets)["jis-t11"]
    at_start = search_at_height(CONFIG.vision.search, pallet, 0.800, 0.65, 0.1)
    aligned = at_start.lifted(0.227)  # the forks rose by the face centre's height above them
    assert (aligned.z_min, aligned.z_max) == (pytest.approx(-0.1), pytest.approx(0.1))
    assert dataclasses.astuple(aligned.lifted(-0.227)) == pytest.approx(dataclasses.astuple(at_start))
    assert (aligned.x_min, aligned.x_max, aligned.pitch_max) == (at_start.x_min, at_start.x_max, at_start.pitch_max)


def test_incoming_messages_are_checked_against_the_shipped_schemas():
    order = {"headerId": 4, "timestamp": timestamp(), "version": "2.1.0", "manufacturer": "agf",
             "serialNumber": "x", "orderId": "o", "orderUpdateId": 0, "nodes": [], "edges": []}  # fmt: skip
    assert parse_incoming("order", repr(order).replace("'", '"').encode())["orderId"] == "o"
    with pytest.raises(RejectedMessage) as rejected:
        parse_incoming("order", b'{"headerId": 5, "version": "2.1.0"}')
    refs = {r["referenceKey"]: r["referenceValue"] for r in rejected.value.error["errorReferences"]}
    assert rejected.value.error["errorType"] == "validationError" and refs == {"topic": "order", "headerId": "5"}
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d\dZ", timestamp())
