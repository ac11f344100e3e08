"""Our own VDA 5050 vehicle (robots/vda5050/virtual.py), pure: it drives what it is released,
stitches updates, pauses, cancels, and refuses what the specification lets a vehicle refuse;
everything it says is valid against the official schema of its version."""

from __future__ import annotations

from typing import Any

import pytest

from gridfleet.grid import Cell
from gridfleet.protocol import Action
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.instant import instant_action
from gridfleet.robots.vda5050.orders import OrderStitcher
from gridfleet.robots.vda5050.virtual import Message, Quirk, VirtualSpec, VirtualVehicle
from gridfleet.robots.vda5050.wire import Headers, Vehicle, Version

from support.vda import official_if_here

FRAME = Frame("hall")
T0 = 1_795_000_000.0


def pair(
    version: Version = "2.1.0", quirks: frozenset[Quirk] = frozenset()
) -> tuple[VirtualVehicle, OrderStitcher, Headers]:
    vehicle = Vehicle("agv1", "acme", "sn-7", version)
    spec = VirtualSpec((0.0, 0.0), "hall", speed=1.0, action_s=0.2, quirks=quirks)
    master = Headers(vehicle)
    return VirtualVehicle(vehicle, spec), OrderStitcher(master, FRAME, "gf-t"), master


def valid(version: Version, messages: list[Message]) -> list[Message]:
    schemas = official_if_here()
    for name, message in messages if schemas is not None else []:
        assert schemas.problems(version, name, message) == [], (name, message)
    return messages


def run(v: VirtualVehicle, seconds: float, version: Version = "2.1.0") -> list[dict[str, Any]]:
    """Drive for `seconds` (0.05 s ticks); the states it published."""
    states, now = [], T0
    for _ in range(int(seconds / 0.05)):
        now += 0.05
        states += [m for n, m in valid(version, v.advance(now, 0.05)) if n == "state"]
    return states


@pytest.mark.parametrize("version", ["2.0.0", "2.1.0"])
def test_it_drives_its_base_and_not_its_horizon_and_picks_where_told(version: Version) -> None:
    v, s, _ = pair(version)
    pick = Action(kind="pick", job_id="job-1", square=Cell(2, 0), mass_kg=1.5)
    order = s.order(Cell(0, 0), [Cell(1, 0)], [Cell(2, 0)], pick, T0)
    assert order is not None
    valid(version, v.on_order(order, T0))
    run(v, 1.0, version)
    assert (round(v.x, 3), v.last_node, v.driving) == (0.1, ("sq-1-0", 2), False)  # not the horizon
    update = s.order(Cell(1, 0), [Cell(2, 0)], [], pick, T0 + 1)
    assert update is not None
    valid(version, v.on_order(update, T0 + 1))
    states = run(v, 1.0, version)
    assert v.last_node == ("sq-2-0", 4)
    assert states[-1]["loads"] == [{"loadId": "job-1", "weight": 1.5}]
    assert {a["actionId"]: a["actionStatus"] for a in states[-1]["actionStates"]} == {
        "pick-job-1": "FINISHED"
    }


def test_a_pause_stops_it_at_once_and_the_resume_drives_on() -> None:
    v, s, master = pair()
    order = s.order(Cell(0, 0), [Cell(1, 0), Cell(2, 0)], [], None, T0)
    assert order is not None
    v.on_order(order, T0)
    run(v, 0.05)
    paused = valid(
        "2.1.0", v.on_instant_actions(instant_action(master, "startPause", "p1", T0), T0)
    )
    assert paused[-1][1]["paused"] is True and not paused[-1][1]["driving"]
    where = (v.x, v.y)
    run(v, 0.5)
    assert (v.x, v.y) == where
    v.on_instant_actions(instant_action(master, "stopPause", "p2", T0), T0)
    run(v, 1.0)
    assert v.last_node == ("sq-2-0", 4)


def test_an_update_that_does_not_stitch_is_refused_and_changes_nothing() -> None:
    v, s, _ = pair()
    order = s.order(Cell(0, 0), [Cell(1, 0)], [], None, T0)
    assert order is not None
    v.on_order(order, T0)
    # Its base ends at (1, 0): an update must start there, not where the order began.
    bad = {**order, "orderUpdateId": 1}
    ((_, state),) = valid("2.1.0", v.on_order(bad, T0))
    assert [e["errorType"] for e in state["errors"]] == ["orderUpdateError"]
    assert state["orderUpdateId"] == 0


@pytest.mark.parametrize(
    ("quirk", "error"),
    [("reject_updates", "orderUpdateError"), ("no_route", "noRouteError")],
)
def test_a_vehicle_may_refuse_orders_as_the_specification_allows(quirk: Quirk, error: str) -> None:
    v, s, _ = pair(quirks=frozenset({quirk}))
    first = s.order(Cell(0, 0), [Cell(1, 0)], [], None, T0)
    assert first is not None
    out = v.on_order(first, T0)
    if quirk == "reject_updates":
        update = s.order(Cell(0, 0), [Cell(1, 0), Cell(2, 0)], [], None, T0)
        assert update is not None
        out = v.on_order(update, T0)
    ((_, state),) = valid("2.1.0", out)
    assert error in [e["errorType"] for e in state["errors"]]


def test_cancel_drops_the_order_and_with_nothing_to_cancel_says_so() -> None:
    v, s, master = pair()
    out = valid("2.1.0", v.on_instant_actions(instant_action(master, "cancelOrder", "c1", T0), T0))
    state = out[-1][1]
    assert [e["errorType"] for e in state["errors"]] == ["noOrderToCancel"]
    order = s.order(Cell(0, 0), [Cell(1, 0), Cell(2, 0)], [], None, T0)
    assert order is not None
    v.on_order(order, T0)
    run(v, 0.05)
    out = v.on_instant_actions(instant_action(master, "cancelOrder", "c2", T0), T0)
    state = valid("2.1.0", out)[-1][1]
    assert state["nodeStates"] == [] and not state["driving"]
    assert {a["actionId"]: a["actionStatus"] for a in state["actionStates"]}["c2"] == "FINISHED"


def test_it_reports_on_events_and_otherwise_only_every_state_interval() -> None:
    v, _, _ = pair()
    v.spec.state_every_s = 30.0
    v.state(T0)
    quiet = [m for m in (v.advance(T0 + t, 1.0) for t in range(1, 30)) if m]
    assert quiet == []
    assert [n for n, _ in v.advance(T0 + 30, 1.0)] == ["state"]


def battery(**spec: Any) -> tuple[VirtualVehicle, OrderStitcher, Headers]:
    """A 2.1.0 vehicle at (0, 0) with a battery that drains and charges."""
    vehicle = Vehicle("agv1", "acme", "sn-7", "2.1.0")
    master = Headers(vehicle)
    fields = {"speed": 1.0, "node_pct": 2.0, "idle_pct_per_s": 1.0, "charge_pct_per_s": 10.0}
    v = VirtualVehicle(vehicle, VirtualSpec((0.0, 0.0), "hall", **{**fields, **spec}))
    return v, OrderStitcher(master, FRAME, "gf-t"), master


def charge(v: VirtualVehicle, master: Headers, kind: str, action_id: str) -> dict[str, Any]:
    """The state after instant action `kind`; the action's state in it."""
    message = instant_action(master, kind, action_id, T0)  # type: ignore[arg-type]
    state = valid("2.1.0", v.on_instant_actions(message, T0))[-1][1]
    return {a["actionId"]: a for a in state["actionStates"]}[action_id]


def test_its_battery_drains_per_node_and_standing_and_rises_while_it_charges() -> None:
    v, s, master = battery(battery_pct=50.0)
    order = s.order(Cell(0, 0), [Cell(1, 0), Cell(2, 0)], [], None, T0)
    assert order is not None
    v.on_order(order, T0)
    run(v, 0.5)  # 0.2 m at 1 m/s: both nodes, 2 % each, then standing
    assert v.last_node == ("sq-2-0", 4)
    assert 45.0 < v.battery < 46.0  # 4 % for the nodes, a little for standing
    assert charge(v, master, "startCharging", "sc1")["actionStatus"] == "FINISHED"
    states = run(v, 1.0)
    assert states[-1]["batteryState"]["charging"] is True
    assert 55.0 < states[-1]["batteryState"]["batteryCharge"] < 56.5  # 10 % a second, no drain
    run(v, 10.0)
    assert v.battery == 100.0 and v.charging  # it charges on, at full, until told to stop
    assert charge(v, master, "stopCharging", "sc2")["actionStatus"] == "FINISHED"
    assert not v.charging
    assert charge(v, master, "stopCharging", "sc3")["actionStatus"] == "FAILED"  # nothing to stop


def test_charging_it_takes_no_order_and_at_zero_it_drives_no_further() -> None:
    v, s, master = battery(battery_pct=3.0, idle_pct_per_s=0.0)
    charge(v, master, "startCharging", "sc1")
    order = s.order(Cell(0, 0), [Cell(1, 0), Cell(2, 0), Cell(3, 0)], [], None, T0)
    assert order is not None
    ((_, refused),) = valid("2.1.0", v.on_order(order, T0))
    assert [e["errorType"] for e in refused["errors"]] == ["orderError"]  # while charging
    assert refused["orderId"] == ""
    charge(v, master, "stopCharging", "sc2")
    v.on_order(order, T0)
    states = run(v, 1.0)
    # 2 % a node: (1, 0) leaves it 1 %, (2, 0) empty; there it stands, saying why.
    assert (v.last_node, v.battery, v.driving) == (("sq-2-0", 4), 0.0, False)
    assert [e["errorType"] for e in states[-1]["errors"]] == ["batteryLowError"]
    assert charge(v, master, "startCharging", "sc3")["actionStatus"] == "FAILED"  # order under way


def test_with_charging_stations_it_charges_only_on_one() -> None:
    v, _, master = battery(chargers=((0.3, 0.0),))
    failed = charge(v, master, "startCharging", "sc1")
    assert (failed["actionStatus"], failed["resultDescription"]) == (
        "FAILED",
        "not aligned to charger",
    )
    (error,) = v.errors
    assert error["errorType"] == "chargingError"
    assert error["errorReferences"] == [{"referenceKey": "actionId", "referenceValue": "sc1"}]
    v.x = 0.3
    assert charge(v, master, "startCharging", "sc2")["actionStatus"] == "FINISHED"
    assert v.charging and v.errors == []
