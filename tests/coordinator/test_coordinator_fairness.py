"""One account's flood of requests: limits per account, urgent kinds first, nobody starved (issue 51).

The inbox and the core alone (pure), then the coordinator over a real broker with units moving.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_coordinator_effects import GRID, meet, state
from test_coordinator_shell import STEP, rig

from gridfleet.accounts import Accounts, default_accounts
from gridfleet.coordinator.audit import Identity
from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.inbound import Arrival
from gridfleet.coordinator.inbox import Inbox, Refusals, Waiting
from gridfleet.coordinator.shell import SERVE_BATCH
from gridfleet.coordinator.views import views_period_s
from gridfleet.grid import Cell
from gridfleet.protocol import Reply, Topics, decode
from gridfleet.system.broker_thread import BrokerThread

from support import coordinator_drive as drive
from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.wait import async_wait_for

TOPICS = Topics()


def waiting(account: str, kind: str, n: int = 0) -> Waiting:
    return Waiting(account, kind, f"{account}/{kind}/{n}", Arrival(kind, None, None))  # type: ignore[arg-type]


def test_urgent_requests_go_first_accounts_take_turns_and_each_keeps_its_order() -> None:
    inbox = Inbox()
    for n in range(3):
        assert inbox.offer(waiting("flood", "submit_job", n)) is None
    assert inbox.offer(waiting("flood", "cancel_job")) is None  # behind its own submits
    assert inbox.offer(waiting("ann", "submit_job")) is None
    assert inbox.offer(waiting("ann", "cancel_job")) is None
    assert inbox.offer(waiting("bob", "control_unit")) is None
    order = []
    while (taken := inbox.take()) is not None:
        order.append(taken.topic)
    assert order == [
        "bob/control_unit/0",  # the one account whose next request is urgent: first
        "flood/submit_job/0",  # then each in turn
        "ann/submit_job/0",
        "ann/cancel_job/0",  # ann's next is urgent now: ahead of the flood's second submit
        "flood/submit_job/1",
        "flood/submit_job/2",
        "flood/cancel_job/0",  # an account's own cancel never overtakes its own submits
    ]
    assert len(inbox) == 0


def test_an_account_over_its_limit_is_refused_in_words_and_others_still_get_in() -> None:
    inbox = Inbox(per_account=3)
    assert [inbox.offer(waiting("flood", "submit_job", n)) for n in range(3)] == [None] * 3
    refusal = inbox.offer(waiting("flood", "cancel_job"))
    assert refusal is not None and "'flood' has 3 waiting" in refusal and "at most 3" in refusal
    assert inbox.offer(waiting("ann", "submit_job")) is None
    assert (len(inbox), inbox.waiting("flood"), inbox.waiting("ann")) == (4, 3, 1)
    inbox.take()
    assert inbox.offer(waiting("flood", "submit_job", 9)) is None  # one answered: room for one


def test_refusals_are_told_once_a_second_with_how_many_came_since() -> None:
    told = Refusals(every_s=1.0)
    assert told.refused("flood", "t", "why 1", 10.0)  # the first: at once
    assert not told.refused("flood", "t", "why 2", 10.2)
    assert not told.refused("flood", "t", "why 3", 10.4)
    assert told.refused("ann", "t", "other", 10.4)  # another account: told at once
    assert told.due(10.9) == []
    [(account, untold)] = told.due(11.0)
    assert (account, untold.count, untold.reason) == ("flood", 2, "why 3")
    assert told.due(12.5) == []


def submit(request_id: str, sender: str = "op", **over: object) -> bytes:
    header = {"version": "1.6", "seq": 0, "timestamp": "2026-11-21T10:00:00.000Z", "sender": sender}
    body = {"pickup": [3, 0], "dropoff": [3, 2], "mass_kg": 1.0, "reply_to": sender}
    return json.dumps({"header": header, "request_id": request_id, **body, **over}).encode()


def make_core(identity: Identity | None = None) -> CoordinatorCore:
    core = drive.make_core(GRID)
    if identity is not None:
        core.identity = identity
    core.on_connect()
    meet(core, state(), capacity_kg=5.0)
    return core


def test_a_flood_over_the_limit_is_answered_refused_told_once_and_changes_nothing() -> None:
    core = make_core()
    core.inbox = Inbox(per_account=5)
    for n in range(5):
        effects, waits = core.offer(TOPICS.request("submit_job"), submit(f"r{n}", "flood"), 1.0)
        assert waits and effects.publish == ()
    refused = [
        core.offer(TOPICS.request("submit_job"), submit(f"x{n}", "flood"), 1.0 + n / 100)[0]
        for n in range(10)
    ]
    assert not core.jobs.jobs  # nothing is queued before the inbox is served
    replies = [
        decode(Reply, out.payload) for e in refused for out in e.publish if "/replies/" in out.topic
    ]
    assert [r.request_id for r in replies] == [f"x{n}" for n in range(10)]
    assert all(not r.accepted and "too many requests" in (r.reason or "") for r in replies)
    assert {r.code for r in replies} == {"too_many"}
    errors = [out for e in refused for out in e.publish if out.topic.endswith("/errors")]
    assert len(errors) == 1  # told once; the other nine in a second, in one report
    later = [out for out in core.step(2.5).publish if out.topic.endswith("/errors")]
    assert len(later) == 1 and b"9 more requests of account 'flood' refused" in later[0].payload
    # Another account is not held up, and what waited is answered in turn.
    _, waits = core.offer(TOPICS.request("submit_job"), submit("a1", "ann"), 3.0)
    assert waits
    served = []
    while (one := core.serve_one(3.0)) is not None:
        served += [
            decode(Reply, o.payload).request_id for o in one[1].publish if "/replies/" in o.topic
        ]
    assert served == ["r0", "a1", "r1", "r2", "r3", "r4"]
    assert len(core.jobs.jobs) == 6


def test_one_account_holds_at_most_its_share_of_open_jobs(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("gridfleet.coordinator.requests.MAX_OPEN_JOBS_PER_ACCOUNT", 3)
    accounts: Accounts = default_accounts(["unit1"])
    core = make_core(Identity(accounts, vouched=True))
    topic = TOPICS.request("submit_job")
    # Two clients of the account `operator` (the console and the page, say) share its share.
    answers = [
        core.on_message(topic, submit(f"r{n}", f"operator-{n % 2}"), 1.0).publish for n in range(4)
    ]
    last = next(decode(Reply, o.payload) for o in answers[-1] if "/replies/" in o.topic)
    assert not last.accepted
    assert last.reason is not None and "account 'operator' has 3 not finished" in last.reason
    assert len(core.jobs.jobs) == 3
    other = core.on_message(topic, submit("d1", "dashboard"), 1.0).publish
    assert [decode(Reply, o.payload).accepted for o in other if "/replies/" in o.topic] == [True]


@pytest.mark.every_broker
async def test_another_operators_cancel_overtakes_a_flood_and_the_fleet_keeps_stepping(
    broker: BrokerThread, root: str, tmp_path: Path
) -> None:
    flood = 600
    async with rig(broker, root, tmp_path) as r:
        core = r.coordinator.core
        answered: list[str] = []  # the senders of the requests answered, in order
        take = core.inbox.take
        held = False  # while True the inbox hands nothing out (the flood and the cancel wait)

        def taking() -> Waiting | None:
            waiting = None if held else take()
            if waiting is not None:
                answered.append(waiting.account)
            return waiting

        core.inbox.take = taking  # type: ignore[method-assign]
        mine = r.submit(Cell(1, 8), Cell(8, 8), 1.0, "mine")
        await async_wait_for(lambda: any(x.request_id == mine for x in r.op.replies()), what="mine")
        with MqttProbe(broker.url, f"flooder-{root.rsplit('-', 1)[-1]}") as probe:
            flooder = OperatorPeer(probe, r.topics, "flooder")
            steps_before = core.step_no
            views_before = len(r.op.job_views())
            held = True
            for n in range(flood):
                flooder.send_submit_job(Cell(1, 1), Cell(8, 8), 1.0, job_id=f"f{n}")
            await async_wait_for(lambda: len(core.inbox) >= 100, what="100 of the flood waiting")
            cancel_came_after = len(answered)
            cancel = r.op.send_cancel_job("mine").request_id
            await async_wait_for(lambda: core.inbox.waiting("tester") == 1, what="the cancel in")
            held = False
            r.coordinator._requests.set()  # what an arrival does: answer what waits
            await async_wait_for(
                lambda: any(x.request_id == cancel for x in r.op.replies()),
                timeout=60,
                what="the other operator's cancel answered",
            )
            steps_then = core.step_no
            replies = await async_wait_for(
                lambda: len(got := flooder.replies()) >= flood and got,
                timeout=120,
                what=f"all {flood} of the flood answered",
            )
            views = len(r.op.job_views()) - views_before
            first, last = replies[0].header.timestamp, replies[-1].header.timestamp
        # Once the cancel had arrived, at most a batch of the flood was answered before it.
        overtaken_by = answered[cancel_came_after:].index("tester")
        assert overtaken_by <= SERVE_BATCH, (overtaken_by, cancel_came_after, len(answered))
        assert steps_then > steps_before  # the step loop ran on meanwhile
        assert len({x.request_id for x in replies}) == flood  # each answered once
        for reply in replies:
            assert reply.accepted or "too many" in (reply.reason or ""), reply
        # One queue view a period at most (plus the first and the trailing one), however many jobs.
        span = (last - first).total_seconds()
        assert views <= 3 + (span + 1.0) / views_period_s(STEP), (views, span)
        assert r.fleet.collisions == 0
