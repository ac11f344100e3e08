"""`/units`: every unit, one unit, and an operator's control of one (pause, resume, out of
service, in service, charge)."""

from __future__ import annotations

from flask import Response

from gridfleet.dashboard.api.context import caller, current
from gridfleet.dashboard.api.fleet import FleetView
from gridfleet.dashboard.api.models import Accepted, ControlRequest, UnitsList, UnitView
from gridfleet.dashboard.api.params import UnitPath
from gridfleet.dashboard.api.problems import ApiProblem, accepted
from gridfleet.dashboard.api.web import also, answer, blueprint

api = blueprint("units", "the units: their state, factsheet, control, battery and route")
NAMED_AT_MOST = 20  # units a 404 names


def unknown_unit(view: FleetView, unit: str) -> ApiProblem:
    """404 for a unit the views do not know, naming some they do."""
    known = view.unit_ids()
    named = ", ".join(known[:NAMED_AT_MOST]) or "none"
    more = f" (and {len(known) - NAMED_AT_MOST} more)" if len(known) > NAMED_AT_MOST else ""
    return ApiProblem("unknown_unit", f"unknown unit {unit!r}: the units are {named}{more}")


@api.get("/units", summary="Every unit the fleet's views know", responses={200: UnitsList})
def list_units() -> Response:
    """Each unit's connection, state, factsheet, control, battery and route note."""
    who = caller("read")

    async def work(view: FleetView) -> UnitsList:
        units = [view.unit(u) for u in view.unit_ids()]
        return UnitsList(units=[u for u in units if u is not None])

    return answer(current().run(who, work))


@api.get("/units/<unit_id>", summary="One unit", responses={200: UnitView, **also(404)})
def get_unit(path: UnitPath) -> Response:
    """Its state, factsheet, control (paused, out of service), battery and route note."""
    who = caller("read")

    async def work(view: FleetView) -> UnitView:
        unit = view.unit(path.unit_id)
        if unit is None:
            raise unknown_unit(view, path.unit_id)
        return unit

    return answer(current().run(who, work))


@api.post(
    "/units/<unit_id>/control",
    summary="Pause or resume a unit, take it out of service or back, or send it to charge",
    responses={200: Accepted, **also(404, 409, 422)},
)
def control_unit(path: UnitPath, body: ControlRequest) -> Response:
    """protocol.md §6.4: refused for an unknown unit (404), or a command its state refuses."""
    who = caller("change")
    config = current().config

    async def work(view: FleetView) -> Accepted:
        reply = accepted(await view.control_unit(path.unit_id, body.command, config.request_s))
        return Accepted(reason=reply.reason, job_id=reply.job_id)

    return answer(current().run(who, work, online=True))
