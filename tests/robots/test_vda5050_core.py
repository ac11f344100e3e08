"""One VDA 5050 vehicle as a gridfleet unit (robots/vda5050/core.py): messages in, exactly what
is published out, on both sides; everything sent to the vehicle valid against its official schema."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from typing import Any

import pytest

from gridfleet.grid import Cell, GridMap
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    Action,
    Connection,
    ErrorReport,
    Factsheet,
    HeaderStamper,
    Order,
    Topics,
    UnitState,
    VehicleCondition,
    decode,
    encode,
)
from gridfleet.protocol.device import EstopSignal, encode_estop
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.core import VehicleCore
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.virtual import VirtualSpec, VirtualVehicle
from gridfleet.robots.vda5050.wire import Vehicle, Version

from support.vda import SCHEMAS, needs_schemas, official, state

T0 = 1_795_000_000.0
TOPICS = Topics("t")
GRID = GridMap.from_rows(["....", "....", "...."], name="bay")
STAMP_AT = datetime(2026, 11, 26, 12, 0, tzinfo=UTC)
VDA = "uagv/v2/acme/sn-7/"


def core(version: Version = "2.0.0", capacity: float | None = 20.0) -> VehicleCore:
    config = VehicleConfig(
        Vehicle("agv1", "acme", "sn-7", version), Frame("hall"), capacity, 0.0, False
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


def at(x: int, y: int) -> dict[str, Any]:
    """A VDA position at the centre of square (x, y) (y up on the vehicle's map)."""
    return {"x": x / 10, "y": -y / 10, "theta": 0.0, "mapId": "hall", "positionInitialized": True}


def vda(message: dict[str, Any]) -> bytes:
    return json.dumps(message).encode()


def connection(status: str = "ONLINE", version: str = "2.0.0") -> bytes:
    return vda(
        {
            "headerId": 0,
            "timestamp": "2026-11-26T12:00:00.000Z",
            "version": version,
            "manufacturer": "acme",
            "serialNumber": "sn-7",
            "connectionState": status,
        }
    )


def kinds(outs: list[Outbound]) -> list[str]:
    """Each message's topic, without the roots."""
    return [o.topic.removeprefix("t/v1/").removeprefix(VDA) for o in outs]


def unit_state(outs: list[Outbound]) -> UnitState:
    (found,) = [o for o in outs if o.topic == TOPICS.unit("state", "agv1")]
    return decode(UnitState, found.payload)


def online(c: VehicleCore) -> list[Outbound]:
    outs = c.on_vehicle("connection", connection(), T0)
    return outs + c.on_vehicle("state", vda(state(agvPosition=at(0, 0))), T0)


def order(update: int, released: list[Cell], planned: tuple[Cell, ...] = (), **more: Any) -> bytes:
    stamp = HeaderStamper("coordinator", lambda: STAMP_AT)
    return encode(
        Order(
            header=stamp("order"),
            order_id="c-agv1-1",
            update_id=update,
            released=released,
            planned=list(planned),
            **more,
        )
    )


def sent_to_pick() -> VehicleCore:
    """A vehicle on line at (0, 0), sent to pick job-1 (2.5 kg) at (1, 0)."""
    c = core()
    online(c)
    pick = Action(kind="pick", job_id="job-1", square=Cell(1, 0), mass_kg=2.5)
    c.on_fleet(
        TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0)], target=Cell(1, 0), action=pick), T0
    )
    return c


def pick_state(status: str) -> dict[str, str]:
    """The action state of job-1's pick."""
    return {"actionId": "pick-job-1", "actionType": "pick", "actionStatus": status}


def test_the_unit_comes_online_once_the_vehicle_is_and_says_where_it_stands() -> None:
    c = core()
    asked = c.on_vehicle("connection", connection(), T0)  # not yet: where is it? it is asked
    assert kinds(asked) == ["instantActions"]
    assert [a["actionType"] for a in json.loads(asked[0].payload)["actions"]] == ["stateRequest"]
    outs = c.on_vehicle("state", vda(state(agvPosition=at(0, 0))), T0)
    assert kinds(outs) == [
        "units/agv1/connection",
        "units/agv1/factsheet",
        "units/agv1/state",
        "units/agv1/direction",
        "units/agv1/vehicle",
    ]
    told = decode(VehicleCondition, outs[4].payload)
    assert (told.battery_pct, told.charging, told.errors) == (81.5, False, [])
    assert (outs[4].qos, outs[4].retain) == (1, True)
    assert decode(Connection, outs[0].payload).state == "online"
    factsheet = decode(Factsheet, outs[1].payload)
    assert (factsheet.capacity_kg, factsheet.sensors, factsheet.model) == (
        20.0,
        [],
        "vda5050-2.0.0",
    )
    assert factsheet.map_id == GRID.map_id()
    st = unit_state(outs)
    assert (st.position, st.status, st.direction, st.released, st.estop) == (
        (0, 0),
        "idle",
        "-",
        [],
        False,
    )
    assert outs[3].payload == b"-"


@needs_schemas
def test_a_2_1_vehicle_is_asked_its_factsheet_and_its_capacity_is_the_units() -> None:
    c = core("2.1.0", capacity=None)
    outs = c.on_vehicle("connection", connection(version="2.1.0"), T0)
    assert kinds(outs) == ["instantActions", "instantActions"]
    asked = [json.loads(o.payload)["actions"][0]["actionType"] for o in outs]
    assert asked == ["stateRequest", "factsheetRequest"]
    # Not a unit before its capacity is known; its own condition is told all the same.
    early = c.on_vehicle("state", vda(state("2.1.0", agvPosition=at(0, 0))), T0)
    assert kinds(early) == ["units/agv1/vehicle"]
    virtual = VirtualVehicle(
        Vehicle("agv1", "acme", "sn-7", "2.1.0"), VirtualSpec((0.0, 0.0), "hall", capacity_kg=7.5)
    )
    sheet = virtual.factsheet(T0)
    assert official().problems("2.1.0", "factsheet", sheet) == []
    outs = c.on_vehicle("factsheet", vda(sheet), T0)
    assert kinds(outs)[:2] == ["units/agv1/connection", "units/agv1/factsheet"]
    assert decode(Factsheet, outs[1].payload).capacity_kg == 7.5


@needs_schemas
def test_released_squares_become_the_base_and_the_square_behind_is_held_until_left() -> None:
    c = core()
    online(c)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0)], [Cell(2, 0)]), T0)
    assert kinds(outs) == ["order", "units/agv1/state", "units/agv1/direction"]
    sent = json.loads(outs[0].payload)
    assert [(n["nodeId"], n["released"]) for n in sent["nodes"]] == [
        ("sq-0-0", True),
        ("sq-1-0", True),
        ("sq-2-0", False),
    ]
    acked = unit_state(outs)
    assert (acked.order_id, acked.order_update_id, acked.released) == ("c-agv1-1", 1, [(1, 0)])
    assert outs[2].payload == b"E"
    # Half way: it holds (0, 0) as its square and (1, 0) as released.
    between = state(agvPosition={**at(0, 0), "x": 0.05}, driving=True, orderId=sent["orderId"])
    st = unit_state(c.on_vehicle("state", vda(between), T0 + 1))
    assert (st.position, st.released, st.status) == ((0, 0), [(1, 0)], "moving")
    arrived = state(
        agvPosition=at(1, 0), orderId=sent["orderId"], lastNodeId="sq-1-0", lastNodeSequenceId=2
    )
    st = unit_state(c.on_vehicle("state", vda(arrived), T0 + 2))
    assert (st.position, st.released, st.status) == ((1, 0), [], "idle")
    # The same release again (a heartbeat) adds nothing for the vehicle: only the acknowledgement.
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, [], [Cell(2, 0)]), T0 + 3)
    assert kinds(outs) == ["units/agv1/state"] and unit_state(outs).order_update_id == 2


@pytest.mark.parametrize(
    "loads",
    [None, [], [{"loadId": "job-1"}], [{"loadId": "job-1", "weight": 2.4}], [{}]],
    ids=["cannot-tell", "says-none", "no-weight", "weighed", "nothing-named"],
)
def test_a_pick_the_vehicle_finished_loads_the_unit_with_the_jobs_mass(
    loads: list[dict[str, Any]] | None,
) -> None:
    # The fleet knows the job: from the pick to the drop the unit carries its mass, whatever the
    # vehicle says of its loads (the schemas' `loads`, and each load's `weight`, are optional).
    c = sent_to_pick()
    done = state(
        agvPosition=at(1, 0),
        actionStates=[pick_state("FINISHED")],
        **({} if loads is None else {"loads": loads}),
    )
    st = unit_state(c.on_vehicle("state", vda(done), T0 + 1))
    assert (st.position, st.job_id, st.load_kg) == ((1, 0), "job-1", 2.5)


@needs_schemas
def test_the_fleet_stop_pauses_the_vehicle_and_the_release_resumes_it() -> None:
    c = core()
    online(c)
    latch = TOPICS.fleet("estop")
    outs = c.on_fleet(latch, encode_estop(EstopSignal(True, "dashboard", "")), T0)
    assert kinds(outs) == ["instantActions", "units/agv1/state"]
    assert [a["actionType"] for a in json.loads(outs[0].payload)["actions"]] == ["startPause"]
    assert (unit_state(outs).status, unit_state(outs).estop) == ("stopped", True)
    # Said once: the stop said again pauses nothing more.
    again = c.on_fleet(latch, encode_estop(EstopSignal(True, "dashboard", "again")), T0)
    assert kinds(again) == ["units/agv1/state"]
    outs = c.on_fleet(latch, encode_estop(EstopSignal(False, "dashboard", "")), T0 + 1)
    assert [a["actionType"] for a in json.loads(outs[0].payload)["actions"]] == ["stopPause"]
    assert unit_state(outs).status == "idle"


def test_the_vehicles_own_emergency_stop_is_a_press_and_a_fatal_error_makes_it_lost() -> None:
    c = core()
    online(c)
    pressed = state(agvPosition=at(0, 0), safetyState={"eStop": "MANUAL", "fieldViolation": False})
    outs = c.on_vehicle("state", vda(pressed), T0)
    assert kinds(outs)[0] == "units/agv1/stop"
    assert outs[0].payload.startswith(b"engaged|agv1|")
    assert kinds(c.on_vehicle("state", vda(pressed), T0 + 1)) == ["units/agv1/state"]  # once
    fatal = state(
        agvPosition=at(0, 0),
        errors=[{"errorType": "motorFault", "errorLevel": "FATAL", "errorReferences": []}],
    )
    outs = c.on_vehicle("state", vda(fatal), T0 + 2)
    assert kinds(outs) == ["units/agv1/state", "units/agv1/connection", "units/agv1/vehicle"]
    assert [e.code for e in unit_state(outs).errors] == ["vehicle_down"]  # its last word
    assert decode(Connection, outs[1].payload).state == "broken"
    assert decode(VehicleCondition, outs[2].payload).errors == ["FATAL motorFault"]  # why
    # Well again: the fleet hears it back.
    outs = c.on_vehicle("state", vda(state(agvPosition=at(0, 0))), T0 + 3)
    assert kinds(outs)[:2] == ["units/agv1/connection", "units/agv1/factsheet"]
    assert decode(VehicleCondition, outs[-1].payload).errors == []


def test_the_vehicles_battery_and_own_errors_are_told_when_they_change() -> None:
    c = core()
    online(c)

    def told(**fields: Any) -> list[VehicleCondition]:
        outs = c.on_vehicle("state", vda(state(agvPosition=at(0, 0), **fields)), T0)
        return [decode(VehicleCondition, o.payload) for o in outs if o.topic.endswith("/vehicle")]

    assert told(batteryState={"batteryCharge": 81.9, "charging": False}) == []  # same percent
    (low,) = told(batteryState={"batteryCharge": 80.9, "charging": True})
    assert (low.battery_pct, low.charging) == (80.9, True)
    warning = {"errorType": "lowBattery", "errorLevel": "WARNING", "errorReferences": []}
    many = [{**warning, "errorDescription": f"cell {n}"} for n in range(10)]
    (worn,) = told(batteryState={"batteryCharge": 130.0, "charging": True}, errors=many)
    assert worn.battery_pct == 100.0  # what a vehicle cannot mean, bounded
    assert worn.errors == [f"WARNING lowBattery: cell {n}" for n in range(8)]  # the first 8


@pytest.mark.parametrize(
    ("payload", "says"),
    [
        (b"{not json", "not JSON"),
        (vda({**state(), "driving": "yes"}), "driving"),
        (vda({k: v for k, v in state().items() if k != "safetyState"}), "safetyState"),
        (vda({**state(), "serialNumber": "sn-8"}), "acme/sn-8"),
        (vda({**state(), "version": "1.1.0"}), "version '1.1.0'"),
        (b"x" * 300_000, "bytes"),
    ],
)
def test_a_bad_vehicle_message_is_reported_and_changes_nothing(payload: bytes, says: str) -> None:
    c = core()
    online(c)
    before = (c.square, c.view)
    outs = c.on_vehicle("state", payload, T0)
    assert kinds(outs) == ["errors"]
    report = decode(ErrorReport, outs[0].payload)
    assert report.topic == VDA + "state" and says in report.reason
    assert (c.square, c.view) == before


def test_a_release_that_cannot_be_driven_is_refused_and_sends_the_vehicle_nothing() -> None:
    c = core()
    online(c)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(2, 0)]), T0)
    assert kinds(outs) == ["errors", "units/agv1/state"]
    st = unit_state(outs)
    assert [e.code for e in st.errors] == ["bad_order"] and st.order_update_id == 0


def test_a_silent_vehicle_is_still_heard_every_few_steps() -> None:
    c = core()
    online(c)
    heard = [kinds(c.tick(T0 + i)) for i in range(1, 7)]
    assert heard == [[], [], ["units/agv1/state"], [], [], ["units/agv1/state"]]


def refusal(kind: str, order_id: str, update: int) -> dict[str, Any]:
    return {
        "errorType": kind,
        "errorLevel": "WARNING",
        "errorReferences": [
            {"referenceKey": "orderId", "referenceValue": order_id},
            {"referenceKey": "orderUpdateId", "referenceValue": str(update)},
        ],
    }


def test_a_refused_update_ends_the_order_once_the_vehicle_stops_and_the_next_is_new() -> None:
    c = core()
    online(c)
    first = c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0)]), T0)
    vda_id = json.loads(first[0].payload)["orderId"]
    update = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, [Cell(1, 0), Cell(2, 0)]), T0)
    assert json.loads(update[0].payload)["orderUpdateId"] == 1
    # It drove what it had, and refused the update: (2, 0) is not released any more.
    stopped = state(
        agvPosition=at(1, 0),
        orderId=vda_id,
        errors=[refusal("orderUpdateError", vda_id, 1)],
    )
    st = unit_state(c.on_vehicle("state", vda(stopped), T0 + 1))
    assert (st.position, st.released) == ((1, 0), [])
    assert [e.code for e in st.errors] == ["order_refused"]
    again = c.on_fleet(TOPICS.unit("order", "agv1"), order(3, [Cell(2, 0)]), T0 + 2)
    sent = json.loads(again[0].payload)
    assert (sent["orderUpdateId"], sent["nodes"][0]["nodeId"]) == (0, "sq-1-0")  # a new order
    assert sent["orderId"] != vda_id


def test_a_vehicle_refusing_every_route_is_lost_to_the_fleet() -> None:
    c = core()
    online(c)
    outs: list[Outbound] = []
    for n in range(1, 4):
        sent = c.on_fleet(TOPICS.unit("order", "agv1"), order(n, [Cell(1, 0)]), T0 + n)
        vda_id = json.loads(sent[0].payload)["orderId"]
        refused = state(agvPosition=at(0, 0), errors=[refusal("noRouteError", vda_id, 0)])
        outs = c.on_vehicle("state", vda(refused), T0 + n)
    # Its last state first: the order it refused has ended, so the fleet keeps none of its
    # squares reserved but the one it stands on (a lost unit's squares are kept as last heard).
    assert kinds(outs) == ["units/agv1/state", "units/agv1/direction", "units/agv1/connection"]
    last = unit_state(outs)
    assert (last.position, last.released) == ((0, 0), [])
    assert [e.code for e in last.errors] == ["order_refused", "vehicle_down"]
    assert outs[1].payload == b"-"  # it goes nowhere
    assert decode(Connection, outs[2].payload).state == "broken"
    # An error about an order gone by changes nothing.
    c2 = core()
    online(c2)
    c2.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0)]), T0)
    old = state(agvPosition=at(0, 0), errors=[refusal("noRouteError", "gf-old-1", 0)])
    st = unit_state(c2.on_vehicle("state", vda(old), T0))
    assert st.released == [(1, 0)] and st.errors == []


def test_a_job_dropped_after_its_action_was_sent_cancels_the_order_and_ends_on_one_square() -> None:
    c = core()
    online(c)
    pick = Action(kind="pick", job_id="job-1", square=Cell(1, 0), mass_kg=1.0)
    sent = c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0)], action=pick), T0)
    first_id = json.loads(sent[0].payload)["orderId"]
    # The job is cancelled: the coordinator's next order has no action. The vehicle's order goes.
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, []), T0 + 1)
    assert kinds(outs) == ["instantActions", "units/agv1/state"]
    cancel = json.loads(outs[0].payload)["actions"][0]
    assert cancel["actionType"] == "cancelOrder"
    st = unit_state(outs)
    assert (st.order_update_id, st.released) == (2, [(1, 0)])  # still reserved meanwhile
    # Until the vehicle says it is done, gridfleet's releases go nowhere.
    held = c.on_fleet(TOPICS.unit("order", "agv1"), order(3, [Cell(1, 0)]), T0 + 1)
    assert kinds(held) == ["units/agv1/state"]
    # It stopped half way: a new order from its square takes it on to the next, still released.
    done = state(
        agvPosition={**at(0, 0), "x": 0.05},
        orderId=first_id,
        actionStates=[
            {
                "actionId": cancel["actionId"],
                "actionType": "cancelOrder",
                "actionStatus": "FINISHED",
            },
            {"actionId": "pick-job-1", "actionType": "pick", "actionStatus": "FAILED"},
        ],
    )
    outs = c.on_vehicle("state", vda(done), T0 + 2)
    assert kinds(outs)[0] == "order"
    again = json.loads(outs[0].payload)
    assert again["orderId"] != first_id and again["orderUpdateId"] == 0
    assert [(n["nodeId"], n["released"]) for n in again["nodes"]] == [
        ("sq-0-0", True),
        ("sq-1-0", True),
    ]
    assert all(a == [] for a in (n["actions"] for n in again["nodes"]))
    st = unit_state(outs)
    assert (st.position, st.released, st.job_id) == ((0, 0), [(1, 0)], None)


def test_no_order_to_cancel_from_a_vehicle_that_stopped_ends_the_order_too() -> None:
    c = core()
    online(c)
    pick = Action(kind="pick", job_id="job-1", square=Cell(1, 0), mass_kg=1.0)
    c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0)], action=pick), T0)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, []), T0 + 1)
    cancel = json.loads(outs[0].payload)["actions"][0]["actionId"]
    # Still driving when it says so: its squares stay released.
    refused = {"actionId": cancel, "actionType": "cancelOrder", "actionStatus": "FAILED"}
    moving = state(
        agvPosition={**at(0, 0), "x": 0.05},
        driving=True,
        nodeStates=[{"nodeId": "sq-1-0", "sequenceId": 2, "released": True}],
        actionStates=[refused],
    )
    assert unit_state(c.on_vehicle("state", vda(moving), T0 + 2)).released == [(1, 0)]
    # Stopped on (1, 0) with nothing left, it answers the next cancel the same: the order ends.
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(3, []), T0 + 3)
    cancel = json.loads(outs[0].payload)["actions"][0]["actionId"]
    refused = {"actionId": cancel, "actionType": "cancelOrder", "actionStatus": "FAILED"}
    stopped = state(agvPosition=at(1, 0), actionStates=[refused])
    st = unit_state(c.on_vehicle("state", vda(stopped), T0 + 4))
    assert (st.position, st.released, st.status) == ((1, 0), [], "idle")


def test_under_the_stop_a_vehicle_that_let_go_of_its_pause_is_paused_again() -> None:
    c = core()
    online(c)
    latch = TOPICS.fleet("estop")
    c.on_fleet(latch, encode_estop(EstopSignal(True, "dashboard", "")), T0)
    paused = c.on_vehicle("state", vda(state(agvPosition=at(0, 0), paused=True)), T0 + 1)
    assert "instantActions" not in kinds(paused)
    # A cancel ended its pause (vda-5050-lib's does): paused again at once.
    outs = c.on_vehicle("state", vda(state(agvPosition=at(0, 0), paused=False)), T0 + 2)
    assert kinds(outs)[0] == "instantActions"
    assert json.loads(outs[0].payload)["actions"][0]["actionType"] == "startPause"


def test_under_the_stop_a_dropped_action_cancels_nothing_until_the_release() -> None:
    c = core()
    online(c)
    pick = Action(kind="pick", job_id="job-1", square=Cell(1, 0), mass_kg=1.0)
    c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0)], action=pick), T0)
    c.on_fleet(TOPICS.fleet("estop"), encode_estop(EstopSignal(True, "dashboard", "")), T0)
    halted = c.on_fleet(TOPICS.unit("order", "agv1"), order(2, []), T0 + 1)
    assert kinds(halted) == ["units/agv1/state"]  # no cancelOrder under the stop
    c.on_fleet(TOPICS.fleet("estop"), encode_estop(EstopSignal(False, "dashboard", "")), T0 + 2)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(3, []), T0 + 3)
    assert json.loads(outs[0].payload)["actions"][0]["actionType"] == "cancelOrder"


@needs_schemas
def test_an_operators_pause_or_out_of_service_pauses_the_vehicle_until_lifted() -> None:
    c = core()
    online(c)
    outs = c.on_control("paused", T0)
    assert kinds(outs) == ["instantActions", "units/agv1/state"]
    assert json.loads(outs[0].payload)["actions"][0]["actionType"] == "startPause"
    assert c.on_control("paused", T0) == []  # said again: nothing
    assert kinds(c.on_control("out_of_service", T0)) == []  # still held: nothing more to say
    # Lifted while the fleet's stop holds: it stays paused until that is released too.
    c.on_fleet(TOPICS.fleet("estop"), encode_estop(EstopSignal(True, "dashboard", "")), T0)
    assert "instantActions" not in kinds(c.on_control(None, T0 + 1))
    outs = c.on_fleet(
        TOPICS.fleet("estop"), encode_estop(EstopSignal(False, "dashboard", "")), T0 + 2
    )
    assert json.loads(outs[0].payload)["actions"][0]["actionType"] == "stopPause"


def test_an_order_or_a_resume_the_vehicle_does_not_show_is_sent_again() -> None:
    # A vehicle takes its messages at QoS 0: one may be lost on the way.
    c = core()
    online(c)
    sent = json.loads(
        c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0)]), T0)[0].payload
    )
    assert [k for k in kinds(c.tick(T0 + 0.5)) if k == "order"] == []  # not yet
    again = [o for o in c.tick(T0 + 1.5) if kinds([o]) == ["order"]]
    assert len(again) == 1
    resent = json.loads(again[0].payload)
    assert (resent["orderId"], resent["orderUpdateId"]) == (sent["orderId"], sent["orderUpdateId"])
    assert resent["headerId"] == sent["headerId"] + 1
    # Its state shows it: no more.
    c.on_vehicle("state", vda(state(agvPosition=at(0, 0), orderId=sent["orderId"])), T0 + 2)
    assert "order" not in kinds(c.tick(T0 + 4))
    # A resume that does not take: sent again after a second.
    latch = TOPICS.fleet("estop")
    c.on_fleet(latch, encode_estop(EstopSignal(True, "dashboard", "")), T0 + 5)
    c.on_fleet(latch, encode_estop(EstopSignal(False, "dashboard", "")), T0 + 6)
    still = state(agvPosition=at(0, 0), orderId=sent["orderId"], paused=True)
    assert "instantActions" not in kinds(c.on_vehicle("state", vda(still), T0 + 6.5))
    outs = c.on_vehicle("state", vda(still), T0 + 7.5)
    assert json.loads(outs[0].payload)["actions"][0]["actionType"] == "stopPause"


def test_after_the_adapter_lost_the_broker_the_unit_is_back_at_once_and_the_vehicle_asked() -> None:
    # A vehicle may say nothing for 30 s: its unit must not wait for that to be heard again.
    c = core()
    online(c)
    c.on_broker_lost()
    outs = c.on_vehicle("connection", connection(), T0 + 1)  # retained: it comes again
    assert kinds(outs)[:4] == [
        "instantActions",
        "instantActions",  # paused until an order on this connection (the test below)
        "units/agv1/connection",
        "units/agv1/factsheet",
    ]
    assert json.loads(outs[0].payload)["actions"][0]["actionType"] == "stateRequest"
    assert json.loads(outs[1].payload)["actions"][0]["actionType"] == "startPause"
    assert decode(Connection, outs[2].payload).state == "online"


def actions_in(outs: list[Outbound]) -> list[str]:
    """The instant actions among `outs`, by type."""
    return [
        a["actionType"]
        for o in outs
        if kinds([o]) == ["instantActions"]
        for a in json.loads(o.payload)["actions"]
    ]


def test_after_the_broker_was_lost_the_vehicle_drives_its_base_only_on_an_order_heard_since() -> (
    None
):
    # protocol.md §5.1, "Across a broker's death": the broker failed over to may never have
    # seen the stop engaged. The vehicle drives on only once the coordinator speaks again.
    c = core()
    online(c)
    c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0), Cell(2, 0)]), T0)
    c.on_broker_lost()
    back = c.on_vehicle("connection", connection(), T0 + 1)
    assert "startPause" in actions_in(back)
    driving = state(agvPosition=at(0, 0), orderId=c.orders.order_id)
    c.on_vehicle("state", vda({**driving, "paused": True}), T0 + 1.1)
    # No stop retained on this broker: still paused, as a halt order does not take back a base.
    assert actions_in(c.on_fleet(TOPICS.fleet("estop"), b"released|op|x", T0 + 1.2)) == []
    assert "stopPause" not in actions_in(
        c.on_fleet(TOPICS.unit("order", "agv1"), order(2, []), T0 + 1.3)
    )
    # An order that releases squares (the base ahead): it drives on.
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(3, [Cell(1, 0), Cell(2, 0)]), T0 + 1.4)
    assert actions_in(outs)[-1:] == ["stopPause"]
    assert not c.unheard


def test_after_the_broker_was_lost_a_vehicle_with_no_base_left_resumes_on_a_halt_order() -> None:
    c = core()
    online(c)
    c.on_broker_lost()
    c.on_vehicle("connection", connection(), T0 + 1)
    c.on_vehicle("state", vda(state(agvPosition=at(0, 0), paused=True)), T0 + 1.1)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(1, []), T0 + 1.2)
    assert actions_in(outs) == ["stopPause"] and not c.unheard


def test_states_the_adapter_fails_on_show_on_the_unit_then_break_it_until_one_is_read(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from gridfleet.robots.vda5050.core import UNREADABLE_STATES

    c = core()
    online(c)
    good = vda(state(agvPosition=at(0, 0)))

    def broken(*_: object) -> list[Outbound]:
        raise TypeError("a bug")

    monkeypatch.setattr(c, "_on_state", broken)
    for _ in range(UNREADABLE_STATES - 1):  # shown at once, the unit still usable
        with pytest.raises(TypeError):
            c.on_vehicle("state", good, T0 + 1)
        outs = c.on_failure("state", "TypeError")
        assert kinds(outs) == ["units/agv1/state"]
        (error,) = unit_state(outs).errors
        assert error.code == "unreadable_state" and f"{VDA}state" in error.message
        assert "TypeError" in error.message and "a bug" not in error.message
    with pytest.raises(TypeError):
        c.on_vehicle("state", good, T0 + 2)
    broken_outs = c.on_failure("state", "TypeError")  # the last state first, then broken
    assert kinds(broken_outs) == ["units/agv1/state", "units/agv1/connection"]
    assert decode(Connection, broken_outs[1].payload).state == "broken"
    assert c.tick(T0 + 3) == [] and c.on_failure("state", "TypeError") == []  # no unit: silent
    monkeypatch.undo()
    back = c.on_vehicle("state", good, T0 + 4)  # read again: the unit is back
    assert kinds(back)[:2] == ["units/agv1/connection", "units/agv1/factsheet"]
    assert decode(Connection, back[0].payload).state == "online" and c.unreadable == 0
    assert unit_state(c.on_vehicle("state", good, T0 + 5) or c.state()).errors == []
    # Its connection or factsheet failing is shown too, and breaks nothing.
    outs = c.on_failure("factsheet", "KeyError")
    assert [e.code for e in unit_state(outs).errors] == ["unreadable_message"]


def test_a_unit_whose_state_cannot_even_be_made_is_broken_at_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The fault is in making the unit's state (its view was already taken in): no state can say
    # so, so the unit leaves the fleet (broken) rather than going silent until it is found lost.
    c = core()
    online(c)

    def broken(*_: object) -> list[Outbound]:
        raise TypeError("a bug")

    monkeypatch.setattr(c, "state", broken)
    outs = c.on_failure("state", "TypeError")
    assert kinds(outs) == ["units/agv1/connection"]
    assert decode(Connection, outs[0].payload).state == "broken"


@pytest.mark.parametrize("restarted", [True, False], ids=["restarted", "link-lost"])
def test_a_vehicle_back_on_line_is_announced_from_its_next_state_and_keeps_only_its_own_order(
    restarted: bool,
) -> None:
    # As found: a vehicle killed on its way and restarted elsewhere was announced from its last
    # state before (its old square, its old order's squares released); the coordinator took the
    # stale square, refused every real one, and kept the old route reserved for good.
    c = core()
    online(c)
    outs = c.on_fleet(TOPICS.unit("order", "agv1"), order(1, [Cell(1, 0), Cell(2, 0)]), T0)
    sent = json.loads(outs[0].payload)
    moving = state(agvPosition={**at(0, 0), "x": 0.05}, driving=True, orderId=sent["orderId"])
    assert unit_state(c.on_vehicle("state", vda(moving), T0 + 1)).released == [(1, 0), (2, 0)]
    assert kinds(c.on_vehicle("connection", connection("CONNECTIONBROKEN"), T0 + 2)) == [
        "units/agv1/connection"
    ]
    back = c.on_vehicle("connection", connection(), T0 + 30)
    assert "units/agv1/state" not in kinds(back) and "stateRequest" in back[0].payload.decode()
    if restarted:  # elsewhere, with no order: nothing of the old one is its any more
        fresh = state(agvPosition=at(3, 2), orderId="", lastNodeId="", lastNodeSequenceId=0)
        st = unit_state(c.on_vehicle("state", vda(fresh), T0 + 31))
        assert (st.position, st.released) == ((3, 2), [])
    else:  # its link came back; it still has its order, and its squares stay released
        st = unit_state(c.on_vehicle("state", vda(moving), T0 + 31))
        assert (st.position, st.released) == ((0, 0), [(1, 0), (2, 0)])


def test_a_vehicle_doing_its_pick_says_so_not_that_it_has_not_driven_on() -> None:
    # As found: every VDA unit standing at its pickup read "the vehicle has not reported driving
    # on" while it was doing its pick, as if stuck.
    c = sent_to_pick()
    running = state(agvPosition=at(1, 0), actionStates=[pick_state("RUNNING")])
    st = unit_state(c.on_vehicle("state", vda(running), T0 + 1))
    assert (st.status, st.wait_reason) == ("waiting", "the vehicle is doing its pick of job-1")
