"""The coordinator takes every JSON message it reads exactly as its schema allows (pure).

For each topic kind the coordinator reads (coordinator/inbound.py: the units' connection,
factsheet and state; the operators' requests and record queries), payloads are drawn from the
kind's JSON Schema (support/schema_inputs.py): valid messages, and those with one thing changed
or no JSON object at all, told apart by jsonschema's Draft 2020-12 validator. A valid one is
decoded by the coordinator's own model and handled: any refusal is for what it means (an unknown
unit, a square off the map), in one line on `errors`, and a request with a reply address gets its
reply. An invalid one is refused on `errors` with its reason and changes nothing. None makes the
core fail (it would report an internal error, not raise). Closing and opening a zone (protocol.md
§6.12, §6.13) is held to what the protocol says it comes to, zone by zone, and to nothing else.
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.effects import Effects
from gridfleet.coordinator.jobs import Job
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import TOPICS as SPECS
from gridfleet.protocol import ErrorReport, Reply, ZonesView, decode
from gridfleet.protocol import messages as models

from support.coordinator_drive import TOPICS, make_core, request
from support.coordinator_fakes import ROOM_ROWS
from support.effects import header
from support.schema_inputs import allowed, edge_settings, generation_schema, parsed, payloads

GRID = GridMap.from_rows(ROOM_ROWS)
EDGE = max(GRID.width, GRID.height) + 1  # squares on the map, on walls, and just off it
UNITS = ["unit1", "unit2"]  # unit1 is known and stands on [0, 0]; unit2 is new
JOB = "job-1"  # queued for unit1 before each message
ZONE = "aisle-4"  # closed before each message, its corners given the other way round
ZONE_AS_ASKED = {"name": ZONE, "first": [5, 4], "last": [3, 1], "reason": "cleaning"}

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
    "close_zone",
    "open_zone",
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


def or_known(kind: str, field: str, known: list[Any]) -> dict[str, Any]:
    """`field` of `kind` as its schema allows (squares near the map), or one of `known`."""
    drawn = generation_schema(kind, max_coord=EDGE)["properties"][field]
    return {"anyOf": [{"enum": known}, drawn]}


# The zone closed, another name, the longest name; its corners (as asked, in order) and squares
# just off the map.
ZONE_NAMES = [ZONE, "dock", "z" * 64]
CORNERS = [[5, 4], [3, 1], [GRID.width, 0], [0, GRID.height]]
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
    "close_zone": {
        ("properties", "name"): {"enum": ZONE_NAMES},
        ("properties", "first"): or_known("close_zone", "first", CORNERS),
        ("properties", "last"): or_known("close_zone", "last", CORNERS),
        ("properties", "reason"): or_known("close_zone", "reason", ["cleaning", "spill"]),
    },
    "open_zone": {("properties", "name"): {"enum": ZONE_NAMES}},
}

SETTINGS = edge_settings(60)


def asked(kind: str, **fields: Any) -> bytes:
    """A request of `kind` from an operator's console, with a reply address."""
    hdr = json.loads(header("operator-cli-1").model_dump_json())
    sent = {"header": hdr, "request_id": "r-1", "reply_to": "operator-cli-1", **fields}
    return json.dumps(sent).encode()


# What the draws seldom hit, always tried too: the zone closed again as it was (its corners either
# way round), closed otherwise, a corner off the map, a zone over the unit and the job's pickup;
# the zone opened, and one not closed.
ZONE_CASES = {
    "close_zone": [
        asked("close_zone", **ZONE_AS_ASKED),
        asked("close_zone", **ZONE_AS_ASKED | {"first": [3, 1], "last": [5, 4]}),
        asked("close_zone", **ZONE_AS_ASKED | {"reason": "spill"}),
        asked("close_zone", **ZONE_AS_ASKED | {"name": "dock", "last": [3, GRID.height]}),
        asked("close_zone", name="dock", first=[0, 0], last=[3, 0], reason="spill"),
    ],
    "open_zone": [asked("open_zone", name=ZONE), asked("open_zone", name="dock")],
}


def seeded() -> CoordinatorCore:
    """A core that knows unit1 (online, 10 kg, on [0, 0]), one queued job and one closed zone."""
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
    closing = {"header": hdr | {"sender": "operator"}, "request_id": "seeded-zone", **ZONE_AS_ASKED}
    effects = core.on_message(TOPICS.request("close_zone"), json.dumps(closing).encode(), 0.0)
    assert not errors_in(effects) and list(core.zones.zones) == [ZONE], effects
    return core


def snapshot(core: CoordinatorCore) -> Any:
    """What a message may change: jobs, goals, controls, units, obstacles, the stop, the zones
    (last: those closed, in order, and those kept that are not on the map)."""
    units = {u.id: (u.connection, u.factsheet, u.state) for u in core.world.units.values()}
    return (
        {k: v.to_dict() for k, v in core.jobs.jobs.items()},
        dict(core.directives.goals),
        dict(core.directives.controls),
        units,
        set(core.world.obstacles),
        core.estop,
        (list(core.zones.zones.values()), list(core.zones.ignored)),
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
    if isinstance(decoded, models.CloseZone | models.OpenZone):
        zoned(core, decoded, before, effects, reports)
    else:  # only closing and opening change the zones
        assert snapshot(core)[-1] == before[-1], (kind, payload)


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


def zoned(
    core: CoordinatorCore,
    req: models.CloseZone | models.OpenZone,
    before: Any,
    effects: Effects,
    reports: list[ErrorReport],
) -> None:
    """A valid close_zone or open_zone comes to what protocol.md §6.12 and §6.13 say, from the
    zones closed `before`: refused with its code, or the zone closed (or opened) and the view out
    before the reply; nothing but the zones changes, and they only when accepted and new."""
    closed = {z.name: z for z in before[-1][0]}
    known = closed.get(req.name)
    if isinstance(req, models.CloseZone):
        first = Cell(min(req.first.x, req.last.x), min(req.first.y, req.last.y))
        last = Cell(max(req.first.x, req.last.x), max(req.first.y, req.last.y))
        wanted = (first, last, req.reason)
        as_asked = known is not None and (known.first, known.last, known.reason) == wanted
        if not all(GRID.in_bounds(c) for c in (req.first, req.last)):
            code: str | None = "bad_square"
        elif known is not None and not as_asked:
            code = "conflict"
        else:
            code = None
        changes = code is None and known is None
    else:
        code = None if known is not None else "unknown_zone"
        changes = code is None
    after = snapshot(core)
    assert after[:-1] == before[:-1], (req, after, before)  # nothing but the zones
    if code is not None:
        assert after == before and len(reports) == 1, (req, reports)
        assert reports[0].reason.startswith(f"{type(req).__name__}: zone "), reports
    else:
        assert not reports, (req, reports)
    now = {z.name: z for z in after[-1][0]}
    if not changes:
        assert now == closed, (req, now, closed)
    elif isinstance(req, models.CloseZone):
        assert list(now) == [*closed, req.name], (req, now)
        zone = now[req.name]
        assert (zone.first, zone.last, zone.reason) == (first, last, req.reason), zone
        assert zone.closed_by == req.header.sender, zone
    else:
        assert list(now) == [n for n in closed if n != req.name], (req, now)
    views = [i for i, o in enumerate(effects.publish) if o.topic == TOPICS.fleet("zones")]
    assert len(views) == (1 if changes else 0), (req, effects.publish)
    for i in views:
        out = effects.publish[i].payload
        assert allowed("zones", json.loads(out)), out  # what the page and the API read
        assert decode(ZonesView, out).zones == list(now.values()), out
    if req.reply_to is None:
        return
    at = TOPICS.reply(req.reply_to)
    (i,) = [i for i, o in enumerate(effects.publish) if o.topic == at]
    reply = decode(Reply, effects.publish[i].payload)
    assert reply.accepted == (code is None) and reply.code == code, (req, reply)
    assert reply.reason and req.name in reply.reason, reply
    assert all(v < i for v in views), effects.publish  # the view first: the requester reads it


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

    for case in ZONE_CASES.get(kind, []):
        run = example(payload=case)(run)
    run()


def test_a_request_with_no_json_in_it_is_refused_in_words() -> None:
    core = seeded()
    effects = request(core, "submit_job", b"{", 1.0)
    (report,) = errors_in(effects)
    assert report.reason.startswith("SubmitJob: malformed JSON")
