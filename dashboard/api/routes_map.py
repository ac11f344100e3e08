"""`/places` and `/zones`: the map's named places; the zones closed, closing one, opening one."""

from __future__ import annotations

from flask import Response

from gridfleet.dashboard.api.context import PREFIX, caller, current
from gridfleet.dashboard.api.fleet import FleetView
from gridfleet.dashboard.api.models import Accepted, PlacesList, ZoneRequest, ZonesList
from gridfleet.dashboard.api.params import ZonePath
from gridfleet.dashboard.api.problems import ApiProblem, accepted
from gridfleet.dashboard.api.web import also, answer, blueprint
from gridfleet.protocol.messages import Zone

api = blueprint("map", "the map's named places, and zones closed to the units")


def closed_zone(view: FleetView, name: str) -> Zone | None:
    """Zone `name` as the zones view shows it (None: not closed)."""
    zones = [] if view.zones is None else view.zones.zones
    return next((z for z in zones if z.name == name), None)


@api.get("/places", summary="The map's named places", responses={200: PlacesList})
def list_places() -> Response:
    """Each place's name, square and kinds (pickup, dropoff, charger, parking)."""
    who = caller("read")

    async def work(view: FleetView) -> PlacesList:
        if view.fleet_map is None:
            raise ApiProblem("not_online", "no map on the broker yet: is the coordinator running?")
        return PlacesList(places=view.fleet_map.places)

    return answer(current().run(who, work))


@api.get(
    "/zones",
    summary="The zones closed now, in the order they were closed",
    responses={200: ZonesList},
)
def list_zones() -> Response:
    """Who closed each, when, and why."""
    who = caller("read")

    async def work(view: FleetView) -> ZonesList:
        return ZonesList(zones=[] if view.zones is None else view.zones.zones)

    return answer(current().run(who, work))


@api.put(
    "/zones/<name>",
    summary="Close a zone: no unit is sent into it, one inside leaves it",
    responses={200: Zone, **also(409, 422)},
)
def close_zone(path: ZonePath, body: ZoneRequest) -> Response:
    """The same rectangle and reason again is accepted and changes nothing; another, while it
    is closed, is refused (409: open it first)."""
    who = caller("change")
    config = current().config

    async def work(view: FleetView) -> Zone:
        accepted(
            await view.close_zone(path.name, body.first, body.last, body.reason, config.request_s)
        )
        shown = await view.until(lambda: closed_zone(view, path.name), config.view_s)
        if shown is None:
            raise ApiProblem(
                "no_reply",
                f"zone {path.name} was closed, but the zones view has not shown it within "
                f"{config.view_s:g} s: GET {PREFIX}/zones",
            )
        return shown

    return answer(current().run(who, work, online=True))


@api.delete(
    "/zones/<name>", summary="Open a closed zone again", responses={200: Accepted, **also(404, 422)}
)
def open_zone(path: ZonePath) -> Response:
    """A zone that is not closed is refused (404), naming those that are."""
    who = caller("change")
    config = current().config

    async def work(view: FleetView) -> Accepted:
        reply = accepted(await view.open_zone(path.name, config.request_s))
        await view.until(lambda: closed_zone(view, path.name) is None or None, config.view_s)
        return Accepted(reason=reply.reason)

    return answer(current().run(who, work, online=True))
