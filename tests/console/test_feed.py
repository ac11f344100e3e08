"""The demo feed's random jobs: feasible, and sized to the fleet's mix of units."""

from __future__ import annotations

import asyncio
import json
import random
import time
from collections.abc import Callable

import pytest

from gridfleet.bench.soak.proxy import FaultyProxy
from gridfleet.bus import connect_first
from gridfleet.config import parse_broker_url
from gridfleet.console.feed import demo_queue, feed, random_job
from gridfleet.console.operator import operator_session
from gridfleet.endpoint import payload_of
from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE, DistanceFieldCache
from gridfleet.protocol import (
    CoordinatorStatus,
    FleetMap,
    HeaderStamper,
    JobsView,
    Reply,
    Routes,
    Topics,
    encode,
)
from gridfleet.protocol.messages import RouteView
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.tasks import cancel_and_wait

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


async def _answering_coordinator(
    url: str, topics: Topics, units: list[str], submitted: list[float]
) -> None:
    """Enough of a coordinator for the feed: online, planning for `units`, accepting every job
    and goal (noting when each job came) and keeping the queue empty, so the demo submits again
    at once."""
    stamp = HeaderStamper("coordinator")
    async with connect_first(url, "fake-coordinator") as client:
        for kind in ("submit_job", "set_goal"):  # the scenario's jobs and goals, then the demo's
            await client.subscribe(topics.request(kind), qos=1)
        status = CoordinatorStatus(
            header=stamp("coordinator"), state="online", step=0, step_period_s=1.0, estop=False
        )
        routes = Routes(header=stamp("routes"), step=1, routes={u: RouteView() for u in units})
        await client.publish(topics.fleet("coordinator"), encode(status), qos=1, retain=True)
        await client.publish(topics.fleet("routes"), encode(routes), qos=1, retain=True)
        async for message in client.messages:
            request = json.loads(payload_of(message))
            if message.topic.matches(topics.request("submit_job")):
                submitted.append(time.monotonic())
            reply = Reply(header=stamp("reply"), request_id=request["request_id"], accepted=True)
            await client.publish(topics.reply(request["reply_to"]), encode(reply), qos=1)
            view = JobsView(header=stamp("jobs"), jobs=[])
            await client.publish(topics.fleet("jobs"), encode(view), qos=1, retain=True)


async def test_the_demo_feed_goes_on_on_the_next_broker_when_its_session_is_lost(
    broker: BrokerThread, root: str
) -> None:
    # A cluster soak's feed submitted its first jobs, lost its node, and fed nothing for the rest
    # of the run: its one session was gone and it waited on it for ever.
    topics = Topics(root)
    scenario = load_scenario(MAPS / "playfield.toml")
    target = parse_broker_url(broker.url.split(",")[0])
    proxy = FaultyProxy(target.host, target.port)
    port = await proxy.start()
    submitted: list[float] = []
    units = [u.id for u in scenario.units]
    coordinator = asyncio.create_task(_answering_coordinator(broker.url, topics, units, submitted))
    # Its own broker first (through the proxy), the same broker straight after.
    url = f"mqtt://127.0.0.1:{port},{broker.url.split(',')[0]}"
    feeding = asyncio.create_task(feed(url, root, scenario, True, 0.05, keep_active=1))
    try:
        await async_wait_for(
            lambda: len(submitted) > len(scenario.jobs) + 2 or feeding.done(), 20, what="demo"
        )
        assert not feeding.done(), feeding.exception()
        assert not coordinator.done(), coordinator.exception()
        proxy.refusing = True
        assert proxy.cut() == 1  # the feed's one session
        cut = time.monotonic()
        await async_wait_for(
            lambda: sum(t > cut for t in submitted) >= 3, 20, what="jobs after the cut"
        )
        assert not feeding.done()
    finally:
        for task in (feeding, coordinator):
            await cancel_and_wait(task)
        await proxy.close()
