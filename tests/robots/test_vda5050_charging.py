"""A VDA 5050 vehicle's energy as a gridfleet unit's (robots/vda5050/core.py, charging.py):
its batteryState is the unit's battery, its vehicles file's `energy` the factsheet's, and the
order's `charge` starts and stops its charge by `startCharging` / `stopCharging`, pure, against
hand-made states and against our own virtual vehicle; all sent to a vehicle valid against its
official schema."""

from __future__ import annotations

import json
from typing import Any

import pytest
from test_vda5050_core import GRID, STAMP_AT, T0, TOPICS, at, connection, kinds, unit_state, vda

from gridfleet.grid import Cell
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    EnergyModel,
    ErrorReport,
    Factsheet,
    HeaderStamper,
    Order,
    UnitState,
    decode,
    encode,
)
from gridfleet.protocol.device import EstopSignal, encode_estop
from gridfleet.robots.vda5050.charging import Charge, Charging
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.core import EMPTY, VehicleCore
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.resend import RESEND_S
from gridfleet.robots.vda5050.virtual import VirtualSpec, VirtualVehicle
from gridfleet.robots.vda5050.wire import Vehicle, Version

from support.vda import SCHEMAS, official, state

ENERGY = EnergyModel(move_pct=0.5, idle_pct_per_s=0.01, charge_pct_per_s=2.0)
FRAME = Frame("hall")
CHARGER = Cell(1, 0)


def core(
    version: Version = "2.0.0", energy: EnergyModel | None = ENERGY, serial: str = "sn-7"
) -> VehicleCore:
    config = VehicleConfig(
        Vehicle("agv1", "acme", serial, version), FRAME, 20.0, 0.0, False, energy=energy
    )
    checker = official() if SCHEMAS.exists() else None
    return VehicleCore(
        config,
        GRID,
        TOPICS,
        run_id="r1",
        step_s=0.5,
        stamp=HeaderStamper("agv1", lambda: STAMP_AT),
        check=None if checker is None else lambda topic, m: checker.check(version, topic, m),
    )


def order(update: int, released: list[Cell], charge: Cell | None = None) -> bytes:
    stamp = HeaderStamper("coordinator", lambda: STAMP_AT)
    return encode(
        Order(
            header=stamp("order"),
            order_id="c-agv1-1",
            update_id=update,
            released=released,
            charge=charge,
        )
    )


def instants(outs: list[Outbound]) -> list[tuple[str, str, str]]:
    """Each instant action sent: (type, id, blocking)."""
    return [
        (a["actionType"], a["actionId"], a["blockingType"])
        for o in outs
        if o.topic.endswith("/instantActions")
        for a in json.loads(o.payload)["actions"]
    ]


def states(outs: list[Outbound]) -> list[UnitState]:
    return [decode(UnitState, o.payload) for o in outs if o.topic == TOPICS.unit("state", "agv1")]


def charging(pct: float, on: bool, **more: Any) -> bytes:
    """A state of the vehicle standing on CHARGER (its order done) with this battery."""
    return vda(
        state(
            agvPosition=at(*CHARGER),
            lastNodeId="sq-1-0",
            batteryState={"batteryCharge": pct, "charging": on},
            **more,
        )
    )


def at_charger(c: VehicleCore, version: Version = "2.0.0") -> list[Outbound]:
    """The vehicle on line at CHARGER, its unit told (update 1) to charge there; what the
    vehicle's state showing the order it was sent (its first: one node, where it stands) makes."""
    c.on_vehicle("connection", connection(version=version), T0)
    c.on_vehicle("state", vda(state(version, **_at_charger(40.0, False))), T0)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [], CHARGER), T0)
    (sent,) = [json.loads(o.payload) for o in outs if o.topic.endswith("/order")]
    assert instants(outs) == []  # not before the vehicle has shown its order
    shown = state(version, **_at_charger(40.0, False), orderId=sent["orderId"])
    return c.on_vehicle("state", vda(shown), T0)


def test_the_units_battery_and_energy_are_the_vehicles_and_its_files() -> None:
    c = core()
    c.on_vehicle("connection", connection(), T0)
    outs = c.on_vehicle("state", charging(130.0, False), T0)
    factsheet = decode(Factsheet, next(o for o in outs if o.topic.endswith("/factsheet")).payload)
    assert factsheet.energy == ENERGY
    assert (unit_state(outs).battery_pct, unit_state(outs).charging) == (100.0, False)  # clamped
    outs = c.on_vehicle("state", charging(-3.0, True), T0 + 1)
    assert (unit_state(outs).battery_pct, unit_state(outs).charging) == (0.0, True)
    # Every state of the vehicle's is the unit's, with the exact figure.
    outs = c.on_vehicle("state", charging(54.87, False), T0 + 2)
    assert (unit_state(outs).battery_pct, unit_state(outs).charging) == (54.87, False)


def test_without_energy_in_its_vehicles_file_the_unit_reports_none() -> None:
    c = core(energy=None)
    c.on_vehicle("connection", connection(), T0)
    outs = c.on_vehicle("state", charging(40.0, True), T0)
    assert decode(Factsheet, outs[1].payload).energy is None
    assert (unit_state(outs).battery_pct, unit_state(outs).charging) == (None, False)
    # The vehicle's own condition still says it (units/<unit>/vehicle, for the dashboard).
    assert kinds(outs)[-1] == "units/agv1/vehicle"


@pytest.mark.parametrize("version", ["2.0.0", "2.1.0"])
def test_an_order_to_charge_where_it_stands_starts_the_charge_and_heartbeats_keep_it(
    version: Version,
) -> None:
    c = core(version)
    outs = at_charger(c, version)
    ((kind, start_id, blocking),) = instants(outs)  # held to the official schema as it went
    assert (kind, blocking) == ("startCharging", "HARD")
    assert unit_state(outs).charging is False  # not before the vehicle says so
    started = c.on_vehicle(
        "state",
        vda(
            state(
                version,
                **_at_charger(40.0, True),
                actionStates=[_action(start_id, "FINISHED")],
            )
        ),
        T0 + 1,
    )
    assert (unit_state(started).charging, unit_state(started).battery_pct) == (True, 40.0)
    # The coordinator's heartbeat names the charger again: nothing more for the vehicle.
    again = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, [], CHARGER), T0 + 2)
    assert kinds(again) == ["units/agv1/state"] and unit_state(again).order_update_id == 2


def _at_charger(pct: float, on: bool) -> dict[str, Any]:
    return {
        "agvPosition": at(*CHARGER),
        "lastNodeId": "sq-1-0",
        "batteryState": {"batteryCharge": pct, "charging": on},
    }


def _action(action_id: str, status: str, kind: str | None = None) -> dict[str, str]:
    return {
        "actionId": action_id,
        "actionType": kind or action_id.split("-")[0],
        "actionStatus": status,
    }


def test_no_charge_starts_before_the_vehicle_stands_there_with_nothing_left() -> None:
    c = core()
    c.on_vehicle("connection", connection(), T0)
    c.on_vehicle("state", vda(state(agvPosition=at(0, 0))), T0)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [CHARGER], CHARGER), T0)
    assert kinds(outs)[0] == "order" and instants(outs) == []
    sent = json.loads(outs[0].payload)
    driving = state(
        agvPosition=at(*CHARGER),
        driving=True,
        orderId=sent["orderId"],
        nodeStates=[{"nodeId": "sq-1-0", "sequenceId": 2, "released": True}],
    )
    assert instants(c.on_vehicle("state", vda(driving), T0 + 1)) == []
    arrived = state(
        agvPosition=at(*CHARGER), orderId=sent["orderId"], lastNodeId="sq-1-0", lastNodeSequenceId=2
    )
    assert [a[0] for a in instants(c.on_vehicle("state", vda(arrived), T0 + 2))] == [
        "startCharging"
    ]


def test_an_order_elsewhere_stops_the_charge_first_and_goes_nowhere_until_it_has() -> None:
    c = core()
    ((_, start_id, _),) = instants(at_charger(c))
    c.on_vehicle("state", charging(60.0, True, actionStates=[_action(start_id, "FINISHED")]), T0)
    away = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, [Cell(2, 0)]), T0 + 1)
    ((kind, stop_id, blocking),) = instants(away)
    assert (kind, blocking) == ("stopCharging", "HARD")
    assert "order" not in kinds(away)  # a charging vehicle takes no order
    told = unit_state(away)
    assert (told.order_update_id, told.released, told.charging) == (2, [], True)
    # Acknowledged, the coordinator's next updates go nowhere either until the charge is over.
    assert kinds(c.on_fleet(TOPICS.unit("order", "agv1"), order(3, [Cell(2, 0)]), T0 + 2)) == [
        "units/agv1/state"
    ]
    stopping = charging(61.0, True, actionStates=[_action(stop_id, "RUNNING")])
    assert instants(c.on_vehicle("state", stopping, T0 + 3)) == []  # no second stop
    done = charging(61.0, False, actionStates=[_action(stop_id, "FINISHED")])
    assert unit_state(c.on_vehicle("state", done, T0 + 4)).charging is False
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(4, [Cell(2, 0)]), T0 + 5)
    assert kinds(outs)[0] == "order" and instants(outs) == []  # and no new charge meanwhile
    assert [n["nodeId"] for n in json.loads(outs[0].payload)["nodes"]] == ["sq-1-0", "sq-2-0"]


def test_an_order_naming_no_charger_stops_the_charge_and_the_next_one_may_start_it() -> None:
    c = core()
    at_charger(c)
    c.on_vehicle("state", charging(60.0, True), T0)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, []), T0 + 1)
    assert [a[0] for a in instants(outs)] == ["stopCharging"]
    c.on_vehicle("state", charging(60.0, False), T0 + 2)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(3, [], CHARGER), T0 + 3)
    assert [a[0] for a in instants(outs)] == ["startCharging"]


def test_a_failed_start_is_reported_once_and_not_tried_again_until_ordered_afresh() -> None:
    c = core()
    (start,) = instants(at_charger(c))
    refusal = {
        "errorType": "chargingError",
        "errorLevel": "WARNING",
        "errorDescription": "not aligned to charger",
        "errorReferences": [{"referenceKey": "actionId", "referenceValue": start[1]}],
    }
    failed = charging(40.0, False, actionStates=[_action(start[1], "FAILED")], errors=[refusal])
    outs = c.on_vehicle("state", failed, T0 + 1)
    (report,) = [decode(ErrorReport, o.payload) for o in outs if o.topic.endswith("/errors")]
    assert "startCharging failed (not aligned to charger)" in report.reason
    (error,) = unit_state(outs).errors
    assert error.code == "no_charger" and "[1, 0]" in error.message
    # Its states and the coordinator's heartbeats start nothing again, nor say it again.
    for n in range(2, 6):
        outs = c.on_vehicle("state", failed, T0 + n) + c.on_fleet(
            TOPICS.unit("order", "agv1"), order(n, [], CHARGER), T0 + n
        )
        outs += c.tick(T0 + n + 0.5)
        assert instants(outs) == [] and all(not s.errors for s in states(outs))
    # Ordered afresh (no charge, then the charger again): one more try.
    c.on_fleet(TOPICS.unit("order", "agv1"), order(6, []), T0 + 6)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(7, [], CHARGER), T0 + 7)
    assert [a[0] for a in instants(outs)] == ["startCharging"]


def test_a_start_no_state_shows_is_sent_again_under_its_id() -> None:
    c = core()
    (start,) = instants(at_charger(c))
    assert instants(c.tick(T0 + RESEND_S / 2)) == []
    assert instants(c.tick(T0 + RESEND_S + 0.1)) == [start]  # lost (QoS 0): the same again
    listed = charging(40.0, False, actionStates=[_action(start[1], "WAITING")])
    c.on_vehicle("state", listed, T0 + 2)
    assert instants(c.tick(T0 + 5)) == []  # it has it: its outcome is awaited


def test_under_the_stop_the_charge_goes_on_and_the_release_finds_it_charging() -> None:
    c = core()
    at_charger(c)
    c.on_vehicle("state", charging(50.0, True), T0)
    latch = TOPICS.fleet("estop")
    outs = c.on_fleet(latch, encode_estop(EstopSignal(True, "dashboard", "")), T0 + 1)
    assert [a[0] for a in instants(outs)] == ["startPause"]
    halt = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, []), T0 + 2)  # no charge: a halt
    assert instants(halt) == []
    outs = c.on_fleet(latch, encode_estop(EstopSignal(False, "dashboard", "")), T0 + 3)
    assert [a[0] for a in instants(outs)] == ["stopPause"]
    c.on_vehicle("state", charging(50.0, True), T0 + 4)
    assert instants(c.on_fleet(TOPICS.unit("order", "agv1"), order(3, [], CHARGER), T0 + 5)) == []


def test_a_charge_the_vehicle_ends_itself_is_not_started_again() -> None:
    c = core()
    (start,) = instants(at_charger(c))
    c.on_vehicle("state", charging(90.0, True, actionStates=[_action(start[1], "FINISHED")]), T0)
    # Full, it stops itself (the spec lets it): the unit charged there stays `charging`.
    outs = c.on_vehicle("state", charging(100.0, False), T0 + 1)
    assert (unit_state(outs).charging, unit_state(outs).errors) == (True, [])
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, [], CHARGER), T0 + 2)
    assert instants(outs) == []
    # One that ended short of full (its charger's doing) says so, and is not `charging`.
    d = core(serial="sn-7")
    (start,) = instants(at_charger(d))
    d.on_vehicle("state", charging(40.0, True, actionStates=[_action(start[1], "FINISHED")]), T0)
    outs = d.on_vehicle("state", charging(43.0, False), T0 + 1)
    assert unit_state(outs).charging is False
    assert [(e.code, e.message) for e in unit_state(outs).errors] == [
        ("charge_ended", "the vehicle ended its charge itself at 43 %")
    ]
    assert instants(d.on_fleet(TOPICS.unit("order", "agv1"), order(2, [], CHARGER), T0 + 2)) == []


def test_at_zero_it_waits_saying_its_battery_is_empty() -> None:
    c = core()
    c.on_vehicle("connection", connection(), T0)
    c.on_vehicle("state", vda(state(batteryState={"batteryCharge": 0.0, "charging": False})), T0)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0)]), T0)
    assert (unit_state(outs).status, unit_state(outs).wait_reason) == ("waiting", EMPTY)


# ---- with our own virtual vehicle ----------------------------------------------------------


class Loop:
    """The adapter's core and a virtual vehicle, wired to each other; the fleet's side kept."""

    def __init__(self, version: Version, spec: VirtualSpec) -> None:
        self.core = core(version)
        self.vehicle = VirtualVehicle(Vehicle("agv1", "acme", "sn-7", version), spec)
        self.version = version
        self.now = T0
        self.fleet: list[Outbound] = []  # what the adapter told the fleet
        self.sent: list[tuple[str, dict[str, Any]]] = []  # what the adapter told the vehicle
        self.deliver(self.core.on_vehicle("connection", connection(version=version), T0))
        self.heard(self.vehicle.advance(T0, 0.0))

    def deliver(self, outs: list[Outbound]) -> None:
        for out in outs:
            if out.topic.endswith("/order") and out.topic.startswith("uagv/"):
                self.sent.append(("order", json.loads(out.payload)))
                self.heard(self.vehicle.on_order(json.loads(out.payload), self.now))
            elif out.topic.endswith("/instantActions"):
                self.sent.append(("instantActions", json.loads(out.payload)))
                self.heard(self.vehicle.on_instant_actions(json.loads(out.payload), self.now))
            else:
                self.fleet.append(out)

    def heard(self, messages: list[tuple[str, dict[str, Any]]]) -> None:
        for name, message in messages:
            if name in ("state", "factsheet"):
                self.deliver(self.core.on_vehicle(name, vda(message), self.now))  # type: ignore[arg-type]

    def order(self, update: int, released: list[Cell], charge: Cell | None = None) -> None:
        self.deliver(
            self.core.on_fleet(
                TOPICS.unit("order", "agv1"), order(update, released, charge), self.now
            )
        )

    def run(self, seconds: float) -> None:
        for n in range(int(seconds / 0.05)):
            self.now += 0.05
            self.heard(self.vehicle.advance(self.now, 0.05))
            if n % 10 == 9:
                self.deliver(self.core.tick(self.now))

    def last(self) -> UnitState:
        return states(self.fleet)[-1]

    def actions(self) -> list[str]:
        return [
            a["actionType"]
            for name, m in self.sent
            if name == "instantActions"
            for a in m["actions"]
            if a["actionType"] in ("startCharging", "stopCharging")
        ]


@pytest.mark.parametrize("version", ["2.0.0", "2.1.0"])
def test_our_vehicle_drives_to_the_charger_charges_and_leaves_when_sent_on(
    version: Version,
) -> None:
    spec = VirtualSpec(
        FRAME.position(Cell(0, 0)),
        "hall",
        speed=1.0,
        battery_pct=30.0,
        node_pct=0.5,
        chargers=(FRAME.position(CHARGER),),
        state_every_s=0.5,
    )
    loop = Loop(version, spec)
    loop.order(1, [CHARGER], CHARGER)
    loop.run(1.0)
    assert loop.actions() == ["startCharging"]
    assert loop.vehicle.charging and loop.last().charging
    loop.run(5.0)
    assert loop.last().battery_pct is not None and loop.last().battery_pct > 38.0  # 2 % a second
    loop.order(2, [Cell(2, 0)])  # a job: on to (2, 0)
    loop.run(1.0)
    assert loop.actions() == ["startCharging", "stopCharging"]
    assert not loop.vehicle.charging
    assert not any(e["errorType"] == "orderError" for e in loop.vehicle.errors)  # never refused
    loop.order(3, [Cell(2, 0)])
    loop.run(1.0)
    assert (loop.last().position, loop.last().charging) == ((2, 0), False)
    schemas = official() if SCHEMAS.exists() else None
    for name, message in loop.sent if schemas is not None else []:
        assert schemas.problems(version, name, message) == [], (name, message)


def test_our_vehicle_off_its_charging_station_fails_the_start_and_the_unit_says_so() -> None:
    spec = VirtualSpec(
        FRAME.position(CHARGER), "hall", chargers=(FRAME.position(Cell(3, 2)),), state_every_s=0.5
    )
    loop = Loop("2.1.0", spec)
    loop.order(1, [], CHARGER)
    loop.run(3.0)
    assert loop.actions() == ["startCharging"]  # once
    errors = [e for s in states(loop.fleet) for e in s.errors]
    assert [e.code for e in errors] == ["no_charger"]
    assert "not aligned to charger" in errors[0].message
    assert not loop.last().charging


def test_the_charge_machine_refuses_what_its_table_does_not_list() -> None:
    m = Charging()
    assert not m.stop("s1", T0) and m.state is Charge.NONE  # nothing to stop
    assert m.start("c1", CHARGER, T0) and not m.start("c2", CHARGER, T0)  # one start in flight
    assert m.busy and m.seen(False, frozenset(), frozenset({"c1"}), CHARGER) == "failed"
    assert (m.state, m.busy, m.square) == (Charge.FAILED, False, CHARGER)
    assert not m.start("c3", CHARGER, T0)  # not again until ordered afresh
    assert m.forget() and m.start("c4", CHARGER, T0)
    assert m.seen(True, frozenset(), frozenset(), CHARGER) == "started"  # charging says it
    assert m.stop("s2", T0) and m.seen(True, frozenset(), frozenset({"s2"}), CHARGER) == (
        "stop_failed"
    )
    assert not m.stop("s3", T0)  # it said it cannot: no second stop
    assert m.seen(False, frozenset(), frozenset(), CHARGER) == "stopped" and m.state is Charge.NONE
    assert m.seen(True, frozenset(), frozenset(), Cell(2, 2)) == "adopted"  # it charges anyway
    assert (m.state, m.square) == (Charge.CHARGING, Cell(2, 2))
