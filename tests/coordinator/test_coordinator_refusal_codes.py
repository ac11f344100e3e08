"""Every refusal of every request carries its code (Reply.code, protocol.md §6.5) beside its
reason, and an accepted request none; the pure core, its replies read as they are published."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.inbox import Inbox
from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.world import World
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import (
    CancelJob,
    Charger,
    ClearObstacles,
    ControlUnit,
    Leds,
    RemoveUnit,
    Reply,
    Sensors,
    SetGoal,
    SubmitJob,
    UnitState,
    decode,
    encode,
)
from gridfleet.protocol.messages import Request

from support.coordinator_drive import TOPICS, meet, reply_in, request
from support.effects import header, stamper

# Column 4 is a wall from top to bottom: [5, y] cannot be reached from the rest.
GRID = GridMap.from_rows(["....@.", ".@..@.", "....@."])
C1 = Charger(name="C1", square=Cell(3, 2))


def make() -> CoordinatorCore:
    """Connected, with unit1 (5 kg) idle at [0, 0]; charger C1 at [3, 2]."""
    world = World(GRID, fleet_known_after_s=0.0, chargers=(C1,))
    core = CoordinatorCore(world, JobBook(), "n", topics=TOPICS, stamp=stamper("coordinator"))
    core.on_connect()
    state = UnitState(
        header=header("unit1"),
        step=0,
        position=Cell(0, 0),
        direction="-",
        status="idle",
        leds=Leds(),
        sensors=Sensors(N="wall", E="free", S="free", W="wall"),
    )
    meet(core, state, capacity_kg=5.0)
    return core


def fields(**over: Any) -> dict[str, Any]:
    return {"header": header("op"), "request_id": "r1", "reply_to": "op", **over}


def job(**over: Any) -> SubmitJob:
    return SubmitJob(**fields(**{"pickup": [3, 0], "dropoff": [0, 2], "mass_kg": 1.0, **over}))


def control(command: str, unit: str = "unit1", request_id: str = "r1") -> ControlUnit:
    return ControlUnit(**fields(unit=unit, command=command, request_id=request_id))


KIND = {
    SubmitJob: "submit_job",
    CancelJob: "cancel_job",
    SetGoal: "set_goal",
    ControlUnit: "control_unit",
    ClearObstacles: "clear_obstacles",
    RemoveUnit: "remove_unit",
}


def answer(core: CoordinatorCore, req: Request, now: float = 1.0) -> Reply:
    return reply_in(request(core, KIND[type(req)], req, now))


def nothing(core: CoordinatorCore) -> None:
    """No preparation."""


def submitted(core: CoordinatorCore) -> None:
    """job `j` queued."""
    assert answer(core, job(job_id="j", request_id="first"), 0.0).accepted


def cancelled(core: CoordinatorCore) -> None:
    """job `j` queued and cancelled."""
    submitted(core)
    cancel = CancelJob(**fields(job_id="j", request_id="gone"))
    assert answer(core, cancel, 0.0).accepted


def out_of_service(core: CoordinatorCore) -> None:
    """unit1 out of service."""
    assert answer(core, control("out_of_service", request_id="oos"), 0.0).accepted


CASES: list[tuple[str, Callable[[CoordinatorCore], None], Request, str, str]] = [
    ("off the map", nothing, job(pickup=[9, 0]), "pickup [9, 0] is off the 6x3 map", "bad_square"),
    ("on a wall", nothing, job(dropoff=[1, 1]), "dropoff [1, 1] is on a wall", "bad_square"),
    (
        "on a charger",
        nothing,
        job(pickup=[3, 2]),
        "pickup [3, 2] is charger C1: a unit charging there would block it",
        "bad_square",
    ),
    (
        "too heavy",
        nothing,
        job(mass_kg=50.0),
        "mass 50.0 kg exceeds every unit's capacity (largest 5.0 kg)",
        "too_heavy",
    ),
    (
        "walled off",
        nothing,
        job(pickup=[5, 0]),
        "dropoff [0, 2] cannot be reached from pickup [5, 0]",
        "unreachable",
    ),
    ("job id taken", submitted, job(job_id="j", mass_kg=2.0), "job id 'j' is taken", "conflict"),
    (
        "unknown job",
        nothing,
        CancelJob(**fields(job_id="nope")),
        "unknown job 'nope'",
        "unknown_job",
    ),
    (
        "job already final",
        cancelled,
        CancelJob(**fields(job_id="j")),
        "job j is already cancelled",
        "conflict",
    ),
    (
        "goal of an unknown unit",
        nothing,
        SetGoal(**fields(unit="ghost", target=[2, 0])),
        "unknown unit 'ghost'",
        "unknown_unit",
    ),
    (
        "goal on a wall",
        nothing,
        SetGoal(**fields(unit="unit1", target=[1, 1])),
        "target [1, 1] is on a wall",
        "bad_square",
    ),
    (
        "goal out of reach",
        nothing,
        SetGoal(**fields(unit="unit1", target=[5, 1])),
        "unit unit1 cannot reach [5, 1]",
        "unreachable",
    ),
    (
        "control of an unknown unit",
        nothing,
        control("pause", "ghost"),
        "unknown unit 'ghost'",
        "unknown_unit",
    ),
    (
        "resume of a unit not paused",
        nothing,
        control("resume"),
        "unit unit1 is not paused",
        "conflict",
    ),
    (
        "in service of a unit in service",
        nothing,
        control("in_service"),
        "unit unit1 is not out of service",
        "conflict",
    ),
    (
        "pause of a unit out of service",
        out_of_service,
        control("pause"),
        "unit unit1 is out of service: put it back in service first",
        "conflict",
    ),
    (
        "charge of a unit without energy",
        nothing,
        control("charge"),
        "unit unit1 reports no energy: it has nothing to charge",
        "invalid",
    ),
    (
        "charge of an unknown unit",
        nothing,
        control("charge", "ghost"),
        "unknown unit 'ghost'",
        "unknown_unit",
    ),
    (
        "clearing a square that is no obstacle",
        nothing,
        ClearObstacles(**fields(squares=[[2, 0]])),
        "[2, 0] is not a discovered obstacle (known: none)",
        "bad_square",
    ),
    (
        "removing an unknown unit",
        nothing,
        RemoveUnit(**fields(unit="ghost")),
        "unknown unit 'ghost'",
        "unknown_unit",
    ),
    (
        "removing a unit heard from",
        nothing,
        RemoveUnit(**fields(unit="unit1")),
        "unit unit1 is online and heard from: only a lost unit (offline, broken or silent) can "
        "be removed; take it out of service and switch it off first",
        "conflict",
    ),
]


@pytest.mark.parametrize(
    ("before", "req", "reason", "code"),
    [case[1:] for case in CASES],
    ids=[case[0] for case in CASES],
)
def test_each_refusal_carries_its_code_and_its_reason(
    before: Callable[[CoordinatorCore], None], req: Request, reason: str, code: str
) -> None:
    core = make()
    before(core)
    answered = answer(core, req)
    assert (answered.accepted, answered.reason, answered.code) == (False, reason, code)


def test_an_accepted_request_carries_no_code() -> None:
    core = make()
    for req in (job(), control("pause"), control("resume")):
        answered = answer(core, req.model_copy(update={"request_id": f"ok-{id(req)}"}))
        assert (answered.accepted, answered.code) == (True, None)


def test_a_full_queue_and_an_account_with_too_many_jobs_are_refused_with_their_codes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    core = make()
    monkeypatch.setattr("gridfleet.coordinator.requests.MAX_OPEN_JOBS_PER_ACCOUNT", 1)
    assert answer(core, job(request_id="a")).accepted
    answered = answer(core, job(request_id="b"))
    assert (answered.code, answered.reason) == (
        "too_many",
        "too many jobs: account 'op' has 1 not finished yet (at most 1 an account); wait for "
        "some to finish, or cancel some",
    )
    monkeypatch.setattr("gridfleet.coordinator.requests.MAX_OPEN_JOBS", 1)
    answered = answer(core, job(request_id="c"))
    assert (answered.code, answered.reason) == (
        "queue_full",
        "the queue is full: 1 jobs are not finished yet (at most 1); wait for some to finish, or "
        "cancel some",
    )


def test_a_request_that_does_not_decode_or_waits_beyond_its_share_is_refused_with_its_code() -> (
    None
):
    core = make()
    bad = encode(job()).replace(b'"mass_kg":1.0', b'"mass_kg":"1.0"')
    answered = reply_in(request(core, "submit_job", bad, 1.0))
    assert (answered.accepted, answered.code) == (False, "invalid")
    core.inbox = Inbox(per_account=1)
    topic = TOPICS.request("submit_job")
    assert core.offer(topic, encode(job(request_id="w1")), 1.0)[1], "the first one waits"
    effects, waits = core.offer(topic, encode(job(request_id="w2")), 1.0)
    (refused,) = [decode(Reply, m.payload) for m in effects.publish if "/replies/" in m.topic]
    assert (waits, refused.accepted, refused.code) == (False, False, "too_many")
    assert refused.reason is not None and refused.reason.startswith("too many requests: account")


def test_a_request_id_reused_for_another_request_is_refused_as_a_conflict() -> None:
    core = make()
    assert answer(core, job()).accepted
    answered = answer(core, job(pickup=[2, 0]))
    assert (answered.accepted, answered.code) == (False, "conflict")
