"""`/coordinator`: whether the coordinator runs, as its retained status says (a health check)."""

from __future__ import annotations

from flask import Response

from gridfleet.dashboard.api.context import caller, current
from gridfleet.dashboard.api.fleet import FleetView
from gridfleet.dashboard.api.problems import ApiProblem
from gridfleet.dashboard.api.web import answer, blueprint
from gridfleet.protocol import CoordinatorStatus

api = blueprint("coordinator", "the coordinator's status")


@api.get(
    "/coordinator",
    summary="The coordinator's status: online, offline or broken, its step and its stop",
    responses={200: CoordinatorStatus},
)
def coordinator_status() -> Response:
    """503 when no coordinator has ever said anything under this topic root."""
    who = caller("read")

    async def work(view: FleetView) -> CoordinatorStatus:
        if view.coordinator is None:
            raise ApiProblem(
                "not_online",
                f"no coordinator has said it runs under root {view.topics.root!r}: is it started?",
            )
        return view.coordinator

    return answer(current().run(who, work))
