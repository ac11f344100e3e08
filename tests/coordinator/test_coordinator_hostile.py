"""Malformed and hostile messages on every topic the coordinator reads: refused, nothing changes."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.grid import GridMap
from gridfleet.protocol import ErrorReport, Reply, Topics, decode
from gridfleet.system.broker_thread import BrokerThread

from support.wait import async_wait_for

pytestmark = (
    pytest.mark.every_broker
)  # oversized and malformed payloads meet the broker's limits first

GRID = GridMap.from_rows(["....", ".@..", "...."])
TOPICS = Topics("fuzz")
HDR = {"version": "1.6", "seq": 0, "timestamp": "2026-11-21T10:00:00Z", "sender": "unit1"}
READ_TOPICS = [
    TOPICS.unit("connection", "unit1"),
    TOPICS.unit("factsheet", "unit1"),
    TOPICS.unit("state", "unit1"),
    TOPICS.fleet("estop"),
    TOPICS.request("submit_job"),
    TOPICS.request("cancel_job"),
    TOPICS.request("set_goal"),
]


def state_payload(**over: Any) -> bytes:
    msg = {
        "header": HDR,
        "step": 1,
        "position": [0, 0],
        "direction": "-",
        "status": "idle",
        "leds": {},
        "sensors": {"N": "wall", "E": "free", "S": "free", "W": "wall"},
    }
    msg.update(over)
    return json.dumps(msg).encode()


def coordinator(db: str | Path) -> CoordinatorShell:
    return CoordinatorShell("mqtt://127.0.0.1:1", GRID, root="fuzz", step_s=0.05, db_path=db)


def snapshot(c: CoordinatorShell) -> Any:
    units = {u.id: (u.connection, u.factsheet, u.state) for u in c.world.units.values()}
    return (
        {k: v.to_dict() for k, v in c.core.jobs.jobs.items()},
        dict(c.core.directives.goals),
        units,
        set(c.world.obstacles),
        c.core.estop,
    )


async def seeded(db: str | Path) -> CoordinatorShell:
    """A coordinator that knows one unit and one job."""
    c = coordinator(db)
    conn = {"header": HDR, "state": "online"}
    await c.handle(TOPICS.unit("connection", "unit1"), json.dumps(conn).encode())
    fs = {"header": HDR, "capacity_kg": 5.0, "step_period_s": 0.05}
    await c.handle(TOPICS.unit("factsheet", "unit1"), json.dumps(fs).encode())
    await c.handle(TOPICS.unit("state", "unit1"), state_payload())
    sub = {"header": HDR, "request_id": "r", "pickup": [3, 0], "dropoff": [3, 2], "mass_kg": 1.0}
    await c.handle(TOPICS.request("submit_job"), json.dumps(sub).encode())
    await c.answer_waiting()
    assert len(c.core.jobs.jobs) == 1 and c.world.units["unit1"].state is not None
    return c


HOSTILE: list[tuple[str, bytes]] = [
    (TOPICS.unit("state", "unit1"), state_payload(position=[50, 50])),  # off the map
    (TOPICS.unit("state", "unit1"), state_payload(position=[1, 1])),  # on a wall
    (TOPICS.unit("state", "unit1"), state_payload(position=[-1, 0])),
    (TOPICS.unit("state", "unit1"), state_payload(step="1")),  # wrong type
    (TOPICS.unit("state", "unit1"), state_payload(extra=1)),  # unknown field
    (TOPICS.unit("state", "unit1"), state_payload(obstacles=[[0, 1]] * 5)),  # too many
    (TOPICS.unit("state", "unit1"), state_payload(header={**HDR, "version": "9.9"})),
    (
        TOPICS.unit("connection", "unit1"),
        b'{"header": %s, "state": "maybe"}' % json.dumps(HDR).encode(),
    ),
    (
        TOPICS.unit("factsheet", "unit1"),
        b'{"header": %s, "capacity_kg": -1, "step_period_s": 1}' % json.dumps(HDR).encode(),
    ),
    (TOPICS.fleet("estop"), b"maybe|x|y"),
    (TOPICS.fleet("estop"), b"engaged|bad/id|x"),
    (TOPICS.fleet("estop"), b"engaged|x|" + b"r" * 600),
    (TOPICS.fleet("estop"), b"\xff\xfe"),
    (
        TOPICS.request("submit_job"),
        json.dumps(
            {"header": HDR, "request_id": "a", "pickup": [9, 9], "dropoff": [0, 0], "mass_kg": 1}
        ).encode(),
    ),
    (
        TOPICS.request("submit_job"),
        json.dumps(
            {"header": HDR, "request_id": "a", "pickup": [1, 1], "dropoff": [0, 0], "mass_kg": 1}
        ).encode(),
    ),
    (
        TOPICS.request("submit_job"),
        json.dumps(
            {"header": HDR, "request_id": "a", "pickup": [0, 0], "dropoff": [2, 0], "mass_kg": 0}
        ).encode(),
    ),
    (
        TOPICS.request("submit_job"),
        json.dumps(
            {
                "header": HDR,
                "request_id": "a",
                "pickup": [0, 0],
                "dropoff": [2, 0],
                "mass_kg": 1,
                "job_id": "job-1",
            }
        ).encode(),
    ),
    (
        TOPICS.request("cancel_job"),
        json.dumps({"header": HDR, "request_id": "a", "job_id": "nope"}).encode(),
    ),
    (
        TOPICS.request("set_goal"),
        json.dumps({"header": HDR, "request_id": "a", "unit": "ghost", "target": [0, 0]}).encode(),
    ),
    (
        TOPICS.request("set_goal"),
        json.dumps({"header": HDR, "request_id": "a", "unit": "unit1", "target": [1, 1]}).encode(),
    ),
    (TOPICS.request("submit_job"), b"{" * 20000),  # oversized
    (TOPICS.request("submit_job"), b"\x00\x01"),
]


@pytest.mark.parametrize(("topic", "payload"), HOSTILE)
async def test_each_hostile_message_is_refused_and_changes_nothing(
    tmp_path: Path, topic: str, payload: bytes
) -> None:
    c = await seeded(tmp_path / "db")
    before = snapshot(c)
    errors = c.errors_sent
    await c.handle(topic, payload)
    await c.answer_waiting()
    assert snapshot(c) == before
    assert c.errors_sent == errors + 1


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4)
    ),
    max_leaves=12,
)


@st.composite
def near_valid(draw: st.DrawFn) -> bytes:
    """A valid-looking message with one field replaced by something random."""
    base = json.loads(state_payload())
    key = draw(st.sampled_from([*base.keys(), "request_id", "mass_kg", "pickup", "job_id"]))
    base[key] = draw(json_values)
    return json.dumps(base).encode()


payloads = st.one_of(
    st.binary(max_size=200),
    json_values.map(lambda v: json.dumps(v).encode()),
    near_valid(),
)


@settings(
    max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(topic=st.sampled_from(READ_TOPICS), payload=payloads)
def test_fuzz_every_topic_changes_nothing_and_never_raises(topic: str, payload: bytes) -> None:
    # The stores in memory: 300 coordinators each making their tables on disk spent a CI run's
    # minute waiting for the disk (fsync), not fuzzing.
    async def go() -> None:
        c = await seeded(":memory:")
        before = snapshot(c)
        await c.handle(topic, payload)
        await c.answer_waiting()
        after = snapshot(c)
        # A random payload may, very rarely, be a valid message: then it must be one.
        if after != before:
            assert topic.endswith("/state"), (topic, payload)
        for store in (c.store, c.audit_store, c.history):
            store.close()

    asyncio.run(go())


async def test_service_keeps_running_and_answers_after_garbage(
    broker: BrokerThread, root: str, tmp_path: Path
) -> None:
    from support.probe import MqttProbe

    topics = Topics(root)
    c = CoordinatorShell(broker.url, GRID, root=root, step_s=0.02, db_path=tmp_path / "db")
    stop = asyncio.Event()
    task = asyncio.create_task(c.run(stop))
    await asyncio.wait_for(c.ready.wait(), 10)
    probe = MqttProbe(broker.url, "hostile").connect()
    probe.subscribe(topics.fleet("errors"), qos=1)
    probe.subscribe(topics.reply("hostile"), qos=1)
    try:
        garbage = [b"", b"{", b"\xff" * 10, b"x" * 70000, b'{"header": null}']
        sent = 0
        for kind in ("connection", "factsheet", "state"):
            for g in garbage[1:]:  # an empty one there is a clear: no message, nothing refused
                probe.publish(topics.unit(kind, "unit1"), g)
                sent += 1
        for kind in ("submit_job", "cancel_job", "set_goal"):
            for g in garbage:
                probe.publish(topics.request(kind), g)
                sent += 1
        probe.publish(topics.fleet("estop"), b"nonsense")
        sent += 1
        await async_wait_for(
            lambda: len(probe.received(topics.fleet("errors"))) >= sent, what="every refusal"
        )
        report = decode(ErrorReport, probe.received(topics.fleet("errors"))[0].payload)
        assert report.topic.startswith(topics.prefix)
        # Still alive: a valid request gets a reply.
        hdr = {**HDR, "sender": "hostile"}
        req = {
            "header": hdr,
            "request_id": "ok",
            "reply_to": "hostile",
            "pickup": [0, 0],
            "dropoff": [3, 2],
            "mass_kg": 1.0,
        }
        probe.publish(topics.request("submit_job"), json.dumps(req).encode())
        await async_wait_for(lambda: c.core.jobs.jobs, what="job accepted")
        # Awaited, not probe.wait(): that would hold up this loop, the coordinator's, and its reply.
        replies = await async_wait_for(
            lambda: probe.received(topics.reply("hostile")), what="reply"
        )
        assert decode(Reply, replies[0].payload).accepted
        assert not task.done()
    finally:
        probe.close()
        stop.set()
        await task
