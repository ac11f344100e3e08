"""vda-5050-lib 1.4.0's virtual AGV (VDA 5050 2.0.0, in Node.js) charging on gridfleet's orders,
through the adapter, with the orders a coordinator would send published by the test itself.

What its VirtualAgvAdapter does (its source, adapter/virtual-agv-adapter.js): it charges
wherever it stands (no charging station), but refuses `startCharging` while an order is under
way ("charging denied as order is in progress") and any order while it charges ("order is not
executable while charging", an `orderError`); `startCharging` and `stopCharging` each take a
second (RUNNING, then FINISHED); it gains `100 / 3600 / fullBatteryChargeTime` % a second and
loses `100 / batteryMaxReach` % a metre driven, nothing standing; at 100 % it stops charging by
itself. Every VDA 5050 message of the runs is held to the official 2.0.0 schemas.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from test_vda5050_lib import LIB_ACTIONS, LibAgvs, VdaWire

from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import EnergyModel, HeaderStamper, Order, Topics, UnitState, decode, encode
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.shell import AdapterShell
from gridfleet.robots.vda5050.wire import Vehicle
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.probe import MqttProbe
from support.vda import official_if_here
from support.wait import wait_for

pytestmark = [pytest.mark.slow, pytest.mark.amqtt_only]  # as test_vda5050_lib.py's

FRAME = Frame("hall")
GRID = GridMap.from_rows(["....", "....", "...."], name="bay")
CHARGER = Cell(1, 1)
# Its battery as the unit's energy model says it: 0.5 % a square (0.1 m), 2 % a second charging.
SQUARE_PCT, CHARGE_PCT_S = 0.5, 2.0
LIB_BATTERY = {
    "batteryMaxReach": FRAME.square_m * 100 / SQUARE_PCT,  # metres on a full charge
    "fullBatteryChargeTime": 100 / 3600 / CHARGE_PCT_S,  # hours from 0 to 100 %
}
ENERGY = EnergyModel(move_pct=SQUARE_PCT, idle_pct_per_s=0.0, charge_pct_per_s=CHARGE_PCT_S)


@dataclass
class Charger:
    """One vda-5050-lib AGV as unit agv1 at CHARGER, and the orders the test sends it."""

    probe: MqttProbe
    topics: Topics
    wire: VdaWire
    serial: str
    stamp: HeaderStamper
    update: int = 0

    def order(self, released: list[Cell], charge: Cell | None) -> None:
        """The coordinator's next update of its order: squares to drive, a charger or none."""
        self.update += 1
        message = Order(
            header=self.stamp("order"),
            order_id="c-agv1-1",
            update_id=self.update,
            released=released,
            charge=charge,
        )
        self.probe.publish(self.topics.unit("order", "agv1"), encode(message))

    def states(self) -> list[UnitState]:
        """Every state of the unit so far."""
        return [decode(UnitState, m.payload) for m in self.probe.received(self._state)]

    @property
    def _state(self) -> str:
        return self.topics.unit("state", "agv1")

    def last(self) -> UnitState | None:
        found = self.states()
        return found[-1] if found else None

    def vehicle(self) -> list[dict[str, Any]]:
        """Every state the AGV published."""
        topic = f"uagv/v2/vdalib/{self.serial}/state"
        with self.wire.lock:
            return [json.loads(p) for t, p in self.wire.seen if t == topic]

    def sent(self, kind: str) -> list[dict[str, Any]]:
        """Every instant action of `kind` the adapter sent the AGV."""
        topic = f"uagv/v2/vdalib/{self.serial}/instantActions"
        with self.wire.lock:
            messages = [json.loads(p) for t, p in self.wire.seen if t == topic]
        return [a for m in messages for a in m["actions"] if a["actionType"] == kind]


@pytest.fixture
def battery_pct() -> float:
    """The AGV's charge at the start (a test may parametrize it)."""
    return 30.0


@pytest.fixture
def charger(
    battery_pct: float,
    broker: BrokerThread,
    root: str,
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
) -> Iterator[Charger]:
    probe = probe_factory()
    wire = VdaWire(probe)
    probe.subscribe(topics.unit("state", "agv1"), qos=0)
    serial = f"{root.replace('/', '-')}-c"
    agvs = LibAgvs(
        broker.url,
        {serial: CHARGER},
        0.5,
        {serial: {**LIB_BATTERY, "initialBatteryCharge": battery_pct}},
    )
    config = VehicleConfig(
        Vehicle("agv1", "vdalib", serial, "2.0.0"),
        FRAME,
        5.0,
        0.0,
        True,
        LIB_ACTIONS,
        energy=ENERGY,
    )
    adapter = ServiceThread(
        lambda: AdapterShell(
            [config], GRID, broker.url, topics, step_s=0.2, schemas=official_if_here()
        ),
        "vda5050",
    ).start()
    try:
        wait_for(lambda: probe.received(topics.unit("state", "agv1")), 30, what="agv1 on line")
        yield Charger(probe, topics, wire, serial, HeaderStamper("coordinator"))
    finally:
        adapter.stop()
        agvs.stop()
        assert wire.problems() == []


def charging(c: Charger) -> bool:
    last = c.last()
    return last is not None and last.charging


@pytest.mark.timeout(120)
def test_a_vda_5050_lib_agv_charges_on_gridfleets_order_and_leaves_when_sent_on(
    charger: Charger,
) -> None:
    c = charger
    c.order([], CHARGER)
    wait_for(lambda: charging(c), 20, what="agv1 charging", context=c.last)
    assert c.last() is not None and c.last().battery_pct == pytest.approx(30.0, abs=3)  # type: ignore[union-attr]
    wait_for(
        lambda: (getattr(c.last(), "battery_pct", 0) or 0) >= 36.0,
        20,
        what="its charge rising (2 % a second)",
        context=c.last,
    )
    # Heartbeats name the charger again: nothing more for the AGV.
    c.order([], CHARGER)
    # Sent on to (2, 1): the charge stops first, and that order goes nowhere.
    c.order([Cell(2, 1)], None)
    wait_for(lambda: not charging(c), 20, what="agv1 done charging", context=c.last)
    assert [a["blockingType"] for a in c.sent("startCharging")] == ["HARD"]
    assert [a["blockingType"] for a in c.sent("stopCharging")] == ["HARD"]
    assert c.last().position == (1, 1)  # type: ignore[union-attr]
    # The coordinator's next order goes to the AGV, which drives it.
    c.order([Cell(2, 1)], None)
    wait_for(
        lambda: getattr(c.last(), "position", None) == (2, 1),
        20,
        what="agv1 at (2, 1)",
        context=lambda: (c.last(), c.vehicle()[-1:]),
    )
    refused = [
        e
        for s in c.vehicle()
        for e in s["errors"]
        if e["errorType"] in ("orderError", "instantActionError")
    ]
    assert refused == []  # it was never sent what it refuses
    assert len(c.sent("startCharging")) == 1


@pytest.mark.parametrize("battery_pct", [97.0], ids=["nearly-full"])
@pytest.mark.timeout(120)
def test_a_vda_5050_lib_agv_that_stops_itself_when_full_is_not_started_again(
    charger: Charger,
) -> None:
    c = charger
    c.order([], CHARGER)
    wait_for(
        lambda: any(s["batteryState"]["batteryCharge"] >= 100 for s in c.vehicle()),
        30,
        what="the AGV full",
        context=lambda: c.vehicle()[-1:],
    )
    wait_for(
        lambda: not c.vehicle()[-1]["batteryState"]["charging"],
        10,
        what="the AGV stopped charging itself",
    )
    for _ in range(3):  # the coordinator's heartbeats go on naming the charger
        c.order([], CHARGER)
    wait_for(
        lambda: getattr(c.last(), "order_update_id", 0) == c.update, 10, what="all acknowledged"
    )
    # Full, on its charger: still `charging` to the fleet, and started once only.
    last = c.last()
    assert last is not None and (last.battery_pct, last.charging) == (100.0, True)
    assert len(c.sent("startCharging")) == 1 and c.sent("stopCharging") == []
