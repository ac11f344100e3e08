"""A VDA 5050 vehicle of our own, pure: it takes orders and instant actions, drives, reports.

For trying the adapter without hardware and for the tests' 2.1.0 parts (the factsheet) and the
behaviours the specification allows a vehicle and `vda-5050-lib` does not show: states only on
events and every `state_every_s` (up to 30 s), QoS 0, refusing an order update
(`orderUpdateError`), a route it cannot drive (`noRouteError`), `noOrderToCancel` when it has
no order.

It drives its released nodes in order at `speed` (m/s) along straight edges, stops at once when
paused (a stopping distance of 0), does a node's `pick`/`drop` standing still for `action_s`, and
takes an update only if it starts at the last base node it has (§6.6 of the specification).

Its battery (VDA 5050 `batteryState`): `node_pct` for every node it drives to, `idle_pct_per_s`
while it stands and does not charge, `charge_pct_per_s` while it charges, within 0 and 100.
`startCharging` starts a charge where it stands, standing with no order under way (FAILED
otherwise, or, with `chargers` given, off its charging stations: "not aligned to charger", as
the spec's example of a failed start says, with a `chargingError`); it charges on at 100 % (its
own overcharge protection) until `stopCharging`. While it charges it takes no order (the spec:
charging is false only once it is ready for orders; an `orderError` says so); at 0 % it drives
no further (a `batteryLowError` WARNING while it has nodes to drive) until it has charged.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Literal

from gridfleet.robots.vda5050.wire import Headers, VdaTopic, Vehicle

REACH_M = 0.11  # how far from an order's first node (or a charging station) it may stand
Message = tuple[VdaTopic, dict[str, Any]]  # (topic, message) to publish
# What the spec lets a vehicle do that gridfleet's must cope with: refuse order updates, refuse
# every route, or name its loads without their weight (the schemas' load requires no field).
Quirk = Literal["reject_updates", "no_route", "weightless_loads"]


@dataclass
class _Node:
    node_id: str
    sequence_id: int
    released: bool
    x: float
    y: float
    actions: list[dict[str, Any]]


@dataclass
class VirtualSpec:
    """How one virtual vehicle behaves."""

    start: tuple[float, float]  # its reference point on its map, metres
    map_id: str
    speed: float = 0.5  # m/s
    capacity_kg: float = 10.0
    action_s: float = 0.5  # a pick or a drop
    state_every_s: float = 30.0  # a state at least this often, besides every event
    quirks: frozenset[Quirk] = frozenset()
    battery_pct: float = 90.0  # its charge at the start
    node_pct: float = 0.0  # what driving to one node costs
    idle_pct_per_s: float = 0.0  # what a second standing (not charging) costs
    charge_pct_per_s: float = 2.0  # what a second charging adds
    # Where it can charge (its reference point within REACH_M of one); None: wherever it stands.
    chargers: tuple[tuple[float, float], ...] | None = None


@dataclass
class _Action:
    action: dict[str, Any]
    status: str = "WAITING"
    description: str | None = None


@dataclass
class VirtualVehicle:
    """The vehicle's state machine: messages and time in, messages out."""

    vehicle: Vehicle
    spec: VirtualSpec
    headers: Headers = field(init=False)
    x: float = field(init=False)
    y: float = field(init=False)
    theta: float = 0.0
    order_id: str = ""
    update_id: int = 0
    last_node: tuple[str, int] = ("", 0)
    nodes: list[_Node] = field(default_factory=list)  # ahead, the first is the next to reach
    actions: dict[str, _Action] = field(default_factory=dict)
    paused: bool = False
    driving: bool = False
    loads: dict[str, float] = field(default_factory=dict)  # load id -> kg
    errors: list[dict[str, Any]] = field(default_factory=list)
    busy_until: float | None = None  # doing a node's action until then
    last_state_at: float | None = None
    battery: float = field(init=False)  # its charge, %
    charging: bool = False

    def __post_init__(self) -> None:
        self.headers = Headers(self.vehicle)
        self.x, self.y = self.spec.start
        self.battery = min(100.0, max(0.0, self.spec.battery_pct))
        self._ids = itertools.count()

    # ---- what arrives -------------------------------------------------------------------------

    def on_order(self, order: dict[str, Any], now: float) -> list[Message]:
        """An `order`: a new one, an update stitched onto the current base, or a refusal."""
        self.errors = [
            e
            for e in self.errors
            if e["errorType"] not in ("orderUpdateError", "noRouteError", "orderError")
        ]
        same = order["orderId"] == self.order_id
        if same and order["orderUpdateId"] == self.update_id:
            return []  # the same again: nothing to do
        if self.charging:
            why = "order is not executable while charging"
            return self._refuse("orderError", why, order, now)
        nodes = sorted(order["nodes"], key=lambda n: n["sequenceId"])
        if "no_route" in self.spec.quirks:
            return self._refuse("noRouteError", "no route to the order's nodes", order, now)
        first = nodes[0]
        if same:
            base = [n for n in self.nodes if n.released]
            stitch = (base[-1].node_id, base[-1].sequence_id) if base else self.last_node
            if (
                "reject_updates" in self.spec.quirks
                or order["orderUpdateId"] < self.update_id
                or (first["nodeId"], first["sequenceId"]) != stitch
            ):
                why = "the update does not continue the base"
                return self._refuse("orderUpdateError", why, order, now)
            kept = base
        else:
            if any(n.released for n in self.nodes):
                return self._refuse("orderUpdateError", "an order is still under way", order, now)
            at = first["nodePosition"]
            # Within a square of it: stopped between two nodes, it may start at the next.
            if math.dist((at["x"], at["y"]), (self.x, self.y)) > max(
                REACH_M, at.get("allowedDeviationXY", 0.0)
            ):
                why = "the first node is not where it stands"
                return self._refuse("noRouteError", why, order, now)
            self.last_node = (first["nodeId"], first["sequenceId"])
            self.actions = {}
            kept = []
        self.order_id, self.update_id = order["orderId"], order["orderUpdateId"]
        # The first node's actions: done where it stands, or added to the base node it is.
        if kept:
            kept[-1].actions += first.get("actions", [])
        else:
            self._start_actions(first.get("actions", []), now)
        self.nodes = kept + [
            _Node(
                n["nodeId"],
                n["sequenceId"],
                n["released"],
                n["nodePosition"]["x"],
                n["nodePosition"]["y"],
                list(n.get("actions", [])),
            )
            for n in nodes[1:]
        ]
        for node in self.nodes:
            for a in node.actions:
                self.actions.setdefault(a["actionId"], _Action(a))
        return [("state", self.state(now))]

    def _start_actions(self, actions: list[dict[str, Any]], now: float) -> None:
        """Do `actions` standing still (a pick or a drop takes `action_s`)."""
        for a in actions:
            self.actions[a["actionId"]] = _Action(a, "RUNNING")
        if actions:
            self.busy_until, self.driving = now + self.spec.action_s, False

    def _refuse(self, kind: str, why: str, order: dict[str, Any], now: float) -> list[Message]:
        self.errors.append(
            {
                "errorType": kind,
                "errorLevel": "WARNING",
                "errorDescription": why,
                "errorReferences": [
                    {"referenceKey": "orderId", "referenceValue": order["orderId"]},
                    {
                        "referenceKey": "orderUpdateId",
                        "referenceValue": str(order["orderUpdateId"]),
                    },
                ],
            }
        )
        return [("state", self.state(now))]

    def on_instant_actions(self, message: dict[str, Any], now: float) -> list[Message]:
        """`instantActions`: pause, resume, cancel, factsheet request."""
        out: list[Message] = []
        for action in message.get("actions", []):
            kind = action.get("actionType") or action.get("actionName")
            done = _Action(action, "FINISHED")
            self.actions[action["actionId"]] = done
            if kind == "startPause":
                self.paused, self.driving = True, False
            elif kind == "stopPause":
                self.paused = False
            elif kind == "cancelOrder":
                if not self.nodes and not self._running():
                    done.status = "FAILED"
                    self.errors.append(
                        {
                            "errorType": "noOrderToCancel",
                            "errorLevel": "WARNING",
                            "errorDescription": "no order to cancel",
                            "errorReferences": [
                                {"referenceKey": "actionId", "referenceValue": action["actionId"]}
                            ],
                        }
                    )
                else:
                    self._cancel()
            elif kind == "factsheetRequest":
                out.append(("factsheet", self.factsheet(now)))
            elif kind == "startCharging":
                self._start_charging(done)
            elif kind == "stopCharging":
                if self.charging:
                    self.charging = False
                else:
                    done.status, done.description = "FAILED", "charging not in progress"
            else:
                done.status, done.description = "FAILED", f"{kind} is not supported"
        return [*out, ("state", self.state(now))]

    def _start_charging(self, done: _Action) -> None:
        """Charge where it stands, if it may (else the action FAILED, and why)."""
        self.errors = [e for e in self.errors if e["errorType"] != "chargingError"]
        if self.charging:
            return  # charging already: idempotent, as the spec's table says
        if self.driving or any(n.released for n in self.nodes) or self._running():
            done.status, done.description = "FAILED", "charging denied: an order is under way"
            return
        stations = self.spec.chargers
        if stations is not None and not any(
            math.dist(at, (self.x, self.y)) <= REACH_M for at in stations
        ):
            done.status, done.description = "FAILED", "not aligned to charger"
            self.errors.append(
                {
                    "errorType": "chargingError",
                    "errorLevel": "WARNING",
                    "errorDescription": "not aligned to charger: no charging station here",
                    "errorReferences": [
                        {"referenceKey": "actionId", "referenceValue": done.action["actionId"]}
                    ],
                }
            )
            return
        self.charging = True

    def _running(self) -> bool:
        return any(a.status in ("WAITING", "RUNNING") for a in self.actions.values())

    def _cancel(self) -> None:
        """Stop where it is (a stopping distance of 0), drop the order's nodes and actions."""
        self.nodes = []
        self.driving = False
        self.busy_until = None
        for a in self.actions.values():
            if a.status in ("WAITING", "RUNNING"):
                a.status = "FAILED"

    # ---- time ---------------------------------------------------------------------------------

    def advance(self, now: float, dt: float) -> list[Message]:
        """`dt` seconds of driving up to `now`; a state on every event and when one is due."""
        events = False
        percent = int(self.battery)
        if self.busy_until is not None and now >= self.busy_until:
            self._finish_actions()
            self.busy_until = None
            events = True
        moving = (
            not self.paused
            and not self.charging
            and self.battery > 0
            and self.busy_until is None
            and self.nodes
            and self.nodes[0].released
        )
        if moving:
            events |= self._drive(now, dt)
        elif self.driving:
            self.driving, events = False, True
        if self.charging:
            self.battery = min(100.0, self.battery + self.spec.charge_pct_per_s * dt)
        elif not self.driving:
            self.battery = max(0.0, self.battery - self.spec.idle_pct_per_s * dt)
        events |= self._empty() or int(self.battery) != percent  # its battery by whole percents
        due = self.last_state_at is None or now - self.last_state_at >= self.spec.state_every_s
        return [("state", self.state(now))] if events or due else []

    def _drive(self, now: float, dt: float) -> bool:
        node = self.nodes[0]
        step = self.spec.speed * dt
        gap = math.dist((self.x, self.y), (node.x, node.y))
        started = not self.driving
        self.driving = True
        if gap > step:
            self.theta = math.atan2(node.y - self.y, node.x - self.x)
            self.x += (node.x - self.x) * step / gap
            self.y += (node.y - self.y) * step / gap
            return started
        self.x, self.y = node.x, node.y
        self.last_node = (node.node_id, node.sequence_id)
        self.nodes.pop(0)
        self.battery = max(0.0, self.battery - self.spec.node_pct)
        if node.actions:
            self._start_actions(node.actions, now)
        elif not (self.nodes and self.nodes[0].released):
            self.driving = False
        return True

    def _empty(self) -> bool:
        """A `batteryLowError` while it has nodes to drive at 0 %, gone once it has charged;
        whether that changed."""
        empty = self.battery <= 0 and any(n.released for n in self.nodes)
        told = any(e["errorType"] == "batteryLowError" for e in self.errors)
        if empty == told:
            return False
        if empty:
            self.driving = False
            self.errors.append(
                {
                    "errorType": "batteryLowError",
                    "errorLevel": "WARNING",
                    "errorDescription": "battery empty: cannot drive",
                }
            )
        else:
            self.errors = [e for e in self.errors if e["errorType"] != "batteryLowError"]
        return True

    def _finish_actions(self) -> None:
        for a in self.actions.values():
            if a.status != "RUNNING":
                continue
            a.status = "FINISHED"
            params = {p["key"]: p["value"] for p in a.action.get("actionParameters", [])}
            load = str(params.get("loadId", a.action["actionId"]))
            if a.action["actionType"] == "pick":
                self.loads[load] = float(params.get("weight", 0.0))
            elif a.action["actionType"] == "drop":
                self.loads.pop(load, None)

    # ---- what goes out ------------------------------------------------------------------------

    def connection(
        self, state: Literal["ONLINE", "OFFLINE", "CONNECTIONBROKEN"], now: float
    ) -> dict[str, Any]:
        """The `connection` message."""
        return {**self.headers("connection", now), "connectionState": state}

    def state(self, now: float) -> dict[str, Any]:
        """The `state` message now."""
        self.last_state_at = now
        message: dict[str, Any] = {
            **self.headers("state", now),
            "orderId": self.order_id,
            "orderUpdateId": self.update_id,
            "lastNodeId": self.last_node[0],
            "lastNodeSequenceId": self.last_node[1],
            "nodeStates": [
                {"nodeId": n.node_id, "sequenceId": n.sequence_id, "released": n.released}
                for n in self.nodes
            ],
            "edgeStates": [],
            "agvPosition": {
                "x": round(self.x, 4),
                "y": round(self.y, 4),
                "theta": round(self.theta, 4),
                "mapId": self.spec.map_id,
                "positionInitialized": True,
            },
            "driving": self.driving,
            "paused": self.paused,
            "actionStates": [
                {
                    "actionId": a.action["actionId"],
                    "actionType": a.action.get("actionType") or a.action.get("actionName"),
                    "actionStatus": a.status,
                    **({"resultDescription": a.description} if a.description else {}),
                }
                for a in self.actions.values()
            ],
            "batteryState": {"batteryCharge": round(self.battery, 2), "charging": self.charging},
            "operatingMode": "AUTOMATIC",
            "errors": list(self.errors),
            "safetyState": {"eStop": "NONE", "fieldViolation": False},
            "loads": [
                {"loadId": load}
                if "weightless_loads" in self.spec.quirks
                else {"loadId": load, "weight": kg}
                for load, kg in sorted(self.loads.items())
            ],
        }
        return message

    def factsheet(self, now: float) -> dict[str, Any]:
        """The `factsheet` (2.1): what it is, carries and does."""
        actions = [
            {"actionType": kind, "actionScopes": scopes}
            for kind, scopes in (
                ("pick", ["NODE"]),
                ("drop", ["NODE"]),
                ("startPause", ["INSTANT"]),
                ("stopPause", ["INSTANT"]),
                ("cancelOrder", ["INSTANT"]),
                ("factsheetRequest", ["INSTANT"]),
                ("startCharging", ["INSTANT"]),
                ("stopCharging", ["INSTANT"]),
            )
        ]
        return {
            **self.headers("factsheet", now),
            "typeSpecification": {
                "seriesName": "gridfleet-virtual",
                "agvKinematic": "OMNI",
                "agvClass": "CARRIER",
                "maxLoadMass": self.spec.capacity_kg,
                "localizationTypes": ["GRID"],
                "navigationTypes": ["PHYSICAL_LINE_GUIDED"],
            },
            "physicalParameters": {
                "speedMin": 0.0,
                "speedMax": self.spec.speed,
                "accelerationMax": 1.0,
                "decelerationMax": 1.0,
                "heightMax": 0.2,
                "width": 0.08,
                "length": 0.08,
            },
            "protocolLimits": {
                "maxStringLens": {},
                "maxArrayLens": {},
                "timing": {"minOrderInterval": 0.0, "minStateInterval": 0.0},
            },
            "protocolFeatures": {"optionalParameters": [], "agvActions": actions},
            "agvGeometry": {},
            "loadSpecification": {
                "loadSets": [
                    {"setName": "crate", "loadType": "crate", "maxWeight": self.spec.capacity_kg}
                ]
            },
        }
