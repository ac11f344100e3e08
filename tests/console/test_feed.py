"""The demo feed's random jobs: feasible, and sized to the fleet's mix of units."""

from __future__ import annotations

import random
from collections.abc import Callable

import pytest

from gridfleet.console.feed import demo_queue, random_job
from gridfleet.console.operator import operator_session
from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE, DistanceFieldCache
from gridfleet.protocol import FleetMap, Topics, encode
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread

from support.effects import header
from support.fleet_peer import CoordinatorPeer
from support.paths import MAPS
from support.probe import MqttProbe
from support.wait import async_wait_for

WAREHOUSE = MAPS / "warehouse.toml"


def test_demo_jobs_fit_the_fleets_mix_and_every_one_can_be_done() -> None:
    # The hour-long warehouse demo: masses up to the biggest capacity went mostly to the four
    # big units while eight small ones idled.
    scenario = load_scenario(WAREHOUSE)
    fields = DistanceFieldCache(scenario.grid)
    capacities = sorted(u.capacity for u in scenario.units)
    jobs = [random_job(scenario, random.Random(seed), fields) for seed in range(400)]
    home = scenario.units[0].start
    for pickup, dropoff, mass in jobs:
        assert 0 < mass <= capacities[-1] and pickup != dropoff
        assert UNREACHABLE not in (fields.distance(home, pickup), fields.distance(home, dropoff))
    small = capacities[0]
    share_small_units = sum(c <= small for c in capacities) / len(capacities)
    share_small_jobs = sum(mass <= small for _, _, mass in jobs) / len(jobs)
    # About as many jobs fit the smallest units as there are such units (a fifth of the jobs
    # before, a uniform draw up to the biggest capacity, for a third of the units).
    assert share_small_jobs >= 0.8 * share_small_units, (share_small_jobs, share_small_units)


def test_demo_jobs_avoid_the_obstacles_units_found() -> None:
    # The hour-long demo: 34 demo jobs refused, "pickup [6, 7] is on a known obstacle".
    scenario = load_scenario(WAREHOUSE)
    fields = DistanceFieldCache(scenario.grid)
    found = frozenset(scenario.grid.free_cells()[::3])
    for seed in range(200):
        pickup, dropoff, _ = random_job(scenario, random.Random(seed), fields, found)
        assert pickup not in found and dropoff not in found


async def test_the_operator_session_follows_the_obstacles_of_the_fleet_map(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    topics = Topics(root)
    view = FleetMap(
        header=header("coordinator"),
        name="m",
        width=3,
        height=1,
        rows=["..."],
        obstacles=[Cell(1, 0)],
    )
    probe_factory().publish(topics.fleet("map"), encode(view), qos=1, retain=True)
    async with operator_session(broker.url, topics, "op") as op:
        await async_wait_for(lambda: op.obstacles == {Cell(1, 0)}, what="the found obstacle")


async def test_a_malformed_fleet_map_changes_nothing_the_operator_knows(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    topics = Topics(root)
    good = FleetMap(
        header=header("coordinator"), name="m", width=3, height=1, rows=["..."], obstacles=[]
    )
    probe = probe_factory()
    coordinator = CoordinatorPeer(probe, topics)
    async with operator_session(broker.url, topics, "op") as op:
        found = good.model_copy(update={"obstacles": [Cell(2, 0)]})
        probe.publish(topics.fleet("map"), encode(found))
        await async_wait_for(lambda: op.obstacles == {Cell(2, 0)}, what="the found obstacle")
        for bad in (b"{not json", b'{"obstacles": [[-1, 0]]}', b"x" * 10):
            probe.publish(topics.fleet("map"), bad)
        coordinator.status("online", step=7)  # a marker: read after the bad maps
        await async_wait_for(
            lambda: op.coordinator is not None and op.coordinator.step == 7, what="the marker"
        )
        assert op.obstacles == {Cell(2, 0)}  # the bad maps changed nothing
        later = good.model_copy(update={"obstacles": [Cell(1, 0)]})
        probe.publish(topics.fleet("map"), encode(later))
        await async_wait_for(lambda: op.obstacles == {Cell(1, 0)}, what="the next good map")


def test_the_demo_keeps_a_job_queued_for_every_unit() -> None:
    # 150 units with 6 jobs kept queued: 144 stood idle through the whole demo (issue 19).
    assert demo_queue(4, 0.5) == (6, 0.5)  # a small fleet: at least 6, one every step
    keep, pace = demo_queue(150, 0.2)
    assert keep == 150 and pace == pytest.approx(0.2 / 25)  # refilled within a step or so
    assert demo_queue(150, 0.2, keep_active=10) == (10, 0.2)
