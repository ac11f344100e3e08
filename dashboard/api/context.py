"""What every route of the API shares: its settings, who calls, and the way to the fleet."""

from __future__ import annotations

import threading
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TypeVar

from flask import current_app, g

from gridfleet.dashboard.api.fleet import FleetClients, FleetView, guarded, require_online
from gridfleet.dashboard.api.identity import Caller, Identity, Need
from gridfleet.dashboard.api.problems import ApiProblem

T = TypeVar("T")
EXTENSION = "gridfleet_api"
PREFIX = "/api/v1"


@dataclass(frozen=True)
class ApiConfig:
    """The API's waits and bounds."""

    request_s: float = 10.0  # for the coordinator's reply to one request (re-sent meanwhile)
    connect_s: float = 5.0  # for the account's connection to the broker, at its first use
    view_s: float = 5.0  # for a view to show what an accepted request changed
    heartbeat_s: float = 15.0  # between an event stream's heartbeats
    stream_s: float = 3600.0  # an event stream's longest life (it resumes with Last-Event-ID)
    max_streams: int = 16  # event streams open at once
    retry_s: float = 2.0  # the first wait before a request is sent again (it doubles)


class ApiContext:
    """The API's shared parts, kept in the app (`current()`)."""

    def __init__(self, config: ApiConfig, identity: Identity, clients: FleetClients) -> None:
        self.config = config
        self.identity = identity
        self.clients = clients
        self.streams = threading.BoundedSemaphore(config.max_streams)

    def run(
        self,
        caller: Caller,
        work: Callable[[FleetView], Awaitable[T]],
        *,
        online: bool = False,
    ) -> T:
        """`work` on the caller's own connection (503 without one; with `online`, also
        without a coordinator online), its answer, or its problem."""
        config = self.config
        link = self.clients.link(caller.name, caller.password)

        async def go() -> T:
            view = await link.ready(config.connect_s)
            if online:
                await require_online(view)
            return await guarded(work(view))

        bound = config.connect_s + config.request_s + config.view_s + 5.0
        return self.clients.run(go(), bound)


def current() -> ApiContext:
    """The API's context in the app serving this request."""
    context = current_app.extensions[EXTENSION]
    assert isinstance(context, ApiContext)
    return context


def caller(need: Need = "read") -> Caller:
    """This request's caller (found before the route ran), if it may do what `need` names."""
    found = g.get("api_caller")
    if not isinstance(found, Caller):
        raise ApiProblem("unauthorized", "no caller found for this request")
    found.require(need)
    return found
