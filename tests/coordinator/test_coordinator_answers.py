"""A retried request gets its first answer and changes nothing; the achieved step rate in status.

Exact-publish tests on the pure core (as in test_coordinator_effects.py), and the store's part:
a submit retried after a restart creates no second job.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from gridfleet.coordinator.answers import Answers
from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.store import JobStore
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import CancelJob, Leds, Sensors, SetGoal, SubmitJob, UnitState

from support.coordinator_drive import make_core, meet, request
from support.effects import header, header_json, published

GRID = GridMap.from_rows(["....", ".@..", "...."])
JOB = {"pickup": [3, 0], "dropoff": [3, 2], "mass_kg": 1.0, "priority": 0}
ERRORS = "gridfleet/v1/errors"
JOBS = "gridfleet/v1/fleet/jobs"
REPLY = "gridfleet/v1/replies/op"
STATUS = "gridfleet/v1/coordinator/status"


def reply(
    seq: int,
    request_id: str,
    accepted: bool,
    reason: str | None,
    job_id: str | None,
    code: str | None = None,
) -> Any:
    payload = {
        "header": header_json("coordinator", seq),
        "request_id": request_id,
        "accepted": accepted,
        "reason": reason,
        "job_id": job_id,
        "code": code,
    }
    return (REPLY, payload, 1, False)


def error(seq: int, topic: str, reason: str, request_id: str) -> Any:
    payload = {
        "header": header_json("coordinator", seq),
        "topic": topic,
        "reason": reason,
        "request_id": request_id,
    }
    return (ERRORS, payload, 1, False)


def submit(request_id: str = "r1", sender: str = "op", **over: Any) -> SubmitJob:
    fields: dict[str, Any] = {**JOB, "request_id": request_id, "reply_to": "op", **over}
    return SubmitJob(header=header(sender), **fields)


def unit_state() -> UnitState:
    return UnitState(
        header=header("unit1"),
        step=0,
        position=Cell(0, 0),
        direction="-",
        status="idle",
        leds=Leds(),
        sensors=Sensors(N="wall", E="free", S="free", W="wall"),
    )


@pytest.fixture
def core() -> CoordinatorCore:
    """Connected, with unit1 online at [0, 0], 5 kg."""
    c = make_core(GRID)
    c.on_connect()
    meet(c, unit_state(), capacity_kg=5.0)
    return c


def test_a_retried_submit_gets_the_first_reply_and_queues_no_second_job(
    core: CoordinatorCore,
) -> None:
    first = request(core, "submit_job", submit(), 0.0)
    assert published(first)[0] == reply(0, "r1", True, None, "job-1")
    assert [(a.sender, a.request_id) for a in first.answered] == [("op", "r1")]
    again = request(core, "submit_job", submit(), 1.0)
    assert published(again) == [reply(1, "r1", True, None, "job-1")]
    assert (again.persist, again.answered, again.views_at) == ((), (), None)
    assert list(core.jobs.jobs) == ["job-1"]


def test_a_retried_cancel_is_accepted_again_not_refused_as_already_cancelled(
    core: CoordinatorCore,
) -> None:
    request(core, "submit_job", submit(), 0.0)
    cancel = CancelJob(header=header("op"), request_id="c1", reply_to="op", job_id="job-1")
    request(core, "cancel_job", cancel, 1.0)
    again = request(core, "cancel_job", cancel, 2.0)
    assert published(again) == [reply(2, "c1", True, None, "job-1")]
    assert again.persist == ()


def test_a_retried_goal_changes_nothing_after_the_goal_was_cleared(core: CoordinatorCore) -> None:
    goal = SetGoal(header=header("op"), request_id="g1", reply_to="op", unit="unit1", target=(3, 2))
    request(core, "set_goal", goal, 0.0)
    clear = goal.model_copy(update={"request_id": "g2", "target": None})
    request(core, "set_goal", clear, 1.0)
    assert published(request(core, "set_goal", goal, 2.0)) == [reply(2, "g1", True, None, None)]
    assert core.directives.goals == {}, "the late copy of g1 did not pin the unit again"


def test_a_retried_refusal_is_refused_again_with_the_same_reason(core: CoordinatorCore) -> None:
    request(core, "submit_job", submit(pickup=(12, 3)), 0.0)
    reason = "pickup [12, 3] is off the 4x3 map"
    assert published(request(core, "submit_job", submit(pickup=(12, 3)), 1.0)) == [
        error(1, "gridfleet/v1/requests/submit_job", f"SubmitJob: {reason}", "r1"),
        reply(1, "r1", False, reason, None, "bad_square"),
    ]


def test_an_id_reused_for_a_different_request_is_refused_and_changes_nothing(
    core: CoordinatorCore,
) -> None:
    request(core, "submit_job", submit(), 0.0)
    other = request(core, "submit_job", submit(pickup=[0, 2]), 1.0)
    reason = (
        "request id 'r1' was already used by op for a different request: "
        "give every request its own id"
    )
    assert published(other) == [
        error(0, "gridfleet/v1/requests/submit_job", f"SubmitJob: {reason}", "r1"),
        reply(1, "r1", False, reason, None, "conflict"),
    ]
    assert (other.persist, other.answered, list(core.jobs.jobs)) == ((), (), ["job-1"])
    retry = request(core, "submit_job", submit(), 2.0)
    assert published(retry) == [reply(2, "r1", True, None, "job-1")], "the first answer is kept"


def test_the_same_request_id_from_another_sender_is_a_new_request(core: CoordinatorCore) -> None:
    request(core, "submit_job", submit(), 0.0)
    effects = request(core, "submit_job", submit(sender="op2"), 1.0)
    assert published(effects)[0] == reply(1, "r1", True, None, "job-2")
    assert list(core.jobs.jobs) == ["job-1", "job-2"]


def test_a_job_id_resubmitted_with_the_same_content_is_that_job_and_other_content_is_taken(
    core: CoordinatorCore,
) -> None:
    request(core, "submit_job", submit("r1", job_id="crate"), 0.0)
    # A new request id (the answer forgotten, or a restarted client): the same job, accepted.
    same = request(core, "submit_job", submit("r2", job_id="crate"), 1.0)
    assert published(same) == [reply(1, "r2", True, None, "crate")]
    assert (same.persist, list(core.jobs.jobs)) == ((), ["crate"])
    other = request(core, "submit_job", submit("r3", job_id="crate", mass_kg=2.0), 2.0)
    assert published(other) == [
        error(0, "gridfleet/v1/requests/submit_job", "SubmitJob: job id 'crate' is taken", "r3"),
        reply(2, "r3", False, "job id 'crate' is taken", "crate", "conflict"),
    ]
    elsewhere = request(core, "submit_job", submit("r4", sender="op2", job_id="crate"), 3.0)
    assert published(elsewhere)[1] == reply(
        3, "r4", False, "job id 'crate' is taken", "crate", "conflict"
    )


def test_a_submit_retried_after_a_restart_queues_no_second_job(tmp_path: Path) -> None:
    store = JobStore(tmp_path / "jobs.sqlite3")
    before = make_core(GRID)
    meet(before, unit_state(), capacity_kg=5.0)
    effects = request(before, "submit_job", submit(), 0.0)
    store.save(effects.persist, effects.answered)
    store.close()
    store = JobStore(tmp_path / "jobs.sqlite3")
    after = make_core(GRID, jobs=store.load())
    after.answers.restore(store.load_answers())
    after.on_connect()
    meet(after, unit_state(), capacity_kg=5.0)
    again = request(after, "submit_job", submit(), 5.0)
    assert published(again) == [reply(0, "r1", True, None, "job-1")]
    assert list(after.jobs.jobs) == ["job-1"]
    store.close()


def test_the_store_keeps_only_the_latest_answers(tmp_path: Path) -> None:
    store = JobStore(tmp_path / "jobs.sqlite3", answers_kept=2)
    core = make_core(GRID)
    meet(core, unit_state(), capacity_kg=5.0)
    for n in range(1, 4):
        effects = request(core, "submit_job", submit(f"r{n}"), float(n))
        store.save(effects.persist, effects.answered)
    assert [a.request_id for a in store.load_answers()] == ["r2", "r3"]
    assert len(store.load()) == 3, "jobs are never pruned"
    store.close()


def test_answers_are_bounded_and_the_oldest_is_forgotten() -> None:
    answers = Answers(kept=2)
    book = JobBook()
    core = make_core(GRID)
    core.jobs, core.answers = book, answers
    meet(core, unit_state(), capacity_kg=5.0)
    for n in range(1, 4):
        request(core, "submit_job", submit(f"r{n}"), float(n))
    assert len(answers) == 2
    assert answers.recall(submit("r1")) is None, "r1 is forgotten: a retry now is a new job"
    assert answers.recall(submit("r3")) is not None


def test_status_carries_the_achieved_step_time_once_per_window() -> None:
    core = make_core(GRID)
    statuses = []
    for n in range(13):  # a step every 0.5 s, the period is 1 s: twice as fast as set
        effects = core.step(0.5 * n)
        statuses += [p for p in published(effects) if p[0] == STATUS]
    assert [(s[1]["step"], s[1]["achieved_step_s"], s[3]) for s in statuses] == [
        (11, 0.5, True),  # 5 s after the first step, 10 steps later
    ]
    assert published([core.status("offline")])[0][1]["achieved_step_s"] == 0.5


def test_a_full_queue_refuses_a_new_job_in_words_and_changes_nothing(
    core: CoordinatorCore, monkeypatch: pytest.MonkeyPatch
) -> None:
    # As found: nothing bounded the queue, and ~32,000 queued jobs pushed the retained queue
    # view past the broker's packet limit (a broken view for everybody).
    monkeypatch.setattr("gridfleet.coordinator.requests.MAX_OPEN_JOBS", 2)
    for n in (1, 2):
        request(core, "submit_job", submit(f"r{n}", job_id=f"j{n}"), 0.0)
    full = request(core, "submit_job", submit("r3", job_id="j3"), 1.0)
    reason = (
        "the queue is full: 2 jobs are not finished yet (at most 2); wait for some to finish, "
        "or cancel some"
    )
    answers = [m for m in published(full) if "/fleet/" not in m[0]]  # a view may be due anyway
    assert [
        (topic, body.get("accepted"), body.get("reason"), body.get("code"))
        for topic, body, *_ in answers
    ] == [
        ("gridfleet/v1/errors", None, f"SubmitJob: {reason}", None),
        ("gridfleet/v1/replies/op", False, reason, "queue_full"),
    ]
    assert list(core.jobs.jobs) == ["j1", "j2"] and full.persist == ()
    # A retry of a queued job is still answered as before.
    again = published(request(core, "submit_job", submit("r2", job_id="j2"), 2.0))
    again = [m for m in again if "/fleet/" not in m[0]]
    assert [(topic, body.get("accepted")) for topic, body, *_ in again] == [
        ("gridfleet/v1/replies/op", True)
    ]
