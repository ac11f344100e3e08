"""A clean stop of the coordinator: every unit it was ordering gets a halt order, then it says offline."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from gridfleet.grid import Cell
from gridfleet.protocol import CoordinatorStatus, Order, Topics, decode
from gridfleet.system.threads import ServiceThread

from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.wait import wait_for

RunSystem = Callable[..., tuple[ServiceThread, ServiceThread]]
UNITS = ["unit1", "unit2", "unit3", "unit4"]


def test_a_clean_stop_holds_every_unit_before_saying_offline(
    run_system: RunSystem, playfield: Path, probe_factory: Callable[..., MqttProbe], topics: Topics
) -> None:
    probe = probe_factory()
    probe.subscribe(topics.all_units("order"))
    probe.subscribe(topics.fleet("coordinator"))
    # A slow step, so the unit is still on its way (squares released) when the stop comes.
    coordinator, _ = run_system(playfield, step_s=0.3)

    def orders(unit: str) -> list[Order]:
        return [decode(Order, m.payload) for m in probe.received(topics.unit("order", unit))]

    wait_for(lambda: all(orders(u) for u in UNITS), what="the coordinator ordering every unit")
    assert OperatorPeer(probe, topics).set_goal("unit1", Cell(9, 9)).accepted

    wait_for(lambda: any(o.released for o in orders("unit1")), what="unit1 on its way")
    coordinator.stop()

    def said_offline() -> float | None:
        for m in probe.received(topics.fleet("coordinator")):
            if decode(CoordinatorStatus, m.payload).state == "offline":
                return m.at
        return None

    bye = wait_for(said_offline, what="the coordinator's offline")
    for unit in UNITS:
        seen = probe.received(topics.unit("order", unit))
        assert seen and all(m.at <= bye for m in seen), f"{unit}: an order came after offline"
        assert decode(Order, seen[-1].payload).released == [], f"{unit}: not held at the end"
