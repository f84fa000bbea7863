"""The truck as a VDA 5050 2.1 vehicle against a real MQTT broker (amqtt) on a loopback port, with a
small fleet manager on paho-mqtt. Every message the vehicle publishes is checked against the
standard's 2.1.0 JSON schemas in ../shared/reference/vda5050-2.1.0/.

Two whole picks run in the simulated world: one complete order (its message sequence is the diagram
of docs/fleet.md: ``AGF_WRITE_DOCS=1`` rewrites it), and one that loses its broker, is paused and
resumed, and is cancelled mid-motion."""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from agf.config import load_config
from agf.fleet.messages import timestamp
from agf.paths import DEFAULT_CONFIG, repo_path

SCHEMAS = repo_path("../shared/reference/vda5050-2.1.0")
if not SCHEMAS.is_dir():
    pytest.skip(
        "../shared/reference/vda5050-2.1.0 is absent: the vehicle's messages cannot be checked against the schemas",
        allow_module_level=True,
    )
pytest.importorskip("amqtt.broker", reason="amqtt (the test extra) is not installed")
mqtt = pytest.importorskip("paho.mqtt.client")
jsonschema = pytest.importorskip("jsonschema")

from agf.fleet.agent import FleetAgent  # noqa: E402
from drivers.mqtt_fleet import MqttFleetLink  # noqa: E402
from drivers.sim.fleet_truck import SimulatedFleetTruck  # noqa: E402

# one pytest-xdist worker runs them all: its tests share one broker
pytestmark = pytest.mark.xdist_group("test_fleet")

CONFIG = load_config(DEFAULT_CONFIG)
VALIDATORS = {
    topic: jsonschema.Draft202012Validator(json.loads((SCHEMAS / f"{topic}.schema").read_text()))
    for topic in ("state", "connection", "factsheet")
}
SERIALS = itertools.count(1)
PICK = {"loadType": "jis-t11", "stationType": "truckBed", "loadId": "P-0001", "height": 0.80}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


BROKER = """
import asyncio, sys
from amqtt.broker import Broker

async def serve():
    await Broker({"listeners": {"default": {"type": "tcp", "bind": "127.0.0.1:" + sys.argv[1]}}}).start()
    await asyncio.Event().wait()

asyncio.run(serve())
"""


class LoopbackBroker:
    """amqtt on 127.0.0.1 in a process of its own: ``stop`` kills it, as a broker that goes away would go."""

    def __init__(self) -> None:
        self.port = free_port()
        self.process: subprocess.Popen | None = None

    def start(self) -> None:
        command = [sys.executable, "-c", BROKER, str(self.port)]
        self.process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                return
            except OSError:
                assert self.process.poll() is None, "the amqtt broker did not start"
                assert time.monotonic() < deadline, "the amqtt broker did not listen within 60 s"
                time.sleep(0.1)

    def stop(self) -> None:
        self.process.kill()
        self.process.wait()


class FleetManager:
    """The fleet side: sends orders and instant actions, records and schema-checks what the vehicle says."""

    def __init__(self, port: int, prefix: str, manufacturer: str, serial: str) -> None:
        self.prefix, self.manufacturer, self.serial = prefix, manufacturer, serial
        self.received: list[tuple[str, dict[str, Any]]] = []  # vehicle -> fleet, in arrival order
        self.sent: list[tuple[int, str, dict[str, Any]]] = []  # (index in received when sent, topic, message)
        self.invalid: list[str] = []
        self._ids: dict[str, int] = {}
        self._cond = threading.Condition()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"fleet-{serial}")
        self.client.reconnect_delay_set(1, 2)
        self.client.on_connect = lambda c, u, f, r, p: c.subscribe(f"{prefix}/+", 1)
        self.client.on_message = self._on_message
        self.client.connect("127.0.0.1", port, keepalive=5)
        self.client.loop_start()

    def _on_message(self, client: Any, userdata: Any, message: Any) -> None:
        topic = message.topic.rsplit("/", 1)[1]
        if topic in ("order", "instantActions"):
            return
        body = json.loads(message.payload)
        problems = [f"{topic} {body.get('headerId')}: {e.message}" for e in VALIDATORS[topic].iter_errors(body)]
        with self._cond:
            self.invalid.extend(problems)
            self.received.append((topic, body))
            self._cond.notify_all()

    def header(self, topic: str) -> dict[str, Any]:
        self._ids[topic] = self._ids.get(topic, 0) + 1
        return {
            "headerId": self._ids[topic],
            "timestamp": timestamp(),
            "version": "2.1.0",
            "manufacturer": self.manufacturer,
            "serialNumber": self.serial,
        }

    def send(self, topic: str, body: dict[str, Any] | bytes) -> int:
        """Publish on ``prefix/topic`` (a dict gets a header); returns the mark to wait from."""
        message = {"raw": body.decode(errors="replace")} if isinstance(body, bytes) else {**self.header(topic), **body}
        payload = body if isinstance(body, bytes) else json.dumps(message).encode()
        with self._cond:
            mark = len(self.received)
            self.sent.append((mark, topic, message))
        self.client.publish(f"{self.prefix}/{topic}", payload, qos=0).wait_for_publish(5)
        return mark

    def order(self, order_id: str, update_id: int = 0, actions: list | None = None, **extra: Any) -> int:
        node = {"nodeId": "station-1", "sequenceId": 0, "released": True, "actions": actions or []}
        return self.send(
            "order", {"orderId": order_id, "orderUpdateId": update_id, "nodes": [node], "edges": [], **extra}
        )

    def instant(self, action_id: str, action_type: str) -> int:
        return self.send(
            "instantActions", {"actions": [{"actionId": action_id, "actionType": action_type, "blockingType": "NONE"}]}
        )

    def wait(self, topic: str, test: Callable[[dict[str, Any]], bool], since: int = 0, timeout: float = 30) -> dict:
        """The first ``topic`` message from index ``since`` on that passes ``test``."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for t, body in self.received[since:]:
                    if t == topic and test(body):
                        return body
                left = deadline - time.monotonic()
                if left <= 0:
                    seen = [b for t, b in self.received[since:] if t == topic][-3:]
                    raise AssertionError(f"no {topic} message passed the test within {timeout} s; last: {seen}")
                self._cond.wait(left)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def action(state: dict[str, Any], action_id: str) -> dict[str, Any]:
    return next((a for a in state["actionStates"] if a["actionId"] == action_id), {})


def status(action_id: str, *wanted: str) -> Callable[[dict[str, Any]], bool]:
    return lambda state: action(state, action_id).get("actionStatus") in wanted


def has_error(error_type: str, **refs: str) -> Callable[[dict[str, Any]], bool]:
    def test(state: dict[str, Any]) -> bool:
        for error in state["errors"]:
            given = {r["referenceKey"]: r["referenceValue"] for r in error.get("errorReferences", [])}
            if error["errorType"] == error_type and all(given.get(k) == v for k, v in refs.items()):
                return True
        return False

    return test


def pick(action_id: str, **parameters: Any) -> dict[str, Any]:
    return {
        "actionId": action_id,
        "actionType": "pick",
        "blockingType": "HARD",
        "actionParameters": [{"key": k, "value": v} for k, v in parameters.items()],
    }


@pytest.fixture(scope="module")
def broker():
    broker = LoopbackBroker()
    broker.start()
    yield broker
    broker.stop()


@dataclasses.dataclass
class Vehicle:
    agent: FleetAgent
    truck: SimulatedFleetTruck
    fleet: FleetManager
    broker: LoopbackBroker


@pytest.fixture
def vehicle(broker):
    serial = f"test-{next(SERIALS)}"
    fleet_config = dataclasses.replace(
        CONFIG.fleet,
        serial_number=serial,
        broker=dataclasses.replace(CONFIG.fleet.broker, port=broker.port, reconnect_min=0.5, reconnect_max=2.0),
    )
    truck = SimulatedFleetTruck(CONFIG)
    agent = FleetAgent(fleet_config, CONFIG.forks, CONFIG.vision.search, truck)
    fleet = FleetManager(broker.port, agent.prefix, fleet_config.manufacturer, serial)
    agent.attach(MqttFleetLink(fleet_config.broker, agent.prefix, agent, agent.will()))
    agent.start()
    fleet.wait("connection", lambda m: m["connectionState"] == "ONLINE")
    fleet.wait("state", lambda m: True)
    yield Vehicle(agent, truck, fleet, broker)
    mark = len(fleet.received)
    agent.close()
    fleet.wait("connection", lambda m: m["connectionState"] == "OFFLINE", since=mark)
    fleet.close()
    assert not fleet.invalid, fleet.invalid


def steady(truck: SimulatedFleetTruck, seconds: float = 1.0) -> bool:
    """True when no axis moves more than 0.1 mm (or mrad) over ``seconds``."""
    before = truck.world.positions()
    time.sleep(seconds)
    after = truck.world.positions()
    return all(abs(after[n] - before[n]) < 1e-4 for n in before)


def test_bad_input_becomes_an_error_with_its_reference_and_moves_nothing(vehicle):
    fleet = vehicle.fleet
    factsheet = fleet.wait("factsheet", lambda m: True)
    assert {s["loadType"] for s in factsheet["loadSpecification"]["loadSets"]} >= {"jis-t11", "epal"}
    late = FleetManager(vehicle.broker.port, fleet.prefix, fleet.manufacturer, "late")  # connection and factsheet
    try:  # are retained: a fleet manager that subscribes later still gets them
        assert late.wait("connection", lambda m: True)["connectionState"] == "ONLINE"
        assert late.wait("factsheet", lambda m: True) == factsheet
    finally:
        late.close()

    mark = fleet.send("order", b"{not json")
    fleet.wait("state", has_error("validationError", topic="order"), since=mark)
    mark = fleet.send("order", {"orderId": "o-x", "orderUpdateId": 0, "edges": []})  # no nodes
    header = fleet.sent[-1][2]["headerId"]
    fleet.wait("state", has_error("validationError", topic="order", headerId=str(header)), since=mark)
    mark = fleet.order("o-v", actions=[pick("p-v", **PICK)], version="1.1.0")
    fleet.wait("state", has_error("validationError", version="1.1.0"), since=mark)
    mark = fleet.order("o-u", actions=[{"actionId": "a-dance", "actionType": "dance", "blockingType": "NONE"}])
    fleet.wait("state", has_error("orderError", orderId="o-u", actionId="a-dance"), since=mark)
    without_load_type = {k: v for k, v in PICK.items() if k != "loadType"}
    mark = fleet.order("o-m", actions=[pick("p-m", **without_load_type)])
    fleet.wait("state", has_error("orderError", actionId="p-m", actionParameter="loadType"), since=mark)
    mark = fleet.order("o-t", actions=[pick("p-t", **{**PICK, "loadType": "crate"})])
    fleet.wait("state", has_error("orderError", actionId="p-t", actionParameter="loadType"), since=mark)
    mark = fleet.order("o-h", actions=[pick("p-h", **{**PICK, "height": 3.0})])
    fleet.wait("state", has_error("orderError", actionId="p-h", actionParameter="height"), since=mark)
    far = {
        "nodeId": "far",
        "sequenceId": 0,
        "released": True,
        "actions": [],
        "nodePosition": {"x": 12.0, "y": 3.0, "mapId": "hall"},
    }
    mark = fleet.send("order", {"orderId": "o-far", "orderUpdateId": 0, "nodes": [far], "edges": []})
    fleet.wait("state", has_error("orderError", orderId="o-far", nodeId="far"), since=mark)
    mark = fleet.instant("i-dance", "dance")
    state = fleet.wait("state", has_error("instantActionError", actionId="i-dance"), since=mark)
    assert action(state, "i-dance")["actionStatus"] == "FAILED"
    mark = fleet.instant("i-cancel", "cancelOrder")
    fleet.wait("state", has_error("noOrderToCancel", actionId="i-cancel"), since=mark)
    assert len(state["errors"]) >= 9 and all(e["errorLevel"] == "WARNING" for e in state["errors"])

    # An order at the truck without actions is taken: the warnings end, the order becomes current.
    mark = fleet.order("o-1", update_id=1)
    state = fleet.wait("state", lambda s: s["orderId"] == "o-1", since=mark)
    assert state["errors"] == [] and state["lastNodeId"] == "station-1" and state["orderUpdateId"] == 1
    mark = fleet.order("o-1", update_id=0)
    fleet.wait("state", has_error("orderUpdateError", orderId="o-1", orderUpdateId="0"), since=mark)
    mark = fleet.order("o-1", update_id=1)
    state = fleet.wait("state", has_error("orderUpdateError", orderId="o-1", orderUpdateId="1"), since=mark)
    assert state["orderId"] == "o-1" and state["orderUpdateId"] == 1

    mark = fleet.instant("i-state", "stateRequest")
    fleet.wait("state", status("i-state", "FINISHED"), since=mark)
    mark = fleet.instant("i-sheet", "factsheetRequest")
    fleet.wait("factsheet", lambda m: True, since=mark)
    assert vehicle.truck.sessions == 0  # no simulated world was built: nothing moved
    statuses = {
        a["actionStatus"]
        for _, s in fleet.received
        if _ == "state"
        for a in s["actionStates"]
        if a["actionType"] == "pick"
    }
    assert statuses == set()  # no pick was ever accepted
    # The link breaks without a goodbye: the broker sends the last will, the vehicle reconnects by itself.
    mark = len(fleet.received)
    vehicle.agent._link._client.socket().close()
    fleet.wait("connection", lambda m: m["connectionState"] == "CONNECTIONBROKEN", since=mark)
    fleet.wait("connection", lambda m: m["connectionState"] == "ONLINE", since=mark)


def test_serve_flags_are_checked_before_anything_connects(capsys):
    from agf.cli import main

    assert main(["serve", "--json", "--broker", "http://127.0.0.1:1883"]) == 2
    assert "expected mqtt://HOST:PORT" in json.loads(capsys.readouterr().out)["error"]
    assert main(["serve", "--json", "--serial", "truck/7"]) == 2
    assert "topic level" in json.loads(capsys.readouterr().out)["error"]


def test_agf_serve_comes_online_and_says_offline_when_stopped(broker):
    serial = f"serve-{next(SERIALS)}"
    fleet = FleetManager(broker.port, f"uagv/v2/agf/{serial}", "agf", serial)
    command = [
        sys.executable,
        "-m",
        "agf.cli",
        "serve",
        "--broker",
        f"mqtt://127.0.0.1:{broker.port}",
        "--serial",
        serial,
    ]
    env = {**os.environ, "PYTHONPATH": str(repo_path("."))}
    process = subprocess.Popen(command, env=env, stdin=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        fleet.wait("connection", lambda m: m["connectionState"] == "ONLINE", timeout=120)
        fleet.wait("factsheet", lambda m: True)
        mark = fleet.instant("i-1", "stateRequest")
        fleet.wait("state", status("i-1", "FINISHED"), since=mark)
        assert "type 'reset'" in process.stderr.readline()
        process.stdin.write("reset\n")  # the local reset is typed at the truck, never sent by the fleet
        process.stdin.flush()
        assert "no fault to reset" in process.stderr.readline()
        mark = len(fleet.received)
        process.send_signal(signal.SIGTERM)
        fleet.wait("connection", lambda m: m["connectionState"] == "OFFLINE", since=mark)
        assert process.wait(timeout=30) == 0
    finally:
        process.kill()
        fleet.close()
    assert not fleet.invalid, fleet.invalid


def phases(fleet: FleetManager, action_id: str, since: int) -> list[str]:
    """The pick's statuses in the states since ``since``, repeats collapsed."""
    seen = [action(s, action_id).get("actionStatus") for t, s in fleet.received[since:] if t == "state"]
    return [s for s, _ in itertools.groupby(seen) if s is not None]


def test_an_order_picks_the_pallet(vehicle):
    fleet, truck = vehicle.fleet, vehicle.truck
    mark = fleet.order("o-pick", actions=[pick("pick-1", **PICK)])
    state = fleet.wait("state", status("pick-1", "FINISHED", "FAILED"), since=mark, timeout=600)
    assert action(state, "pick-1")["actionStatus"] == "FINISHED", state["errors"]
    assert phases(fleet, "pick-1", mark) == ["WAITING", "INITIALIZING", "RUNNING", "FINISHED"]
    assert state["errors"] == [] and state["orderId"] == "o-pick" and state["lastNodeId"] == "station-1"
    (load,) = state["loads"]
    assert load["loadId"] == "P-0001" and load["loadType"] == "jis-t11" and load["loadPosition"] == "forks"
    assert load["loadDimensions"]["height"] == pytest.approx(0.144)
    search = truck.world.config.vision.search  # `height` narrowed the vertical search to +-100 mm
    assert search.z_max - search.z_min == pytest.approx(0.2) and search.z_min < 0.227 < search.z_max
    assert truck.sessions == 1 and 0.005 < truck.world.min_clearance < 1.0  # inserted, nothing touched
    mark = fleet.order("o-again", actions=[pick("pick-2", **PICK)])  # the forks carry the pallet now
    fleet.wait("state", has_error("orderError", orderId="o-again", actionId="pick-2"), since=mark)
    if os.environ.get("AGF_WRITE_DOCS"):
        write_sequence_diagram(fleet)


def wait_phase(agent: FleetAgent, test: Callable[[str], bool], timeout: float) -> None:
    """Wait until the running pick's controller state passes ``test``; fail at once if the pick ended."""
    deadline = time.monotonic() + timeout
    while not test(phase := agent.pick_phase()):
        assert phase is not None, f"the pick ended: {agent.state()['errors']}"
        assert time.monotonic() < deadline, f"the pick is still {phase} after {timeout} s"
        time.sleep(0.05)


def moving(truck: SimulatedFleetTruck) -> bool:
    return not steady(truck, 0.1)


def test_broker_loss_and_pause_hold_the_pick_and_cancel_stops_it_mid_motion(vehicle):
    fleet, truck, agent, broker = vehicle.fleet, vehicle.truck, vehicle.agent, vehicle.broker
    mark = fleet.order("o-hold", actions=[pick("pick-3", **PICK)])
    state = fleet.wait("state", status("pick-3", "RUNNING", "FAILED"), since=mark, timeout=300)
    assert action(state, "pick-3")["actionStatus"] == "RUNNING", state["errors"]

    broker.stop()  # the truck holds at the pick's next state boundary and tries to reconnect
    try:
        wait_phase(agent, lambda phase: phase == "paused", 300)
        assert steady(truck, 1.5)
    finally:
        mark = len(fleet.received)
        broker.start()
    fleet.wait("connection", lambda m: m["connectionState"] == "ONLINE", since=mark, timeout=60)
    wait_phase(agent, lambda phase: phase != "paused", 60)  # back online: the pick goes on

    mark = fleet.instant("pause-1", "startPause")
    state = fleet.wait("state", status("pause-1", "FINISHED", "FAILED"), since=mark, timeout=300)
    held = action(state, "pick-3")
    assert held["actionStatus"] == "RUNNING" and held["actionDescription"] == "controller: paused", state["errors"]
    assert state["paused"]
    assert steady(truck, 1.5)
    mark = fleet.instant("resume-1", "stopPause")
    state = fleet.wait("state", status("pick-3", "RUNNING", "FAILED"), since=mark, timeout=60)
    assert not state["paused"] and action(state, "resume-1")["actionStatus"] == "FINISHED"

    wait_phase(agent, lambda phase: phase in ("aligning", "inserting") and moving(truck), 300)
    mark = fleet.instant("cancel-1", "cancelOrder")
    state = fleet.wait("state", status("pick-3", "FAILED"), since=mark, timeout=60)
    assert action(state, "cancel-1")["actionStatus"] == "FINISHED"
    assert has_error("pickFailed", actionId="pick-3", orderId="o-hold")(state)
    assert "cancelled by the fleet (cancelOrder cancel-1)" in state["errors"][-1]["errorDescription"]
    assert state["safetyState"]["eStop"] == "MANUAL" and state["orderId"] == "o-hold"
    time.sleep(1.0)  # the quick-stop ramp
    assert steady(truck, 0.5)

    mark = fleet.order("o-next", actions=[pick("pick-4", **PICK)])  # no pick before the local reset
    fleet.wait("state", has_error("orderError", orderId="o-next", actionId="pick-4"), since=mark)
    mark = len(fleet.received)
    assert agent.local_reset().startswith("reset")
    state = fleet.wait("state", lambda s: s["safetyState"]["eStop"] == "NONE", since=mark)
    assert not has_error("pickFailed")(state) and truck.sessions == 1


def write_sequence_diagram(fleet: FleetManager) -> None:
    """Rewrite docs/fleet.md's sequence diagram from the messages of a recorded order."""
    events = [(mark, 0, "F->>T", topic, body) for mark, topic, body in fleet.sent]
    events += [(i, 1, "T->>F", topic, body) for i, (topic, body) in enumerate(fleet.received)]
    lines, last = [], None
    for _, _, arrow, topic, body in sorted(events, key=lambda e: e[:2]):
        label = f"{arrow}: {topic}: {summary(topic, body)}"
        if label != last:
            lines.append(f"    {label}")
        last = label
    diagram = (
        "```mermaid\nsequenceDiagram\n    participant F as fleet manager\n    participant T as truck (agf serve)\n"
    )
    diagram += "\n".join(lines) + "\n```"
    doc = repo_path("docs/fleet.md")
    head, rest = doc.read_text().split("<!-- sequence:begin -->\n", 1)
    _, tail = rest.split("<!-- sequence:end -->", 1)
    doc.write_text(f"{head}<!-- sequence:begin -->\n{diagram}\n<!-- sequence:end -->{tail}")


def summary(topic: str, body: dict[str, Any]) -> str:
    """The key fields of a message, for the diagram."""
    if topic == "connection":
        return body["connectionState"]
    if topic == "factsheet":
        return "loadSets " + ", ".join(s["loadType"] for s in body["loadSpecification"]["loadSets"])
    if topic == "order":
        acts = [a for n in body["nodes"] for a in n["actions"]]
        return f"{body['orderId']}/{body['orderUpdateId']} " + ", ".join(
            f"{a['actionType']} {a['actionId']}" for a in acts
        )
    if topic == "instantActions":
        return ", ".join(f"{a['actionType']} {a['actionId']}" for a in body["actions"])
    acts = ", ".join(
        f"{a['actionId']} {a['actionStatus']}" + (f" ({a['actionDescription']})" if "actionDescription" in a else "")
        for a in body["actionStates"]
    )
    loads = (
        ", loads " + ", ".join(f"{ld['loadType']} {ld.get('loadId', '')}" for ld in body["loads"])
        if body["loads"]
        else ""
    )
    errors = ", errors " + ", ".join(e["errorType"] for e in body["errors"]) if body["errors"] else ""
    return f"order {body['orderId'] or '-'}, {acts or 'no actions'}{loads}{errors}"
