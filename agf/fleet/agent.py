"""The truck as a VDA 5050 2.1 vehicle: orders with a ``pick``, instant actions, state and factsheet.

One order runs one pick, on a node where the truck already stands (no navigation is built here). The
pick action goes WAITING -> INITIALIZING -> RUNNING -> FINISHED, or FAILED with
a FATAL ``pickFailed`` error carrying the controller's reason; after a failure the truck takes no new
pick until a local reset (never from the network, ISO 3691-4). Bad input never starts a pick: it
becomes a WARNING in ``state.errors`` with its references, reported until an order is accepted.

While the link to the broker is down the pick holds at its next state boundary, and continues when
the link is back; ``startPause`` holds it the same way. Messages arrive on the link's thread, picks
run on a worker thread, a timer thread publishes the state at least every ``state_period``; one lock
guards the vehicle's state.
"""

from __future__ import annotations

import json
import math
import threading
from dataclasses import dataclass, field
from typing import Any

from agf.config import FleetConfig, ForkGeometry, SearchVolume
from agf.controller import PickController, PickResult
from agf.errors import AgfError
from agf.fleet.factsheet import INSTANT_ACTIONS, factsheet_body
from agf.fleet.link import FleetLink
from agf.fleet.messages import INCOMING, QOS, RETAINED, Headers, RejectedMessage, parse_incoming, vda_error
from agf.fleet.pick import PickRequest, pick_request, picked_load
from agf.fleet.truck import FleetTruck


@dataclass
class _PickRun:
    """The pick of the current order: its request, controller (once built) and how it is being stopped."""

    request: PickRequest
    order_id: str
    controller: PickController | None = None
    cancel_reason: str | None = None
    cancel_actions: list[str] = field(default_factory=list)
    pause_actions: list[str] = field(default_factory=list)
    phase: str = "waiting"


class FleetAgent:
    """The VDA 5050 side of one truck; attach a :class:`FleetLink`, then :meth:`start`."""

    def __init__(self, fleet: FleetConfig, forks: ForkGeometry, search: SearchVolume, truck: FleetTruck) -> None:
        self.fleet, self.forks, self.search, self.truck = fleet, forks, search, truck
        self.prefix = f"{fleet.interface_name}/v2/{fleet.manufacturer}/{fleet.serial_number}"
        self._headers = Headers(fleet.manufacturer, fleet.serial_number)
        self._lock = threading.RLock()
        self._link: FleetLink | None = None
        self._link_up = False
        self._order_id, self._order_update_id = "", 0
        self._last_node_id, self._last_node_sequence_id = "", 0
        self._actions: dict[str, dict[str, Any]] = {}  # actionId -> actionState, in arrival order
        self._warnings: list[dict[str, Any]] = []  # bad input, until an order is accepted
        self._fault: dict[str, Any] | None = None  # a failed pick, until the local reset
        self._loads: list[dict[str, Any]] = []
        self._paused = False
        self._run: _PickRun | None = None
        self._worker: threading.Thread | None = None
        self._closing = threading.Event()
        self._state_due = threading.Event()
        self._timer = threading.Thread(target=self._state_timer, name="vda5050-state", daemon=True)

    # -- lifecycle ---------------------------------------------------------------------------------
    def attach(self, link: FleetLink) -> None:
        self._link = link

    def will(self) -> bytes:
        """The last will: ``connection`` CONNECTIONBROKEN (its header is old by the time it is sent)."""
        return self._encode("connection", {"connectionState": "CONNECTIONBROKEN"})

    def start(self) -> None:
        self._timer.start()
        if self._link is not None:
            self._link.start()

    def close(self, reason: str = "agf serve stopped") -> None:
        """Stop a running pick (quick stop), say OFFLINE and disconnect."""
        with self._lock:
            run = self._run
            if run is not None:
                self._cancel(run, reason)
        if self._worker is not None:
            self._worker.join()
        self._closing.set()
        self._state_due.set()
        if self._timer.is_alive():
            self._timer.join()
        if self._link is not None:
            self._link.close(self._encode("connection", {"connectionState": "OFFLINE"}))

    def pick_phase(self) -> str | None:
        """The running pick's controller state (``paused`` while it holds), None when no pick runs."""
        run = self._run
        return None if run is None else run.phase

    def local_reset(self) -> str:
        """The operator's reset at the truck after a failed pick; returns what it did."""
        with self._lock:
            if self._run is not None:
                return "a pick is running; nothing to reset"
            if self._fault is None:
                return "no fault to reset"
            self.truck.reset()
            self._fault = None
            self._publish_state()
        return "reset: the truck takes orders again"

    # -- link events (the link's thread) -------------------------------------------------------------
    def on_link(self, up: bool) -> None:
        with self._lock:
            self._link_up = up
            if up:
                self._send("connection", {"connectionState": "ONLINE"})
                self._send("factsheet", self._factsheet())
                self._publish_state()
            self._apply_hold()  # back online, and the fleet has the state: a held pick goes on

    def on_message(self, topic: str, payload: bytes) -> None:
        kind = topic.rsplit("/", 1)[-1]
        if kind not in INCOMING:
            return
        with self._lock:
            try:
                message = parse_incoming(kind, payload)
                if kind == "order":
                    self._on_order(message)
                else:
                    self._on_instant_actions(message)
            except RejectedMessage as rejected:
                self._warnings.append(rejected.error)
            self._publish_state()

    # -- orders ------------------------------------------------------------------------------------
    def _on_order(self, message: dict[str, Any]) -> None:
        order_id, update_id = message["orderId"], message["orderUpdateId"]
        refs = {"topic": "order", "headerId": message["headerId"], "orderId": order_id, "orderUpdateId": update_id}
        if order_id == self._order_id and update_id <= self._order_update_id:
            what = "repeated (ignored)" if update_id == self._order_update_id else "older than the current one"
            raise RejectedMessage(
                vda_error(
                    "orderUpdateError",
                    f"order {order_id}: orderUpdateId {update_id} is {what}; the current is {self._order_update_id}",
                    refs,
                )
            )
        if self._run is not None:
            raise RejectedMessage(
                vda_error(
                    "orderUpdateError" if order_id == self._order_id else "orderError",
                    f"order {order_id}: the pick of order {self._run.order_id} is running; "
                    "cancel it (cancelOrder) or wait for it to end",
                    refs,
                )
            )
        node = self._only_node(message, refs)
        picks = self._node_picks(node, refs)
        request = self._check_pick(picks[0], refs) if picks else None
        self._accept(message, node, request)

    def _only_node(self, message: dict[str, Any], refs: dict[str, Any]) -> dict[str, Any]:
        """The order's one node, at the truck's position: travel needs a navigation plugin, none is built."""
        nodes, edges = message["nodes"], message["edges"]
        if len(nodes) != 1 or edges:
            extra = (edges or nodes[1:] or nodes)[0]
            key = "edgeId" if edges else "nodeId"
            raise RejectedMessage(
                vda_error(
                    "orderError",
                    f"order {refs['orderId']}: {len(nodes)} nodes and {len(edges)} edges need travel; this truck "
                    "has no navigation plugin, so an order is one node where it stands",
                    {**refs, key: extra.get(key)},
                )
            )
        node = nodes[0]
        refs = {**refs, "nodeId": node["nodeId"]}
        if not node["released"]:
            raise RejectedMessage(
                vda_error("orderError", f"node {node['nodeId']} is not released (horizon only)", refs)
            )
        position = node.get("nodePosition")
        if position is not None:
            x, y, _ = self.truck.position()
            allowed = position.get("allowedDeviationXY", self.fleet.node_deviation)
            off = math.hypot(position["x"] - x, position["y"] - y)
            if position["mapId"] != self.fleet.map_id or off > allowed:
                raise RejectedMessage(
                    vda_error(
                        "orderError",
                        f"node {node['nodeId']} is {off:.2f} m away on map {position['mapId']!r} (the truck is at "
                        f"({x:.2f}, {y:.2f}) on {self.fleet.map_id!r}, allowed {allowed:.2f} m): travel needs a "
                        "navigation plugin, none is configured",
                        refs,
                    )
                )
        return node

    def _node_picks(self, node: dict[str, Any], refs: dict[str, Any]) -> list[dict[str, Any]]:
        for action in node["actions"]:
            if action["actionType"] != "pick":
                raise RejectedMessage(
                    vda_error(
                        "orderError",
                        f"action {action['actionId']}: {action['actionType']!r} is not an action this truck performs "
                        "on a node (it performs 'pick')",
                        {**refs, "actionId": action["actionId"], "actionType": action["actionType"]},
                    )
                )
        if len(node["actions"]) > 1:
            raise RejectedMessage(
                vda_error(
                    "orderError", "one pick per order: the forks carry one load", {**refs, "nodeId": node["nodeId"]}
                )
            )
        return node["actions"]

    def _check_pick(self, action: dict[str, Any], refs: dict[str, Any]) -> PickRequest:
        if self._fault is not None:
            raise RejectedMessage(
                vda_error(
                    "orderError",
                    f"the last pick failed ({self._fault['errorDescription']}); the truck needs a local reset first",
                    {**refs, "actionId": action["actionId"]},
                )
            )
        if self._loads:
            raise RejectedMessage(
                vda_error(
                    "orderError",
                    "the forks already carry a load (drop is not built here)",
                    {**refs, "actionId": action["actionId"]},
                )
            )
        pallets = self.truck.pallets()
        return pick_request(
            action, pallets, self.forks, self.search, self.truck.fork_height(), self.fleet.height_window, refs
        )

    def _accept(self, message: dict[str, Any], node: dict[str, Any], request: PickRequest | None) -> None:
        self._order_id, self._order_update_id = message["orderId"], message["orderUpdateId"]
        self._last_node_id, self._last_node_sequence_id = node["nodeId"], node["sequenceId"]
        self._warnings.clear()
        self._actions = {}
        if request is None:
            return
        self._actions[request.action_id] = {
            "actionId": request.action_id,
            "actionType": "pick",
            "actionStatus": "WAITING",
        }
        run = _PickRun(request, message["orderId"])
        self._run = run
        self._worker = threading.Thread(target=self._pick, args=(run,), name="vda5050-pick", daemon=True)
        self._worker.start()

    # -- the pick (worker thread) ------------------------------------------------------------------
    def _pick(self, run: _PickRun) -> None:
        self._set_phase(run, "connecting")
        try:
            with self.truck.pick_session(run.request, lambda state: self._set_phase(run, state)) as controller:
                with self._lock:
                    run.controller = controller
                    if run.cancel_reason is not None:
                        controller.stop(run.cancel_reason)
                    self._apply_hold()
                result = controller.run()
        except AgfError as exc:
            result = PickResult(False, "fault", f"preparing the pick: {exc}", [], None, {}, [])
        with self._lock:
            self._finish(run, result)

    def _set_phase(self, run: _PickRun, phase: str) -> None:
        # A held pick stays RUNNING, described "controller: paused": the standard's text names PAUSED, but
        # the 2.1.0 state schema's actionStatus has no such value, and a fleet validating states would drop it.
        status = "INITIALIZING" if phase == "connecting" else "RUNNING"
        with self._lock:
            run.phase = phase
            state = self._actions[run.request.action_id]
            before = dict(state)
            state.update(actionStatus=status, actionDescription=f"controller: {phase}")
            if phase == "paused":
                self._finish_actions(run.pause_actions, "FINISHED")
            if state != before or phase == "paused":
                self._publish_state()

    def _finish(self, run: _PickRun, result: PickResult) -> None:
        state = self._actions[run.request.action_id]
        state.pop("actionDescription", None)
        if result.ok:
            state["actionStatus"] = "FINISHED"
            state["resultDescription"] = f"{run.request.load_type} on the forks"
            self._loads = [picked_load(run.request, self.truck.pallets()[run.request.load_type])]
        else:
            state["actionStatus"] = "FAILED"
            self._fault = vda_error(
                "pickFailed",
                result.reason or "the pick failed",
                {"orderId": run.order_id, "actionId": run.request.action_id},
                level="FATAL",
                hint="check the forks and the load at the truck, then reset it there (agf serve: type 'reset')",
            )
        self._finish_actions(run.cancel_actions, "FINISHED")
        self._finish_actions(run.pause_actions, "FINISHED")  # the truck stands still now
        self._run = None
        self._publish_state()

    # -- instant actions ---------------------------------------------------------------------------
    def _on_instant_actions(self, message: dict[str, Any]) -> None:
        refs = {"topic": "instantActions", "headerId": message["headerId"]}
        for action in message["actions"]:
            action_id, kind = action["actionId"], action["actionType"]
            self._actions[action_id] = {"actionId": action_id, "actionType": kind, "actionStatus": "RUNNING"}
            if kind not in INSTANT_ACTIONS:
                self._actions[action_id]["actionStatus"] = "FAILED"
                self._warnings.append(
                    vda_error(
                        "instantActionError",
                        f"instant action {action_id}: {kind!r} is not one this truck takes ({sorted(INSTANT_ACTIONS)})",
                        {**refs, "actionId": action_id, "actionType": kind},
                    )
                )
                continue
            getattr(self, f"_{kind}")(action_id, refs)

    def _cancelOrder(self, action_id: str, refs: dict[str, Any]) -> None:  # noqa: N802 - VDA 5050's name
        run = self._run
        if run is None:
            self._actions[action_id]["actionStatus"] = "FAILED"
            self._warnings.append(
                vda_error("noOrderToCancel", "cancelOrder: no order is running", {**refs, "actionId": action_id})
            )
            return
        run.cancel_actions.append(action_id)
        self._cancel(run, f"cancelled by the fleet (cancelOrder {action_id})")

    def _startPause(self, action_id: str, refs: dict[str, Any]) -> None:  # noqa: N802
        self._paused = True
        run = self._run
        if run is not None and run.phase != "paused":
            run.pause_actions.append(action_id)  # finished once the pick holds
        else:
            self._actions[action_id]["actionStatus"] = "FINISHED"
        self._apply_hold()

    def _stopPause(self, action_id: str, refs: dict[str, Any]) -> None:  # noqa: N802
        self._paused = False
        self._apply_hold()
        self._actions[action_id]["actionStatus"] = "FINISHED"

    def _stateRequest(self, action_id: str, refs: dict[str, Any]) -> None:  # noqa: N802
        self._actions[action_id]["actionStatus"] = "FINISHED"  # the state follows this message

    def _factsheetRequest(self, action_id: str, refs: dict[str, Any]) -> None:  # noqa: N802
        self._send("factsheet", self._factsheet())
        self._actions[action_id]["actionStatus"] = "FINISHED"

    def _cancel(self, run: _PickRun, reason: str) -> None:
        run.cancel_reason = run.cancel_reason or reason
        if run.controller is not None:
            run.controller.stop(run.cancel_reason)

    def _apply_hold(self) -> None:
        """Hold the pick while paused or while the link is down; let it go otherwise."""
        run = self._run
        if run is None or run.controller is None:
            return
        if self._paused or not self._link_up:
            run.controller.pause()
        else:
            run.controller.resume()

    def _finish_actions(self, action_ids: list[str], status: str) -> None:
        for action_id in action_ids:
            self._actions[action_id]["actionStatus"] = status
        action_ids.clear()

    # -- outgoing ----------------------------------------------------------------------------------
    def _state_timer(self) -> None:
        while not self._closing.is_set():
            if not self._state_due.wait(self.fleet.state_period):
                with self._lock:
                    self._publish_state()
            self._state_due.clear()

    def _publish_state(self) -> None:
        self._send("state", self.state())
        self._state_due.set()  # restarts the period

    def state(self) -> dict[str, Any]:
        """The ``state`` message as it stands, without its header."""
        x, y, theta = self.truck.position()
        charge, charging = self.truck.battery()
        state: dict[str, Any] = {
            "orderId": self._order_id,
            "orderUpdateId": self._order_update_id,
            "lastNodeId": self._last_node_id,
            "lastNodeSequenceId": self._last_node_sequence_id,
            "nodeStates": [],
            "edgeStates": [],
            "agvPosition": {"x": x, "y": y, "theta": theta, "mapId": self.fleet.map_id, "positionInitialized": True},
            "driving": False,
            "paused": self._paused,
            "actionStates": [dict(a) for a in self._actions.values()],
            "batteryState": {"batteryCharge": charge, "charging": charging},
            "operatingMode": "AUTOMATIC",
            "errors": [*self._warnings, *([self._fault] if self._fault else [])],
            "safetyState": {"eStop": "MANUAL" if self._fault else "NONE", "fieldViolation": False},
            "loads": [dict(load) for load in self._loads],
        }
        return state

    def _factsheet(self) -> dict[str, Any]:
        return factsheet_body(self.fleet, self.forks, self.truck.pallets())

    def _encode(self, topic: str, body: dict[str, Any]) -> bytes:
        return json.dumps({**self._headers(topic), **body}, allow_nan=False).encode()

    def _send(self, topic: str, body: dict[str, Any]) -> None:
        if self._link is not None and (self._link_up or topic == "connection"):
            self._link.publish(topic, self._encode(topic, body), QOS.get(topic, 0), topic in RETAINED)
