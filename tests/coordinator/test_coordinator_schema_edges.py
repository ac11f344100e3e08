"""The coordinator takes every JSON message it reads exactly as its schema allows (pure).

For each topic kind the coordinator reads (coordinator/inbound.py: the units' connection,
factsheet and state; the operators' requests and record queries), payloads are drawn from the
kind's JSON Schema (support/schema_inputs.py): valid messages, and those with one thing changed
or no JSON object at all, told apart by jsonschema's Draft 2020-12 validator. A valid one is
decoded by the coordinator's own model and handled: any refusal is for what it means (an unknown
unit, a square off the map), in one line on `errors`, and a request with a reply address gets its
reply. An invalid one is refused on `errors` with its reason and changes nothing. None makes the
core fail (it would report an internal error, not raise).
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.effects import Effects
from gridfleet.coordinator.jobs import Job
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import TOPICS as SPECS
from gridfleet.protocol import ErrorReport, Reply, decode
from gridfleet.protocol import messages as models

from support.coordinator_drive import TOPICS, make_core, request
from support.coordinator_fakes import ROOM_ROWS
from support.effects import header
from support.schema_inputs import allowed, edge_settings, parsed, payloads

GRID = GridMap.from_rows(ROOM_ROWS)
EDGE = max(GRID.width, GRID.height) + 1  # squares on the map, on walls, and just off it
UNITS = ["unit1", "unit2"]  # unit1 is known and stands on [0, 0]; unit2 is new
JOB = "job-1"  # queued for unit1 before each message

FROM_UNITS = ["connection", "factsheet", "state"]
REQUESTS = [
    "submit_job",
    "cancel_job",
    "set_goal",
    "control_unit",
    "clear_obstacles",
    "remove_unit",
    "job_history",
    "audit",
    "audit_login",
]
# Ranges of the records around the cores' clock (support.effects.FIXED), ahead of it and too long.
SINCE = [
    "2026-11-21T09:00:00Z",
    "2026-11-21T11:59:59.5+02:00",
    "2026-11-21T10:30:00Z",
    "2000-01-01T00:00:00Z",
]
UNTIL = {
    "anyOf": [{"enum": ["2026-11-21T09:30:00Z", "2026-11-21T10:00:00-01:00"]}, {"type": "null"}]
}
# Ids that name what this coordinator knows, and what it does not.
NARROW: dict[str, dict[tuple[str, ...], Any]] = {
    "cancel_job": {("properties", "job_id"): {"enum": [JOB, "job-2", "nope"]}},
    "set_goal": {("properties", "unit"): {"enum": [*UNITS, "ghost"]}},
    "control_unit": {("properties", "unit"): {"enum": [*UNITS, "ghost"]}},
    "job_history": {("properties", "since"): {"enum": SINCE}, ("properties", "until"): UNTIL},
    "audit": {("properties", "since"): {"enum": SINCE}, ("properties", "until"): UNTIL},
    "submit_job": {
        ("properties", "mass_kg"): {"type": "number", "exclusiveMinimum": 0, "maximum": 30}
    },
}

SETTINGS = edge_settings(60)


def seeded() -> CoordinatorCore:
    """A core that knows unit1 (online, 10 kg, on [0, 0]) and one queued job."""
    core = make_core(GRID, jobs=[Job(id=JOB, pickup=Cell(3, 0), dropoff=Cell(9, 9), mass_kg=1.0)])
    hdr = json.loads(header("unit1").model_dump_json())
    unit = {
        "connection": {"header": hdr, "state": "online"},
        "factsheet": {"header": hdr, "capacity_kg": 10.0, "step_period_s": 1.0},
        "state": {
            "header": hdr,
            "step": 1,
            "position": [0, 0],
            "direction": "-",
            "status": "idle",
            "leds": {},
            "sensors": {"N": "wall", "E": "free", "S": "free", "W": "wall"},
        },
    }
    for kind, message in unit.items():
        effects = core.on_message(TOPICS.unit(kind, "unit1"), json.dumps(message).encode(), 0.0)
        assert not errors_in(effects), effects
    assert core.world.units["unit1"].state is not None
    return core


def snapshot(core: CoordinatorCore) -> Any:
    """What a message may change: jobs, goals, controls, units, obstacles, the stop."""
    units = {u.id: (u.connection, u.factsheet, u.state) for u in core.world.units.values()}
    return (
        {k: v.to_dict() for k, v in core.jobs.jobs.items()},
        dict(core.directives.goals),
        dict(core.directives.controls),
        units,
        set(core.world.obstacles),
        core.estop,
    )


def errors_in(effects: Effects) -> list[ErrorReport]:
    """The error reports among what the core publishes."""
    topic = TOPICS.fleet("errors")
    return [decode(ErrorReport, o.payload) for o in effects.publish if o.topic == topic]


def check(core: CoordinatorCore, kind: str, topic: str, payload: bytes) -> None:
    """Handle one payload and hold the core to its schema's verdict on it."""
    message = parsed(payload)
    valid = allowed(kind, message)
    before = snapshot(core)
    effects = core.on_message(topic, payload, 1.0)
    reports = errors_in(effects)
    failed = [r.reason for r in reports if "internal error" in r.reason]
    assert not failed, (kind, payload, failed)
    for report in reports:
        assert report.topic == topic and report.reason and "\n" not in report.reason, report
    model = getattr(models, SPECS[kind].model or "")
    if not valid:
        assert snapshot(core) == before, (kind, payload)
        if not payload and kind in ("connection", "factsheet", "state"):
            assert not reports  # a retained message cleared (protocol.md §6.11): no message
            return
        assert len(reports) == 1, (kind, payload, reports)
        assert reports[0].reason.startswith((f"{model.__name__}: ", "malformed")), reports[0]
        return
    decoded = decode(model, payload)  # the schema allows it: the code's own model takes it
    shaped = f"{model.__name__}: field "
    assert not any(r.reason.startswith(shaped) for r in reports), (kind, payload, reports)
    reply_to = getattr(decoded, "reply_to", None)
    if reply_to is not None:
        answered(effects, kind, decoded.request_id, reply_to, reports)


def answered(
    effects: Effects, kind: str, request_id: str, reply_to: str, reports: list[ErrorReport]
) -> None:
    """A request with a reply address is answered: its reply, its page or its record query."""
    if kind in ("audit", "job_history"):
        page_model = models.AuditPage if kind == "audit" else models.JobHistoryPage
        at = TOPICS.audit_reply(reply_to) if kind == "audit" else TOPICS.history_reply(reply_to)
        pages = [decode(page_model, o.payload) for o in effects.publish if o.topic == at]
        if not pages:  # accepted: the shell answers it from its store
            assert [r.query.request_id for r in effects.records] == [request_id], effects
            return
        (page,) = pages
        assert page.request_id == request_id and not page.accepted and page.reason, page
        assert any(page.reason in r.reason for r in reports), (page, reports)
        return
    at = TOPICS.reply(reply_to)
    (reply,) = [decode(Reply, o.payload) for o in effects.publish if o.topic == at]
    assert reply.request_id == request_id
    if not reply.accepted:  # refused for what it means: said on the reply and on `errors`
        assert reply.reason and any(reply.reason in r.reason for r in reports), (reply, reports)


@pytest.mark.parametrize("kind", FROM_UNITS)
def test_what_units_say_is_taken_as_its_schema_allows(kind: str) -> None:
    @SETTINGS
    @given(payload=payloads(kind, max_coord=EDGE), unit=st.sampled_from(UNITS))
    def run(payload: bytes, unit: str) -> None:
        check(seeded(), kind, TOPICS.unit(kind, unit), payload)

    run()


@pytest.mark.parametrize("kind", REQUESTS)
def test_each_request_is_taken_as_its_schema_allows(kind: str) -> None:
    @SETTINGS
    @given(payload=payloads(kind, max_coord=EDGE, narrow=NARROW.get(kind)))
    def run(payload: bytes) -> None:
        check(seeded(), kind, TOPICS.request(kind), payload)

    run()


def test_a_request_with_no_json_in_it_is_refused_in_words() -> None:
    core = seeded()
    effects = request(core, "submit_job", b"{", 1.0)
    (report,) = errors_in(effects)
    assert report.reason.startswith("SubmitJob: malformed JSON")
