"""The coordinator's history in words (`fleet/events`, protocol.md §5.7): what each change says,
that the view is bounded and retained, and that it outlives a restart."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.events import EventLog
from gridfleet.coordinator.jobs import Job
from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.coordinator.store import STORED_EVENTS, JobStore
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import (
    CancelJob,
    Connection,
    EventEntry,
    EventsView,
    SubmitJob,
    Topics,
    decode,
    encode,
)
from gridfleet.protocol.messages import MAX_EVENTS
from gridfleet.robots.unit import UnitLogic
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.coordinator_drive import TOPICS, from_unit, make_core, meet, orders_in, request
from support.coordinator_fakes import ROOM_ROWS, Yard
from support.effects import STAMP, header, published
from support.probe import MqttProbe
from support.wait import async_wait_for, wait_for

AT = datetime(2026, 11, 24, 9, 0, tzinfo=UTC)
GRID = GridMap.from_rows(["....", ".@..", "...."])
EVENTS = TOPICS.fleet("events")


def texts(log: EventLog) -> list[str]:
    return [e.text for e in log.events]


def test_a_jobs_life_in_words() -> None:
    log = EventLog()
    job = Job("crate", Cell(1, 8), Cell(8, 8), 1.5, submitted_by="dashboard", created_step=10)
    for state, unit, done in [
        ("queued", None, None),
        ("to_pickup", "unit2", None),
        ("to_pickup", "unit2", None),  # no change: nothing to say
        ("to_dropoff", "unit2", None),
        ("done", "unit2", 152),
    ]:
        job = replace(job, state=state, unit=unit, done_step=done)
        log.jobs_changed(AT, [job], 0.1)
    assert texts(log) == [
        "job crate queued by dashboard (1.5 kg, [1, 8] -> [8, 8])",
        "job crate assigned to unit2",
        "unit2 picked up job crate",
        "job crate done by unit2 in 14.2 s",
    ]
    assert [e.job for e in log.events] == ["crate"] * 4
    assert [e.unit for e in log.events] == [None, "unit2", "unit2", "unit2"]


def test_cancelled_failed_rejected_and_requeued_say_why() -> None:
    log = EventLog()
    job = Job("j", Cell(0, 0), Cell(1, 1), 1.0, state="to_pickup", unit="u1")
    log.know([job])  # loaded from the store: not news
    log.jobs_changed(AT, [job], 1.0)
    lost = "unit u1 was lost; re-queued"
    log.jobs_changed(AT, [replace(job, state="queued", unit=None, reason=lost)], 1.0)
    cancelled = replace(job, state="cancelled", unit=None, reason="cancelled by op")
    log.jobs_changed(AT, [cancelled], 1.0)
    heavy = Job("big", Cell(0, 0), Cell(1, 1), 50.0)
    log.jobs_changed(AT, [heavy], 1.0)
    log.jobs_changed(AT, [replace(heavy, state="rejected", reason="too heavy for any unit")], 1.0)
    far = Job("far", Cell(0, 0), Cell(1, 1), 1.0, state="to_dropoff", unit="u2")
    log.know([far])
    log.jobs_changed(AT, [replace(far, state="failed", reason="unit u2 was lost")], 1.0)
    assert texts(log)[:2] + texts(log)[3:] == [
        "job j back in the queue: unit u1 was lost",
        "job j cancelled by op",
        "job big rejected: too heavy for any unit",
        "job far failed: unit u2 was lost",
    ]


def test_a_job_from_before_a_restart_is_done_without_a_duration() -> None:
    # Its created_step counted the steps of the run before; this run counts from 0 again.
    log = EventLog()
    carried = Job("j", Cell(0, 0), Cell(1, 1), 1.0, state="to_dropoff", unit="u1")
    log.know([replace(carried, created_step=500)])
    log.jobs_changed(AT, [replace(carried, state="done", created_step=500, done_step=30)], 1.0)
    assert texts(log) == ["job j done by u1"]
    core = make_core(
        GRID, jobs=[Job("k", Cell(0, 0), Cell(3, 2), 1.0, state="to_pickup", unit="u1")]
    )
    assert [e.text for e in core.restored().events] == [
        "job k back in the queue: coordinator restarted"
    ]


def test_the_history_keeps_the_latest_and_one_line_each() -> None:
    log = EventLog()
    for n in range(MAX_EVENTS + 5):
        log.add(AT, "unit", f"event {n}")
    log.add(AT, "refusal", "two\nlines " + "x" * 600)
    assert len(log.events) == MAX_EVENTS
    assert log.events[0].text == "event 6"
    assert "\n" not in log.events[-1].text and len(log.events[-1].text) == 500
    assert len(log.take_fresh()) == MAX_EVENTS + 6 and log.take_fresh() == ()


def test_a_flapping_unit_or_chatter_never_pushes_the_stops_history_out() -> None:
    # As found: 120 online/offline flaps of one unit pushed the stop's events out of the view.
    log = EventLog()
    log.add(AT, "stop", "emergency stop engaged by operator (checking aisle 3)")
    log.unit_changed(AT, "unit2", "broken")
    for n in range(120):
        log.unit_changed(AT, "unit1", "offline" if n % 2 else "online")
    for n in range(200):
        log.add(AT, "job", f"job j{n} queued", job=f"j{n}")
    texts = [e.text for e in log.events]
    assert len(texts) == MAX_EVENTS
    assert texts[0] == "emergency stop engaged by operator (checking aisle 3)"
    assert "unit unit2 lost (its connection broke)" in texts  # pushed out by jobs, not by unit1
    assert sum(e.unit == "unit1" for e in log.events) == 0  # its flaps went with the chatter
    # Stop and loss lines give way only to newer ones, past half the view.
    for n in range(60):
        log.add(AT, "stop", f"stop {n}")
    safety = [e.text for e in log.events if e.kind != "job"]
    assert safety == [f"stop {n}" for n in range(10, 60)]


def test_a_unit_keeps_only_its_latest_connection_lines() -> None:
    log = EventLog()
    for n in range(10):
        log.unit_changed(AT, "unit1", "offline" if n % 2 else "online")
    log.unit_changed(AT, "unit2", "online")
    assert [e.text for e in log.events] == [
        "unit unit1 online",
        "unit unit1 offline",
        "unit unit1 online",
        "unit unit1 offline",
        "unit unit2 online",
    ]


def test_the_core_tells_units_stops_jobs_and_refusals_in_its_view() -> None:
    core = make_core(GRID)
    sent = [core.on_connect()]
    unit1 = Connection(header=header("unit1"), state="online")
    from_unit(core, "connection", "unit1", unit1, 0.0)
    from_unit(core, "connection", "unit1", unit1, 0.0)  # said again: no news
    lost = Connection(header=header("unit1", 1), state="broken")
    from_unit(core, "connection", "unit1", lost, 0.0)
    core.on_message(TOPICS.fleet("estop"), b"engaged|op|drill", 0.0)
    submit = SubmitJob(
        header=header("op"),
        request_id="r1",
        reply_to="op",
        pickup=Cell(3, 0),
        dropoff=Cell(3, 2),
        mass_kg=1.0,
    )
    effects = request(core, "submit_job", submit, 0.0)
    wall = submit.model_copy(update={"request_id": "r2", "pickup": Cell(1, 1)})
    refused = request(core, "submit_job", wall, 0.0)
    stepped = core.step(1.0)
    sent += [effects, refused, stepped]
    # Each Effects carries its new entries, for the store.
    assert [e.text for e in effects.events] == ["job job-1 queued by op (1 kg, [3, 0] -> [3, 2])"]
    assert [e.kind for e in refused.events] == ["refusal"]
    view = [p for p in published(stepped, events=True) if p[0] == EVENTS]
    (payload,) = [p[1] for p in view]
    assert [e["text"] for e in payload["events"]] == [
        "unit unit1 online",
        "unit unit1 lost (its connection broke)",
        "emergency stop ENGAGED by op: drill",
        "job job-1 queued by op (1 kg, [3, 0] -> [3, 2])",
        "refused submit_job from op: pickup [1, 1] is on a wall",
    ]
    assert view[0][2:] == (1, True)  # QoS 1, retained
    assert [p for p in published(core.step(2.0), events=True) if p[0] == EVENTS] == []
    back = Connection(header=header("unit1", 2), state="online")
    from_unit(core, "connection", "unit1", back, 0.0)
    sent.append(core.step(3.0))
    # On connecting, after the accepted request, after each step with news: a topic's seq
    # counts what went out, not the views that had nothing new.
    seqs = [
        p[1]["header"]["seq"] for e in sent for p in published(e, events=True) if p[0] == EVENTS
    ]
    assert seqs == [0, 1, 2, 3]


def _drive(core: CoordinatorCore, yard: Yard, now: float, until: Callable[[], bool]) -> float:
    """Step the core and its one unit `u` (which follows its orders) until `until()`."""
    while not until():
        now += 1.0
        assert now < 100, "never got there"
        order = orders_in(core.step(now)).get("u")
        if order is not None:
            yard.units["u"].on_order(order, now)
        yard.tick("u", now)
        from_unit(core, "state", "u", yard.state("u"), now)
    return now


def test_the_view_tells_a_jobs_whole_life_a_cancel_the_stop_and_the_unit() -> None:
    grid = GridMap.from_rows(ROOM_ROWS)
    core = make_core(grid)
    core.on_connect()
    yard = Yard(grid, [UnitLogic("u", grid, Cell(0, 0), 5.0, 1.0)])
    meet(core, yard.state("u"), 5.0)

    def submit(job_id: str, pickup: Cell, dropoff: Cell) -> None:
        req = SubmitJob(
            header=header("t"),
            request_id=job_id,
            pickup=pickup,
            dropoff=dropoff,
            mass_kg=1.5,
            job_id=job_id,
        )
        request(core, "submit_job", req, 0.0)

    def state(job_id: str) -> str:
        return core.jobs.jobs[job_id].state

    submit("crate", Cell(0, 1), Cell(9, 9))
    now = _drive(core, yard, 0.0, lambda: state("crate") == "done")
    crate = core.jobs.jobs["crate"]
    assert crate.done_step is not None and crate.done_step > crate.created_step
    took = float(crate.done_step - crate.created_step)  # steps of 1 s
    submit("box", Cell(1, 1), Cell(9, 0))
    now = _drive(core, yard, now, lambda: state("box") == "to_dropoff")
    cancel = CancelJob(header=header("t"), request_id="c1", job_id="box")
    request(core, "cancel_job", cancel, now)
    core.on_message(TOPICS.fleet("estop"), b"engaged|op|spill", now)
    core.on_message(TOPICS.fleet("estop"), b"released|op|done", now)
    gone = Connection(header=header("u", 1), state="offline")
    from_unit(core, "connection", "u", gone, now)
    (view,) = [p for p in published(core.step(now + 1), events=True) if p[0] == EVENTS]
    assert [(e["kind"], e["text"], e["job"], e["unit"]) for e in view[1]["events"]] == [
        ("unit", "unit u online", None, "u"),
        ("job", "job crate queued by t (1.5 kg, [0, 1] -> [9, 9])", "crate", None),
        ("job", "job crate assigned to u", "crate", "u"),
        ("job", "u picked up job crate", "crate", "u"),
        ("job", f"job crate done by u in {took:.1f} s", "crate", "u"),
        ("job", "job box queued by t (1.5 kg, [1, 1] -> [9, 0])", "box", None),
        ("job", "job box assigned to u", "box", "u"),
        ("job", "u picked up job box", "box", "u"),
        (
            "job",
            "job box cancelled by t; unit u puts the item back at its pickup [1, 1], then is free",
            "box",
            "u",
        ),
        ("stop", "emergency stop ENGAGED by op: spill", None, None),
        ("stop", "emergency stop released by op: done", None, None),
        ("unit", "unit u offline", None, "u"),
    ]
    assert all(e["at"] == STAMP for e in view[1]["events"])  # the core's injected clock


def test_a_job_no_unit_can_carry_is_one_refusal_naming_it() -> None:
    grid = GridMap.from_rows(ROOM_ROWS)
    core = make_core(grid)
    yard = Yard(grid, [UnitLogic("u", grid, Cell(0, 0), 5.0, 1.0)])
    meet(core, yard.state("u"), 5.0)
    heavy = SubmitJob(
        header=header("t"), request_id="r", pickup=Cell(0, 1), dropoff=Cell(9, 9), mass_kg=50.0
    )
    effects = request(core, "submit_job", heavy, 0.0)
    assert core.jobs.jobs["job-1"].state == "rejected"  # listed, so the queue view says why
    ((kind, text, job),) = [(e.kind, e.text, e.job) for e in effects.events]
    assert (kind, job) == ("refusal", "job-1")
    assert text.startswith("refused submit_job from t: ") and "50" in text


def test_a_malformed_message_adds_nothing() -> None:
    core = make_core(GRID)
    core.on_connect()
    core.step(1.0)
    effects = core.on_message(TOPICS.request("submit_job"), b"{not json", 0.0)
    effects = core.on_message(TOPICS.unit("connection", "unit1"), b"[]", 0.0)
    assert effects.events == () and list(core.events.events) == []


def test_the_store_keeps_the_latest_history_across_a_restart(tmp_path: Path) -> None:
    store = JobStore(tmp_path / "jobs.db")
    entries = [
        EventEntry(at=AT, kind="unit", text=f"e{n}", unit=f"u{n}") for n in range(STORED_EVENTS + 3)
    ]
    store.save_events(entries[:50])
    store.save_events(entries[50:])
    store.close()
    again = JobStore(tmp_path / "jobs.db")
    loaded = again.load_events()
    assert [e.text for e in loaded] == [f"e{n}" for n in range(3, STORED_EVENTS + 3)]
    core = make_core(GRID)
    core.events.restore(loaded)
    (view,) = [p for p in published(core.on_connect(), events=True) if p[0] == EVENTS]
    assert len(view[1]["events"]) == MAX_EVENTS


def test_the_view_is_retained_and_kept_in_the_store(
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
    playfield: Path,
    tmp_path: Path,
) -> None:
    run_system(playfield)
    probe = probe_factory()
    probe.subscribe(topics.fleet("events"))
    crate = SubmitJob(
        header=header("op"), request_id="r1", pickup=Cell(1, 8), dropoff=Cell(8, 8), mass_kg=1.5
    )
    probe.publish(topics.request("submit_job"), encode(crate), qos=1)

    def latest() -> list[str]:
        got = probe.received(topics.fleet("events"))
        return [e.text for e in decode(EventsView, got[-1].payload).events] if got else []

    wait_for(lambda: any(" done by " in t for t in latest()), timeout=60, what="the job done")
    late = probe_factory()  # retained: a page loaded now gets the history
    late.subscribe(topics.fleet("events"))
    kept = decode(EventsView, late.wait(topics.fleet("events"), lambda m: m.retain).payload)
    assert any(e.text == "unit unit1 online" for e in kept.events)
    assert any(e.text.startswith("job job-1 queued by op") for e in kept.events)
    # In the coordinator's store too (run_system's): a restarted coordinator publishes it again.
    stored = JobStore(tmp_path / "jobs.db").load_events()
    assert any(" done by " in e.text for e in stored)


async def test_a_restarted_coordinator_publishes_the_history_it_kept(
    broker: BrokerThread,
    topics: Topics,
    probe_factory: Callable[..., MqttProbe],
    tmp_path: Path,
) -> None:
    grid = GridMap.from_rows(ROOM_ROWS)
    db = tmp_path / "jobs.db"
    latch = topics.fleet("estop")

    def told(probe: MqttProbe) -> list[str]:
        """The texts of the latest events view `probe` received (an empty payload is none)."""
        got = [m for m in probe.received(topics.fleet("events")) if m.payload]
        return [e.text for e in decode(EventsView, got[-1].payload).events] if got else []

    @contextlib.asynccontextmanager
    async def running() -> AsyncIterator[CoordinatorShell]:
        coordinator = CoordinatorShell(broker.url, grid, root=topics.root, step_s=0.05, db_path=db)
        stop = asyncio.Event()
        task = asyncio.create_task(coordinator.run(stop))
        try:
            await asyncio.wait_for(coordinator.ready.wait(), 10)
            yield coordinator
        finally:
            stop.set()
            await task

    probe = probe_factory()
    probe.subscribe(topics.fleet("events"))
    history = ["emergency stop ENGAGED by op: drill", "emergency stop released by op: ok"]
    async with running():
        probe.publish(latch, b"engaged|op|drill", retain=True)
        await async_wait_for(lambda: told(probe) == history[:1], what="the stop engaged")
        probe.publish(latch, b"released|op|ok", retain=True)
        await async_wait_for(lambda: told(probe) == history, what="the stop released")
    probe.publish(topics.fleet("events"), b"", retain=True)  # the broker forgets: only the store
    late = probe_factory()
    late.subscribe(topics.fleet("events"))
    async with running():
        # The released latch it reads again is no news: the view is the history it kept.
        await async_wait_for(lambda: told(late), what="the events view after the restart")
        assert told(late) == history


def test_a_unit_still_online_whose_states_stop_is_told_lost_and_then_heard_again() -> None:
    # A link that dies without a FIN: the connection stays `online` until the broker's keep-alive
    # ends the session, and only the unit's silence tells. The fleet stopped counting the unit,
    # and nobody was told.
    core = make_core(GRID)
    yard = Yard(GRID, [UnitLogic("u", GRID, Cell(0, 0), 10.0, 1.0)])
    meet(core, yard.state("u"), 10.0)
    core.step(1.0)
    assert "lost" not in " ".join(texts(core.events))
    lost = core.step(6.5)  # silent for 5 step periods and more (protocol.md §8)
    assert [e.text for e in lost.events] == ["unit u lost (no state for 6.5 s)"]
    assert [e.text for e in core.step(7.5).events] == []  # said once
    from_unit(core, "state", "u", yard.state("u"), 8.0)
    assert [e.text for e in core.step(8.5).events] == ["unit u heard again"]
