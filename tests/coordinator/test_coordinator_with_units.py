"""The real coordinator with the real simulated units on the playfield, over the in-process broker.

The units' world simulation is the ground truth: it counts collisions and moves. Requests go over
MQTT exactly as an operator sends them (`support.operator_peer.OperatorPeer`: protocol models,
replies awaited).
"""

from __future__ import annotations

import contextlib
import itertools
import json
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from gridfleet.coordinator.history_store import HistoryStore
from gridfleet.grid import Cell
from gridfleet.protocol import JobHistoryQuery, Topics, UnitState
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, coordinator_thread, world_of

from support.coordinator_fakes import PLAYFIELD_JOBS
from support.effects import header
from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.wait import WaitTimeout, wait_for

pytestmark = pytest.mark.slow  # seconds a test: in make test, not in test-fast

RunSystem = Callable[..., tuple[ServiceThread, ServiceThread]]
System = Callable[..., tuple[ServiceThread, ServiceThread]]
STEP = 0.05
CAPACITY = {"unit1": 2.0, "unit2": 5.0, "unit3": 10.0, "unit4": 20.0}


@pytest.fixture
def operator(probe_factory: Callable[..., MqttProbe], topics: Topics) -> OperatorPeer:
    """An operator under this test's root."""
    return OperatorPeer(probe_factory(), topics, "tester")


@pytest.fixture
def estop_cleared(operator: OperatorPeer) -> Iterator[None]:
    """Clear the retained emergency stop of this test's root afterwards."""
    yield
    operator.raw_estop(b"")


@pytest.fixture
def system(run_system: RunSystem, playfield: Path) -> System:
    """Start the playfield system; return once the coordinator knows every unit and capacity."""

    def start(step_s: float = STEP) -> tuple[ServiceThread, ServiceThread]:
        coordinator, fleet = run_system(playfield, step_s=step_s)
        world = coordinator.service.world

        def known() -> bool:
            return sorted(world.capacities()) == sorted(CAPACITY.values()) and all(
                u.state is not None for u in world.units.values()
            )

        wait_for(
            lambda: coordinator.call(known), timeout=10, what="the coordinator knows the fleet"
        )
        return coordinator, fleet

    return start


def carried_jobs(op: OperatorPeer, unit: str) -> set[str]:
    """Jobs `unit` ever reported carrying."""
    return {s.job_id for s in op.states(unit) if s.job_id is not None}


@pytest.mark.timeout(150)  # its waits add up to more than 60 s: a slow run fails on the late one
def test_four_units_complete_twelve_mixed_jobs_within_capacity_without_collisions(
    system: System, operator: OperatorPeer
) -> None:
    _, fleet = system()
    world = world_of(fleet)
    ids = []
    for n, (pickup, dropoff, mass) in enumerate(PLAYFIELD_JOBS, start=1):
        ids.append(f"j{n}")
        assert operator.submit_job(pickup, dropoff, mass, job_id=f"j{n}").accepted
    wait_for(lambda: operator.all_final(ids), timeout=50, what="all 12 jobs final")
    jobs = operator.listed_jobs()
    assert {i: jobs[i].state for i in ids} == dict.fromkeys(ids, "done")
    for job in jobs.values():
        assert job.unit is not None and CAPACITY[job.unit] >= job.mass_kg, job
        # The unit the coordinator names is the one that really carried it.
        assert job.id in carried_jobs(operator, job.unit)
    for unit in CAPACITY:
        assert all(s.load_kg <= CAPACITY[unit] for s in operator.states(unit))
        assert not any(e.code == "over_capacity" for s in operator.states(unit) for e in s.errors)
    heavy = {
        i for i, (_, _, mass) in zip(ids, PLAYFIELD_JOBS[: len(ids)], strict=True) if mass > 10
    }
    assert {jobs[i].unit for i in heavy} == {"unit4"}
    assert len({j.unit for j in jobs.values()}) >= 3  # the work was shared, not serialised
    assert world.collisions == 0, world.log


def test_cancel_a_queued_and_an_active_job_releases_the_unit(
    system: System, operator: OperatorPeer
) -> None:
    # Slow steps: unit4 needs 17 of them to its pickup, which must not come before the cancel
    # below, five operator round trips later, however busy the machine.
    _, fleet = system(step_s=0.15)
    units = fleet.service.logic
    # Only unit4 can carry 15 kg: the first job makes it busy, so the second stays queued.
    assert operator.submit_job(Cell(1, 0), Cell(9, 1), 15.0, job_id="active").accepted
    wait_for(lambda: operator.job_state("active") == "to_pickup", timeout=10, what="under way")
    assert operator.listed_jobs()["active"].unit == "unit4"
    assert operator.submit_job(Cell(0, 3), Cell(5, 3), 15.0, job_id="queued").accepted
    wait_for(lambda: operator.job_state("queued") == "queued", timeout=5, what="queued")
    reply = operator.cancel_job("queued")
    assert reply.accepted and reply.job_id == "queued"
    wait_for(lambda: operator.job_state("queued") == "cancelled", timeout=5, what="cancelled")
    assert operator.job_state("active") == "to_pickup"  # untouched by the other cancel
    assert fleet.call(lambda: units["unit4"].job_id) is None, "unit4 loaded: set-up too slow"
    assert operator.cancel_job("active").accepted
    wait_for(lambda: operator.job_state("active") == "cancelled", timeout=5, what="aborted")
    assert "unit4 released" in (operator.listed_jobs()["active"].reason or "")
    # The unit drops its route and action: idle, empty-handed, nothing released.
    wait_for(
        lambda: fleet.call(
            lambda: (
                units["unit4"].status == "idle"
                and not units["unit4"].released
                and units["unit4"].action is None
            )
        ),
        timeout=5,
        what="unit4 idle with no route",
    )
    assert units["unit4"].job_id is None and units["unit4"].load_kg == 0.0
    assert not operator.cancel_job("active").accepted  # already final
    # Released for real: it takes the next heavy job and finishes it.
    assert operator.submit_job(Cell(0, 6), Cell(9, 4), 15.0, job_id="next").accepted
    wait_for(lambda: operator.job_state("next") == "done", timeout=20, what="next job done")
    assert operator.listed_jobs()["next"].unit == "unit4"
    for unit in CAPACITY:
        assert not carried_jobs(operator, unit) & {"active", "queued"}
    assert world_of(fleet).collisions == 0


def test_emergency_stop_halts_all_motion_and_release_resumes(
    system: System, operator: OperatorPeer, estop_cleared: None
) -> None:
    coordinator, fleet = system()
    world = world_of(fleet)
    units = fleet.service.logic
    ids = [f"e{n}" for n in range(4)]
    for job_id, (pickup, dropoff, mass) in zip(ids, PLAYFIELD_JOBS[: len(ids)], strict=True):
        assert operator.submit_job(pickup, dropoff, mass, job_id=job_id).accepted
    start = dict(world.moves)
    wait_for(lambda: sum(world.moves[u] - start[u] for u in start) >= 4, timeout=10, what="motion")
    operator.engage("test")
    wait_for(
        lambda: fleet.call(lambda: all(u.estop for u in units.values())),
        timeout=5,
        what="every unit has the stop",
    )
    frozen = fleet.call(lambda: (dict(world.moves), {u: lg.step for u, lg in units.items()}))
    wait_for(
        lambda: fleet.call(lambda: all(lg.step >= frozen[1][u] + 4 for u, lg in units.items())),
        timeout=5,
        what="four more steps of every unit",
    )
    assert world.moves == frozen[0]  # no unit moved once it had the stop
    core = coordinator.service.core
    assert coordinator.call(lambda: core.estop)
    # Each unit stopped within one of its steps: its first state with the stop shows it
    # stopped with nothing left to drive, and no later state of it moved.
    for unit in CAPACITY:
        states = operator.states(unit)
        first = next(i for i, s in enumerate(states) if s.estop)
        assert states[first].status == "stopped" and states[first].released == []
        assert {s.position for s in states[first:] if s.estop} == {states[first].position}
    operator.release("test")
    wait_for(lambda: operator.all_final(ids), timeout=30, what="jobs finished after release")
    jobs = operator.listed_jobs()
    assert {jobs[i].state for i in ids} == {"done"}, {
        i: (jobs[i].state, jobs[i].reason) for i in ids
    }
    assert sum(world.moves.values()) > sum(frozen[0].values())
    assert world.collisions == 0, world.log


def test_a_forged_order_with_a_jumped_update_id_cannot_take_a_unit_over(
    system: System, operator: OperatorPeer, topics: Topics, probe_factory: Callable[..., MqttProbe]
) -> None:
    _, fleet = system()
    world = world_of(fleet)
    jobs: list[str] = []

    def submit_next() -> None:
        job_id = f"f{len(jobs) + 1}"
        assert operator.submit_job(*PLAYFIELD_JOBS[len(jobs)], job_id=job_id).accepted
        jobs.append(job_id)

    submit_next()
    forger = probe_factory()  # connected first: a forgery must land while its order is current

    def moving() -> UnitState | None:
        """The newest state of a unit driving an order (its order id is the current one).

        Moving, not "with released squares": a unit that moves every step has driven the one
        square it was released by the time it reports, so its states seldom show one.
        """
        return next(
            (
                s
                for u in CAPACITY
                if (s := operator.last_state(u)) and s.order_id and s.status == "moving"
            ),
            None,
        )

    def reported() -> bool:
        return any("never sent" in e.reason for e in operator.errors())

    def under_way() -> UnitState | None:
        if operator.all_final(jobs):  # done before a forgery landed (a busy machine): one more
            submit_next()
        return moving()

    for _ in range(5):  # the order may change under us (a new route): forge the new one then
        now = wait_for(under_way, timeout=20, what="an order under way")
        assert now.order_id is not None
        unit = now.order_id.split("-")[-2]  # <nonce>-<unit>-<route>
        # The coordinator's current order id, an update id it will not reach: every later real
        # update of this order would look stale to the unit, which holds on the forged one.
        forged = {
            "header": {
                "version": "1.6",
                "seq": 0,
                # Stamped now: an order stamped long ago is not driven at all (§4.4 rule 7).
                "timestamp": datetime.now(UTC).isoformat(timespec="milliseconds"),
                "sender": "coordinator",
            },
            "order_id": now.order_id,
            "update_id": 2_000_000_000,
            "step": 0,
            "released": [],
            "planned": [],
            "target": None,
            "action": None,
        }
        forger.publish(topics.unit("order", unit), json.dumps(forged), qos=1)
        with contextlib.suppress(WaitTimeout):
            wait_for(reported, timeout=3, what="the forged order reported")
            break
    wait_for(lambda: operator.all_final(jobs), timeout=30, what="the jobs done all the same")
    assert {operator.listed_jobs()[j].state for j in jobs} == {"done"}
    assert reported()  # and it was reported
    assert world.collisions == 0, world.log


def test_killed_unit_job_is_requeued_and_finished_by_another_capable_unit(
    system: System, operator: OperatorPeer
) -> None:
    # Slow steps: the victim must be killed before its pickup (5 squares away), or the item
    # is lost with it and no other unit can finish the job (protocol §8).
    coordinator, fleet = system(step_s=0.15)
    world = world_of(fleet)
    runners = fleet.service.shells
    units = fleet.service.logic
    core = coordinator.service.core
    # 4 kg: unit2, unit3 and unit4 can carry it (unit2, the nearest, if it is free first).
    assert operator.submit_job(Cell(5, 1), Cell(8, 6), 4.0, job_id="k").accepted
    victim = wait_for(
        lambda: coordinator.call(lambda: (j := core.jobs.get("k")) and j.unit),
        timeout=10,
        what="assigned",
    )
    assert victim != "unit1"

    def kill_if_empty_handed() -> bool:
        if units[victim].job_id is not None:
            return False
        runners[victim].kill()
        return True

    assert fleet.call(kill_if_empty_handed), f"{victim} loaded before the kill: set-up too slow"
    killed_at = world.positions[victim]
    wait_for(lambda: "broken" in operator.connections(victim), timeout=5, what="last will")
    assert "offline" not in operator.connections(victim)
    wait_for(lambda: operator.job_state("k") == "done", timeout=30, what="done by another unit")
    # Back in the queue and re-assigned (both may fall in one coordinator step, and the views go
    # out once a period: the victim's short hold may be in none of them; the core named it).
    owners = [
        j.unit for view in operator.job_views() for j in view.listed() if j.id == "k" and j.unit
    ]
    assert owners and owners[-1] != victim
    assert not any(j.state == "failed" for view in operator.job_views() for j in view.listed())
    finisher = operator.listed_jobs()["k"].unit
    assert finisher in ("unit2", "unit3", "unit4") and finisher != victim
    assert "k" in carried_jobs(operator, finisher) and "k" not in carried_jobs(operator, victim)
    assert world.positions[victim] == killed_at  # dead units do not move
    assert world.collisions == 0, world.log


@pytest.mark.timeout(150)  # its waits add up to more than 60 s: a slow run fails on the late one
def test_coordinator_restart_mid_run_loses_no_job(
    system: System,
    operator: OperatorPeer,
    playfield: Path,
    broker: BrokerThread,
    root: str,
    tmp_path: Path,
) -> None:
    coordinator, fleet = system()
    world = world_of(fleet)
    ids = [f"r{n}" for n in range(8)]
    for job_id, (pickup, dropoff, mass) in zip(ids, PLAYFIELD_JOBS[: len(ids)], strict=True):
        assert operator.submit_job(pickup, dropoff, mass, job_id=job_id).accepted

    def progress() -> bool:
        states = [operator.job_state(i) for i in ids]
        return "done" in states and any(s in ("to_pickup", "to_dropoff") for s in states)

    wait_for(progress, timeout=20, what="some jobs done, some under way")
    coordinator.stop()
    before = operator.listed_jobs()
    assert not all(before[i].state == "done" for i in ids)
    scenario = load_scenario(playfield)
    with coordinator_thread(
        scenario, broker.url, root=root, step_s=STEP, db_path=tmp_path / "jobs.db"
    ):
        try:
            wait_for(lambda: operator.all_final(ids), timeout=40, what="all jobs after restart")
        except Exception:
            print({i: (j.state, j.unit, j.reason) for i, j in operator.listed_jobs().items()})
            print({u: operator.states(u)[-1] for u in CAPACITY})
            raise
    listed = operator.listed_jobs()
    assert {listed[i].state for i in ids} == {"done"}, {
        i: (listed[i].state, listed[i].unit, listed[i].reason) for i in ids
    }
    assert world.collisions == 0, world.log
    # The job history lost nothing either: each job's life from queued to done, once each change.
    history = HistoryStore(tmp_path / "jobs.db")
    since = datetime.now(UTC) - timedelta(hours=1)
    for i in ids:
        query = JobHistoryQuery(header=header("t"), request_id="q", since=since, job_id=i)
        entries, _ = history.query(query, datetime.now(UTC))
        keys = [(e.state, e.unit, e.wait) for e in entries]
        assert keys[0][0] == "queued" and keys[-1][0] == "done", (i, keys)
        assert all(a != b for a, b in itertools.pairwise(keys)), (i, keys)
        ages = [e.since_submitted_s for e in entries]
        assert ages[0] == 0 and ages == sorted(ages), (i, ages)
    history.close()
