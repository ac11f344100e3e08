"""A failed handler is never silent: counted, told on `errors` (the topic and the exception's class,
never its text nor a traceback), a storm held to about one report a second per topic with the
count of those in between; the coordinator's metrics count every component's reports, the alerts
process raises `handler_failures`, and a VDA 5050 unit whose states its adapter fails on shows it
(`unreadable_state`, then `broken`) until a state is handled again. Issue 53, item 2."""

from __future__ import annotations

import asyncio
import time
import zlib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

from gridfleet.alerts.settings import AlertSettings
from gridfleet.alerts.shell import AlertsShell
from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.endpoint import Backoff, Endpoint
from gridfleet.failures import EVERY_S, FailureReports, failure_reason, parse_failure
from gridfleet.maps import load_map
from gridfleet.metrics import MetricsOptions
from gridfleet.outbound import Outbound, error_report
from gridfleet.protocol import TOPICS, ErrorReport, HeaderStamper, Topics, decode
from gridfleet.protocol.messages import AlertsView, Connection, UnitState
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.core import UNREADABLE_STATES, VehicleCore
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.shell import AdapterShell
from gridfleet.robots.vda5050.virtual import VirtualSpec
from gridfleet.robots.vda5050.virtual_shell import VirtualVehicleShell
from gridfleet.robots.vda5050.wire import Vehicle
from gridfleet.system.broker_thread import BrokerThread

from support.paths import MAPS
from support.probe import MqttProbe
from support.scrape import get, parse
from support.wait import async_wait_for

SECRET = "the exception's own words, with a path /srv/secret"


# ---- the rules, pure ---------------------------------------------------------------------------


def test_reasons_read_back_and_name_the_class_alone() -> None:
    one = failure_reason("vda5050", "TypeError")
    assert one == "internal error in vda5050: TypeError while handling a message on this topic"
    assert parse_failure(one) is not None and parse_failure(one).count == 1  # type: ignore[union-attr]
    parsed = parse_failure(failure_reason("unit", "KeyError", 12))
    assert parsed is not None and (parsed.component, parsed.count, parsed.error) == (
        "unit",
        12,
        "KeyError",
    )
    strange = parse_failure(failure_reason("martian", "ValueError"))
    assert strange is not None and strange.component == "other"  # a label stays bounded
    refusal = "SubmitJob: field 'mass_kg': Input should be greater than 0"
    assert parse_failure(refusal) is None


def test_a_storm_is_told_once_a_second_per_topic_and_every_failure_counted() -> None:
    reports = FailureReports("unit", every_s=1.0, burst=10, per_s=2.0)
    told: list[tuple[str, str]] = []
    for i in range(50):  # 50 failures in half a second on one topic
        reason = reports.failed("t/a", "TypeError", i * 0.01)
        if reason is not None:
            told.append(("t/a", reason))
    assert len(told) == 1  # the first at once
    assert reports.next_due(0.5) == pytest.approx(1.0)
    assert reports.due(0.9) == []
    told += reports.due(1.0)
    assert len(told) == 2
    counts = [parse_failure(reason) for _, reason in told]
    assert [c.count for c in counts if c is not None] == [1, 49]  # nothing lost
    assert reports.failures == 50 and reports.next_due(1.0) is None


def test_many_topics_failing_at_once_are_held_to_the_components_budget() -> None:
    reports = FailureReports("unit", every_s=1.0, burst=10, per_s=2.0)
    told = [reports.failed(f"t/{n}", "TypeError", 0.0) for n in range(30)]
    assert sum(r is not None for r in told) == 10  # the burst, then 2 a second
    later = reports.due(1.0)
    assert len(later) == 2
    total = 10 + len(later)
    now = 1.0
    while (at := reports.next_due(now)) is not None:
        now = at
        total += len(reports.due(now))
    assert total == 30 and now <= 1.0 + 20 / 2.0 + 0.01  # every topic told, within the budget


# ---- the endpoint, over the broker ---------------------------------------------------------


@asynccontextmanager
async def running(endpoint: Endpoint, handle: Any) -> AsyncIterator[None]:
    stop = asyncio.Event()
    task = asyncio.create_task(endpoint.run(stop, handle))
    try:
        await async_wait_for(lambda: endpoint.online.is_set() or task.done(), 30, what="online")
        yield
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)


def reports_on(probe: MqttProbe, topics: Topics) -> list[ErrorReport]:
    return [decode(ErrorReport, m.payload) for m in probe.received(topics.fleet("errors"))]


@pytest.mark.every_broker
async def test_a_handler_that_raises_is_counted_and_told_on_errors_without_its_words(
    broker: BrokerThread, topics: Topics
) -> None:
    bad, good = topics.unit("order", "unit1"), topics.unit("goal", "unit1")
    stamp = HeaderStamper("unit1")
    handled: list[str] = []

    def report(topic: str, reason: str) -> Outbound:
        return Outbound.of(
            "errors", topics.fleet("errors"), error_report(stamp("errors"), topic, reason)
        )

    async def handle(topic: str, payload: bytes) -> None:
        if topic == bad:
            raise TypeError(SECRET)
        handled.append(topic)

    endpoint = Endpoint(
        broker.url,
        f"failing-{zlib.crc32(topics.root.encode())}",
        subscriptions=lambda: [(bad, 1), (good, 1)],
        backoff=Backoff(0.05, 0.2),
        component="unit",
        report=report,
    )
    with MqttProbe(broker.url) as probe:
        probe.subscribe(topics.fleet("errors"))
        async with running(endpoint, handle):
            began = time.monotonic()
            for _ in range(20):  # a storm: far more than one a second
                probe.publish(bad, b"{}", qos=1)
            probe.publish(good, b"{}", qos=1)
            await async_wait_for(lambda: handled == [good], 30, what="the next message handled")
            await async_wait_for(lambda: endpoint.handler_failures == 20, 30, what="counted")

            def told() -> int:
                failures = [parse_failure(r.reason) for r in reports_on(probe, topics)]
                return sum(f.count for f in failures if f is not None)

            # The first at once, the rest (with their count) once its second has passed.
            await async_wait_for(lambda: told() == 20, 30, what="every failure told")
            took_s = time.monotonic() - began
        reports = reports_on(probe, topics)
        # Not 20: the first at once, then at most one a second (however slow the machine).
        assert 2 <= len(reports) <= 2 + took_s / EVERY_S, ([r.reason for r in reports], took_s)
        first = reports[0]
        assert first.topic == bad and first.header.sender == "unit1"
        assert first.reason == (
            "internal error in unit: TypeError while handling a message on this topic"
        )
        raw = b"".join(m.payload for m in probe.received(topics.fleet("errors")))
        assert SECRET.encode() not in raw and b"Traceback" not in raw and b"secret" not in raw


@pytest.mark.every_broker
async def test_a_report_that_cannot_be_made_takes_nothing_down(
    broker: BrokerThread, topics: Topics
) -> None:
    bad, good = topics.unit("order", "unit2"), topics.unit("goal", "unit2")
    handled: list[str] = []

    def report(topic: str, reason: str) -> Outbound:
        raise RuntimeError("the report itself is broken")

    async def handle(topic: str, payload: bytes) -> None:
        if topic == bad:
            raise KeyError(SECRET)
        handled.append(topic)

    endpoint = Endpoint(
        broker.url,
        f"no-report-{zlib.crc32(topics.root.encode())}",
        subscriptions=lambda: [(bad, 1), (good, 1)],
        component="unit",
        report=report,
    )
    with MqttProbe(broker.url) as probe:
        async with running(endpoint, handle):
            probe.publish(bad, b"{}", qos=1)
            probe.publish(bad, b"{}", qos=1)
            probe.publish(good, b"{}", qos=1)
            await async_wait_for(lambda: handled == [good], 30, what="still handling")
            assert endpoint.handler_failures == 2 and endpoint.online.is_set()


# ---- the whole chain: a VDA 5050 adapter failing, the metric, the alert, the unit -------------


FRAME = Frame("hall")


@pytest.mark.every_broker
async def test_a_vda_adapter_failing_on_states_is_reported_counted_alerted_and_shown(
    broker: BrokerThread, root: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    topics = Topics(root)
    grid = load_map(MAPS / "playfield.map")
    serial = f"sn-{zlib.crc32(root.encode())}"  # its topics are outside the root: its own
    vehicle = Vehicle("agv1", "gridfleet", serial, "2.1.0")
    spec = VirtualSpec(FRAME.position(grid.free_cells()[0]), FRAME.map_id, state_every_s=0.1)
    virtual = VirtualVehicleShell(vehicle, spec, broker.url)
    adapter = AdapterShell(
        [VehicleConfig(vehicle, FRAME, None, 0.0, False)], grid, broker.url, topics, step_s=0.2
    )
    coordinator = CoordinatorShell(
        broker.url,
        grid,
        root=root,
        step_s=0.2,
        db_path=tmp_path / "jobs.db",
        metrics=MetricsOptions(0),
    )
    alerts = AlertsShell(broker.url, AlertSettings(handler_failures_s=3.0), root=root)
    probe = MqttProbe(broker.url).connect()
    probe.subscribe(f"{root}/v1/#")
    stop = asyncio.Event()
    tasks = [asyncio.create_task(s.run(stop)) for s in (coordinator, alerts, adapter, virtual)]
    connection, state = topics.unit("connection", "agv1"), topics.unit("state", "agv1")

    def links() -> list[str]:
        return [decode(Connection, m.payload).state for m in probe.received(connection)]

    def states() -> list[UnitState]:
        return [decode(UnitState, m.payload) for m in probe.received(state)]

    def failures_scraped() -> float:
        assert coordinator.metrics_server is not None
        status, body = get(coordinator.metrics_server.url)
        assert status == 200, body
        return parse(body).value("gridfleet_handler_failures_total", component="vda5050")

    def alerts_in_force() -> list[tuple[str, str | None]]:
        seen = probe.received(topics.fleet("alerts"))
        if not seen:
            return []
        view = decode(AlertsView, seen[-1].payload, TOPICS["alerts"].max_bytes)
        return [(a.rule, a.subject) for a in view.active]

    try:
        await async_wait_for(lambda: links()[-1:] == ["online"], 30, what="the unit online")
        assert await asyncio.to_thread(failures_scraped) == 0  # scraped off this loop

        def broken(self: VehicleCore, message: Any, now: float) -> Any:
            raise TypeError(SECRET)

        monkeypatch.setattr(VehicleCore, "_on_state", broken)
        await async_wait_for(lambda: links()[-1:] == ["broken"], 30, what="the unit broken")
        codes = [e.code for s in states() for e in s.errors]
        assert codes.count("unreadable_state") >= UNREADABLE_STATES  # each state said so
        said = next(e for s in states() for e in s.errors if e.code == "unreadable_state")
        assert vehicle.topic("state") in said.message and "TypeError" in said.message
        reports = [r for r in reports_on(probe, topics) if r.topic == vehicle.topic("state")]
        assert reports and reports[0].reason == (
            "internal error in vda5050: TypeError while handling a message on this topic"
        )
        assert reports[0].header.sender.startswith("vda5050-")  # the adapter signs it
        raw = b"".join(m.payload for m in probe.received(topics.fleet("errors")))
        assert SECRET.encode() not in raw and b"Traceback" not in raw
        await async_wait_for(
            lambda: ("handler_failures", "vda5050") in alerts_in_force(), 30, what="the alert"
        )
        assert await asyncio.to_thread(failures_scraped) >= 1

        async def counted() -> bool:
            scraped = await asyncio.to_thread(failures_scraped)
            return scraped == adapter.endpoint.handler_failures

        monkeypatch.undo()  # the vehicle's states are read again
        await async_wait_for(lambda: links()[-1:] == ["online"], 30, what="the unit back")
        await async_wait_for(lambda: not states()[-1].errors, 30, what="a state without errors")
        # Every failure reached the metric (the last ones with the next report, a second on),
        # and the alert clears after the quiet period.
        await async_wait_for(counted, 30, what="every failure counted")
        await async_wait_for(
            lambda: ("handler_failures", "vda5050") not in alerts_in_force(), 30, what="cleared"
        )
    finally:
        stop.set()
        for task in tasks:
            await asyncio.wait_for(task, 15)
        probe.close()
