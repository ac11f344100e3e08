"""`/stop`: the emergency stop read, engaged (latched), and released by an operator.

Engaging and releasing are `gridfleet job stop` and `release` themselves (console/job.py), their
words the answer's `message`: a latch already engaged is left as it was; a press the latch does
not hold yet is waited for; a press no coordinator can clear keeps the fleet stopped (409).
"""

from __future__ import annotations

import io

from flask import Response

from gridfleet.console.job import engage, release
from gridfleet.dashboard.api.context import caller, current
from gridfleet.dashboard.api.events import stop_state
from gridfleet.dashboard.api.fleet import FleetView
from gridfleet.dashboard.api.models import StopRequest, StopState
from gridfleet.dashboard.api.params import ReleaseQuery
from gridfleet.dashboard.api.problems import ApiProblem
from gridfleet.dashboard.api.web import also, answer, blueprint

api = blueprint("stop", "the fleet-wide emergency stop")


@api.get(
    "/stop", summary="The emergency stop: the latch and every press", responses={200: StopState}
)
def get_stop() -> Response:
    """The fleet is stopped while the latch or any press holds it (protocol.md §5.1)."""
    who = caller("read")

    async def work(view: FleetView) -> StopState:
        await view.stop_as_kept()
        return stop_state(view.stop, view.coordinator)

    return answer(current().run(who, work))


@api.post("/stop", summary="Engage the emergency stop (latched)", responses={200: StopState})
def engage_stop(body: StopRequest) -> Response:
    """Every unit stops within a step; only an operator's release lets them go on."""
    who = caller("change")
    config = current().config

    async def work(view: FleetView) -> StopState:
        said = io.StringIO()
        await engage(view, body.reason, said)
        await view.until(lambda: view.stop.latch_engaged or None, config.view_s)
        return stop_state(view.stop, view.coordinator, said.getvalue().strip())

    return answer(current().run(who, work))


@api.delete(
    "/stop",
    summary="Release the emergency stop (an operator account only)",
    responses={200: StopState, **also(409)},
)
def release_stop(query: ReleaseQuery) -> Response:
    """A deliberate act of an operator: never a viewer's, nor a dashboard account's token."""
    who = caller("release")
    config = current().config

    async def work(view: FleetView) -> StopState:
        said = io.StringIO()
        code = await release(view, query.reason, config.view_s, said)
        words = said.getvalue().strip()
        if code != 0:
            raise ApiProblem("conflict", words)
        await view.until(lambda: (not view.stop.latch_engaged) or None, config.view_s)
        return stop_state(view.stop, view.coordinator, words)

    return answer(current().run(who, work))
