"""The stop and the jobs across a broker's death, on brokers that share NOTHING (protocol.md §5.1,
"Across a broker's death").

The coordinator, the simulated units and an operator run on a list of two or three independent
embedded brokers: the worst case of a cluster whose retained messages are node-local (RabbitMQ's,
rabbitmq-server #8096). The broker everyone is on is stopped; everyone moves to the next one,
which never saw what was retained on the first: (a) the stop engaged there holds, and is put back
on the next broker; (b) a stale `released` kept by the next broker releases nothing; (c) a fleet
that was released finishes its jobs, none lost or done twice, and no unit counted lost.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from gridfleet.protocol import Topics, decode_estop
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, coordinator_thread, fleet_thread, world_of

from support.operator_peer import OperatorPeer
from support.paths import MAPS
from support.probe import MqttProbe, retained_latch
from support.wait import wait_for

pytestmark = pytest.mark.slow  # seconds a test: in make test, not in test-fast

if TYPE_CHECKING:
    from gridfleet.coordinator.shell import CoordinatorShell
    from gridfleet.robots.fleet import Fleet

SCENARIO = load_scenario(MAPS / "playfield.toml")
ROOT = "failover"
T = Topics(ROOT)
STEP_S = 0.2
# A unit's loss timeout is 5 steps: 2 s at 0.4 s, which a failover on a loaded 2-core host (every
# broker, the coordinator and the units in this one process) takes well inside; at 0.2 s (1 s) a
# unit was once back on the next broker 1.2 s after its last state, and rightly counted lost.
JOBS_STEP_S = 0.4
HELD_S = 3.0  # how long after the failover the stopped fleet is watched for a move
STALE = b"released|operator-cli-old|released long ago, on this broker only"


@contextmanager
def brokers(count: int) -> Iterator[list[BrokerThread]]:
    """`count` embedded brokers that share nothing, each stopped at the end (also on failure)."""
    with ExitStack() as stack:
        yield [stack.enter_context(BrokerThread()) for _ in range(count)]


@contextmanager
def fleet_on(
    tmp_path: Path, urls: str, step_s: float = STEP_S
) -> Iterator[tuple[ServiceThread[CoordinatorShell], ServiceThread[Fleet]]]:
    """The coordinator and the playfield's four units on the broker list `urls`, all online."""
    coordinator = coordinator_thread(
        SCENARIO, urls, root=ROOT, step_s=step_s, db_path=tmp_path / "jobs.db"
    ).start(30)
    try:
        fleet = fleet_thread(SCENARIO, urls, root=ROOT, step_s=step_s).start(30)
        try:
            yield coordinator, fleet
        finally:
            fleet.stop(30)
    finally:
        coordinator.stop(30)


def moves(fleet: ServiceThread[Fleet]) -> int:
    """Every move the units made in the world so far (the ground truth, not what they said)."""
    world = world_of(fleet)
    return fleet.call(lambda: sum(world.moves.values()))


def all_on(
    coordinator: ServiceThread[CoordinatorShell], fleet: ServiceThread[Fleet], url: str
) -> bool:
    """Whether the coordinator and every unit are connected to the broker `url`."""
    shell = coordinator.service
    if not coordinator.call(lambda: shell.ready.is_set() and shell.endpoint.where == url):
        return False
    shells = fleet.service.shells.values()
    return fleet.call(lambda: all(s.online.is_set() and s.endpoint.where == url for s in shells))


def units_stopped(fleet: ServiceThread[Fleet]) -> bool:
    logic = fleet.service.logic
    return fleet.call(lambda: all(u.estop and u.status == "stopped" for u in logic.values()))


def submit_jobs(operator: OperatorPeer, count: int) -> list[str]:
    """`count` jobs of the scenario's (round and round), with ids of ours; each accepted."""
    ids = []
    for n in range(count):
        spec = SCENARIO.jobs[n % len(SCENARIO.jobs)]
        job_id = f"job-{n + 1}"
        reply = operator.submit_job(spec.pickup, spec.dropoff, spec.mass, job_id=job_id)
        assert reply.accepted, reply
        ids.append(job_id)
    return ids


def stopped_on_a_then_failed_over(
    a: BrokerThread,
    b: BrokerThread,
    coordinator: ServiceThread[CoordinatorShell],
    fleet: ServiceThread[Fleet],
) -> tuple[int, dict[str, object]]:
    """Jobs under way, the stop engaged on A, A stopped; the moves and squares when it stopped."""
    with MqttProbe(a.url) as probe:
        operator = OperatorPeer(probe, T, "ann")
        submit_jobs(operator, 4)
        wait_for(lambda: moves(fleet) >= 4, 20, what="the units under way")
        operator.engage("STOP pressed on broker A")
        core = coordinator.service.core
        wait_for(lambda: coordinator.call(lambda: core.estop), what="the coordinator stopped")
        wait_for(lambda: units_stopped(fleet), what="every unit stopped")
    world = world_of(fleet)
    before = moves(fleet), fleet.call(lambda: dict(world.positions))
    a.stop()
    return before


def watch_held(
    coordinator: ServiceThread[CoordinatorShell],
    fleet: ServiceThread[Fleet],
    before: tuple[int, dict[str, object]],
    url: str,
) -> None:
    """Poll until everyone is on `url`, the latch engaged there and HELD_S more: nothing moves."""
    world = world_of(fleet)
    count, squares = before

    def still() -> bool:
        assert moves(fleet) == count, "a unit moved while the stop was engaged"
        assert fleet.call(lambda: dict(world.positions)) == squares
        return True

    wait_for(lambda: still() and all_on(coordinator, fleet, url), 30, what="all on the next broker")
    engaged = wait_for(
        lambda: still() and retained_latch(url, T), 20, what="a latch on the next broker"
    )
    assert decode_estop(engaged).engaged and decode_estop(engaged).by == "ann", engaged
    core = coordinator.service.core
    assert coordinator.call(lambda: core.estop)
    until = time.monotonic() + HELD_S
    wait_for(lambda: still() and time.monotonic() >= until, HELD_S + 10, what="the fleet held")
    wait_for(lambda: units_stopped(fleet), what="the units read the latch again")


def released_flows(url: str, fleet: ServiceThread[Fleet], count: int) -> None:
    """An operator releases on `url`: the fleet moves again."""
    with MqttProbe(url) as probe:
        OperatorPeer(probe, T, "ann").release("area checked")
        wait_for(lambda: moves(fleet) > count, 20, what="the fleet moving after the release")


def test_a_stop_engaged_on_a_broker_that_dies_holds_on_the_next_one_until_released(
    tmp_path: Path,
) -> None:
    with brokers(2) as (a, b), fleet_on(tmp_path, f"{a.url},{b.url}") as (coordinator, fleet):
        assert retained_latch(b.url, T) is None  # B never sees what A keeps
        before = stopped_on_a_then_failed_over(a, b, coordinator, fleet)
        watch_held(coordinator, fleet, before, b.url)
        released_flows(b.url, fleet, before[0])


def test_a_stale_release_kept_by_the_next_broker_does_not_release_the_fleet(
    tmp_path: Path,
) -> None:
    with brokers(2) as (a, b):
        with MqttProbe(b.url) as probe:  # B keeps a release of long ago, A never hears of it
            probe.publish(T.fleet("estop"), STALE, qos=1, retain=True)
        assert retained_latch(b.url, T) == STALE
        with fleet_on(tmp_path, f"{a.url},{b.url}") as (coordinator, fleet):
            before = stopped_on_a_then_failed_over(a, b, coordinator, fleet)
            watch_held(coordinator, fleet, before, b.url)
            released_flows(b.url, fleet, before[0])


def test_a_released_fleet_finishes_its_jobs_across_a_failover_none_lost_none_twice(
    tmp_path: Path,
) -> None:
    with (
        brokers(3) as (a, b, c),
        fleet_on(tmp_path, f"{a.url},{b.url},{c.url}", JOBS_STEP_S) as (
            coordinator,
            fleet,
        ),
    ):
        core = coordinator.service.core
        with MqttProbe(a.url) as probe:
            ids = submit_jobs(OperatorPeer(probe, T, "ann"), 6)
        wait_for(lambda: moves(fleet) >= 6, 20, what="the units under way")
        a.stop()
        wait_for(lambda: all_on(coordinator, fleet, b.url), 30, what="all on broker B")

        def states() -> dict[str, str]:
            return coordinator.call(lambda: {j.id: j.state for j in core.jobs.jobs.values()})

        wait_for(lambda: all(s == "done" for s in states().values()), 45, what="every job done")
        assert sorted(states()) == sorted(ids)  # none lost, none made up
        texts = coordinator.call(lambda: [e.text for e in core.events.events])
        assert not [t for t in texts if " lost" in t], texts  # nobody counted lost
        done = [t for t in texts if t.startswith("job ") and " done" in t]
        assert len(done) == len(ids), done  # each job done once
        # The page's view, on the broker it is on now, says the same.
        with MqttProbe(b.url) as probe:
            listed = OperatorPeer(probe, T, "page")
            wait_for(lambda: listed.all_final(ids), what="the jobs view on broker B")
            assert {i: listed.job_state(i) for i in ids} == dict.fromkeys(ids, "done")
