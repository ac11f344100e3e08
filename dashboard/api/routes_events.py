"""`/events`: the fleet's changes pushed as server-sent events (events.py says which).

A stream sends a heartbeat comment every `heartbeat_s`, ends after `stream_s` (a client's
EventSource reconnects, sending its Last-Event-ID, and goes on where it was), and at most
`max_streams` are open at once (429 beyond). A Last-Event-ID that cannot be resumed (from
before a restart of the dashboard, or pushed out) gets an event `reset` first: read the views
again (GET /jobs, /zones, /stop), then follow the stream.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator

from flask import Response

from gridfleet.dashboard.api.context import caller, current
from gridfleet.dashboard.api.events import HEARTBEAT, EventLog, sse
from gridfleet.dashboard.api.fleet import FleetView
from gridfleet.dashboard.api.params import EventsHeaders
from gridfleet.dashboard.api.problems import ApiProblem
from gridfleet.dashboard.api.web import blueprint

api = blueprint("events", "the fleet's changes, pushed: server-sent events")
STREAM_RETRY_MS = 3000  # how long a client's EventSource waits before it reconnects
BUSY_RETRY_S = 30
RESET = json.dumps(
    {"reason": "the stream cannot go on from that Last-Event-ID: read the views again"}
)


def stream(
    events: EventLog,
    start: int | None,
    heartbeat_s: float,
    life_s: float,
    slot: threading.BoundedSemaphore,
) -> Iterator[str]:
    """The text of one stream: a `reset` if it cannot resume, then each event as it comes;
    its slot among the streams given back when it ends."""
    try:
        yield f"retry: {STREAM_RETRY_MS}\n\n"
        position = start
        if position is None:
            position = events.last
            yield sse(f"{events.run}-{position}", "reset", RESET)
        ends = time.monotonic() + life_s
        while (left := ends - time.monotonic()) > 0:
            found = events.after(position, min(heartbeat_s, left))
            if not found:
                yield HEARTBEAT
                continue
            for event in found:
                yield sse(events.event_id(event), event.kind, event.data)
                position = event.number
    finally:
        slot.release()


@api.get(
    "/events",
    summary="Server-sent events: job, zone, stop and coordinator changes",
    responses={
        200: {
            "description": "a stream of events (text/event-stream)",
            "content": {"text/event-stream": {"schema": {"type": "string"}}},
        }
    },
)
def follow_events(header: EventsHeaders) -> Response:
    """Each event's `data` is JSON: a JobView (job), a ZoneEvent (zone), a StopState (stop),
    a CoordinatorStatus (coordinator)."""
    who = caller("read")
    context = current()
    config = context.config
    link = context.clients.link(who.name, who.password)

    async def connected(view: FleetView) -> None:
        return None

    context.run(who, connected)  # 503 now, not in the stream, when there is no broker
    if not context.streams.acquire(blocking=False):
        raise ApiProblem(
            "too_many_streams",
            f"all {config.max_streams} event streams are open: try again later",
            retry_after=BUSY_RETRY_S,
        )
    start = link.events.resume_from(header.last_event_id)
    body = stream(link.events, start, config.heartbeat_s, config.stream_s, context.streams)
    response = Response(body, mimetype="text/event-stream")
    response.headers["Cache-Control"] = "no-store"
    response.headers["X-Accel-Buffering"] = "no"  # a proxy in front: pass each event at once
    return response
