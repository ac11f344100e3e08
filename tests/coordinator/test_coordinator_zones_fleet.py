"""Closed zones with the real coordinator and the real simulated units on the playfield, over a
real broker: a zone closed mid-run keeps every unit that was outside it out of it, the unit
inside leaves, a job into it waits and is done once it opens, and a coordinator restart keeps it.

What the units publish is the evidence: every unit's states (each move makes one) and the
orders the coordinator sent them, tapped on the broker.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime
from pathlib import Path

import pytest

from gridfleet.grid import Cell
from gridfleet.protocol import Order, Topics, ZonesView, decode
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, coordinator_thread, world_of

from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.wait import wait_for

RunSystem = Callable[..., tuple[ServiceThread, ServiceThread]]
STEP = 0.05
UNITS = ("unit1", "unit2", "unit3", "unit4")
FIRST, LAST = Cell(3, 3), Cell(6, 6)  # the middle of the playfield: walls and a hidden obstacle too
ZONE = {Cell(x, y) for x in range(FIRST.x, LAST.x + 1) for y in range(FIRST.y, LAST.y + 1)}


@pytest.fixture
def operator(probe_factory: Callable[..., MqttProbe], topics: Topics) -> OperatorPeer:
    """An operator under this test's root, tapping the orders and the zones view too."""
    peer = OperatorPeer(probe_factory(), topics, "tester")
    peer.probe.subscribe(topics.all_units("order"), qos=1)
    peer.probe.subscribe(topics.fleet("zones"), qos=1)
    return peer


def start(run_system: RunSystem, playfield: Path) -> tuple[ServiceThread, ServiceThread]:
    """The playfield's coordinator and units; once the coordinator knows all four."""
    coordinator, fleet = run_system(playfield, step_s=STEP)
    world = coordinator.service.world

    def known() -> bool:
        return len(world.capacities()) == 4 and all(
            u.state is not None for u in world.units.values()
        )

    wait_for(lambda: coordinator.call(known), timeout=10, what="the coordinator knows the fleet")
    return coordinator, fleet


def orders(operator: OperatorPeer, unit: str) -> list[Order]:
    """Every order `unit` was sent, as tapped."""
    return [
        decode(Order, m.payload)
        for m in operator.probe.received(operator.topics.unit("order", unit))
    ]


def zones_views(operator: OperatorPeer) -> list[ZonesView]:
    return [
        decode(ZonesView, m.payload)
        for m in operator.probe.received(operator.topics.fleet("zones"))
        if m.payload
    ]


def stayed_out(operator: OperatorPeer, unit: str, closed_at: datetime, until: datetime) -> bool:
    """Check `unit` against the zone from its close (the coordinator's reply at `closed_at`) to
    `until`: once one of its states shows it outside, holding no square of it, and past every
    order sent before the close (nothing given before is still to come), no later state shows
    it inside or holding a square of it. Whether it got out (True) at all."""
    sent = orders(operator, unit)
    place = {(o.order_id, o.update_id): i for i, o in enumerate(sent)}
    before = [i for i, o in enumerate(sent) if o.header.timestamp <= closed_at]
    last_before = before[-1] if before else -1
    out = False
    for st in operator.states(unit):
        if not closed_at < st.header.timestamp < until:
            continue
        inside = st.position in ZONE or bool(ZONE & set(st.released))
        if out:
            assert not inside, f"{unit} back in the closed zone: {st}"
            continue
        taken = place.get((st.order_id or "", st.order_update_id), -1)
        out = not inside and taken >= last_before
    return out


@pytest.mark.slow
@pytest.mark.timeout(150)
def test_a_zone_closed_mid_run_keeps_units_out_and_its_job_waits_until_it_opens(
    run_system: RunSystem, operator: OperatorPeer, playfield: Path
) -> None:
    _, fleet = start(run_system, playfield)
    world = world_of(fleet)
    # unit4 alone carries 15 kg: two jobs keep it busy before the one into the zone.
    assert operator.submit_job(Cell(9, 8), Cell(9, 1), 15.0, job_id="first", priority=9).accepted
    assert operator.submit_job(Cell(9, 1), Cell(8, 9), 15.0, job_id="second", priority=5).accepted
    assert operator.submit_job(Cell(0, 2), Cell(4, 4), 15.0, job_id="in").accepted
    # Jobs across the middle for the others.
    crossing = {"c1": (Cell(0, 4), Cell(9, 6), 1.5), "c2": (Cell(9, 3), Cell(0, 6), 4.0)}
    crossing["c3"] = (Cell(2, 9), Cell(7, 0), 8.0)
    for job_id, (pickup, dropoff, mass) in crossing.items():
        assert operator.submit_job(pickup, dropoff, mass, job_id=job_id).accepted

    def someone_inside() -> str | None:
        for unit in UNITS:
            st = operator.last_state(unit)
            if st is not None and st.position in ZONE:
                return unit
        return None

    inside = wait_for(someone_inside, timeout=20, what="a unit crossing the middle")
    reply = operator.close_zone("aisle-4", LAST, FIRST, "cleaning")
    assert reply.accepted and reply.code is None, reply
    closed_at = reply.header.timestamp

    def waits() -> bool:
        job = operator.listed_jobs().get("in")
        return job is not None and job.wait == "zone_closed"

    wait_for(waits, timeout=10, what="the job into the zone waiting")
    assert operator.listed_jobs()["in"].wait_reason == "zone aisle-4 closed: cleaning"
    refused = operator.submit_job(Cell(5, 3), Cell(0, 0), 1.0, job_id="refused")
    assert (refused.accepted, refused.code, refused.reason) == (
        False,
        "zone_closed",
        "pickup [5, 3] is in zone aisle-4, closed: cleaning",
    )
    ids = ["first", "second", *crossing]
    wait_for(lambda: operator.all_final(ids), timeout=60, what="the jobs round the zone")
    listed = operator.listed_jobs()
    assert {listed[i].state for i in ids} == {"done"}
    assert listed["in"].state in ("queued", "assigned", "to_pickup", "loaded", "to_dropoff")
    wait_for(lambda: someone_inside() is None, timeout=10, what="the unit inside gone out")
    view = zones_views(operator)[-1]
    assert [(z.name, z.first, z.last, z.closed_by) for z in view.zones] == [
        ("aisle-4", FIRST, LAST, "tester")
    ]
    opened = operator.open_zone("aisle-4")
    assert opened.accepted, opened
    for unit in UNITS:
        assert stayed_out(operator, unit, closed_at, opened.header.timestamp), unit
    states = operator.states(inside)
    assert any(s.position in ZONE and s.header.timestamp <= closed_at for s in states)
    wait_for(lambda: operator.all_final(["in"]), timeout=60, what="the job into the zone")
    assert operator.listed_jobs()["in"].state == "done"
    assert zones_views(operator)[-1].zones == []
    assert world.collisions == 0, world.log


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_coordinator_restart_keeps_the_zones_closed(
    run_system: RunSystem,
    operator: OperatorPeer,
    playfield: Path,
    broker: BrokerThread,
    root: str,
    tmp_path: Path,
) -> None:
    coordinator, fleet = start(run_system, playfield)
    assert operator.close_zone("aisle-4", FIRST, LAST, "cleaning").accepted
    coordinator.stop()
    views = len(zones_views(operator))  # the restarted coordinator's goes out when it connects
    scenario = load_scenario(playfield)
    with coordinator_thread(
        scenario, broker.url, root=root, step_s=STEP, db_path=tmp_path / "jobs.db"
    ):
        wait_for(lambda: len(zones_views(operator)) > views, timeout=10, what="a zones view")
        assert [z.name for z in zones_views(operator)[-1].zones] == ["aisle-4"]
        # Still closed: a job into it is refused, and one across it goes round it.
        refused = operator.submit_job(Cell(4, 4), Cell(0, 0), 1.0, job_id="into")
        assert refused.code == "zone_closed", refused
        assert operator.submit_job(Cell(0, 4), Cell(9, 6), 1.5, job_id="across").accepted
        wait_for(lambda: operator.all_final(["across"]), timeout=40, what="the job across")
        assert operator.listed_jobs()["across"].state == "done"
        carrier = operator.listed_jobs()["across"].unit
        assert carrier is not None
        after = [s for s in operator.states(carrier) if s.job_id == "across"]
        assert after and not any(s.position in ZONE for s in after)
    assert world_of(fleet).collisions == 0
