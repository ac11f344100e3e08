"""What `GET /events` tells: the changes of the fleet's views, numbered for Last-Event-ID.

Server-sent events rather than webhooks: the site's server then opens no connection to an
address a token holder names (no SSRF), a stream is authenticated like any request, and one that
broke goes on from its `Last-Event-ID`. `ChangeTracker` (pure) finds what changed from one view
to the next; `EventLog` keeps the latest events of one account's link, numbered, for the streams
(thread-safe: the links run in the API's event loop, the streams in the server's threads).

Events: `job` (a job's state, unit or reason to wait changed, or it is new: data a JobView),
`zone` (closed or opened: a ZoneEvent), `stop` (the stop engaged, released, or its cause
changed: a StopState) and `coordinator` (its state or its stop changed: a CoordinatorStatus).
The first view after a start is the baseline: no event for what already was.
"""

from __future__ import annotations

import secrets
import threading
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

from pydantic import BaseModel

from gridfleet.dashboard.api.models import StopSignal, StopState, ZoneEvent
from gridfleet.protocol import CoordinatorStatus, EstopSignal, JobsView
from gridfleet.protocol.messages import ZonesView
from gridfleet.protocol.stop import StopView

KEPT = 2000  # events one link keeps for streams that resume
EVENT_KINDS = ("job", "zone", "stop", "coordinator")


def signal(s: EstopSignal) -> StopSignal:
    """A latch or press as the API shows it."""
    return StopSignal(engaged=s.engaged, by=s.by, reason=s.reason)


def stop_state(
    stop: StopView, coordinator: CoordinatorStatus | None, message: str | None = None
) -> StopState:
    """The stop as the API shows it."""
    return StopState(
        engaged=stop.engaged,
        latch=None if stop.latch is None else signal(stop.latch),
        presses=[signal(p) for p in stop.presses.values()],
        coordinator_stopped=coordinator is not None
        and coordinator.state == "online"
        and coordinator.estop,
        message=message,
    )


class ChangeTracker:
    """The last view of each kind seen, and what a new one changed (pure)."""

    def __init__(self) -> None:
        self._jobs: dict[str, tuple[str, str | None, str | None]] | None = None
        self._zones: dict[str, str] | None = None
        self._stop: tuple[bool, str | None] | None = None
        self._coordinator: tuple[str, bool] | None = None

    def baseline(
        self,
        jobs: JobsView | None,
        zones: ZonesView | None,
        stop: StopView,
        coordinator: CoordinatorStatus | None,
    ) -> None:
        """Take the views as they are as the start: what changes from here on is an event."""
        if jobs is not None:
            self.jobs(jobs)
        self.zones(zones)
        self.stop(stop, coordinator)
        self.coordinator(coordinator)

    def jobs(self, view: JobsView) -> list[tuple[str, BaseModel]]:
        """A `job` event for each listed job that is new or whose state, unit or wait changed."""
        now: dict[str, tuple[str, str | None, str | None]] = {
            j.id: (j.state, j.unit, j.wait) for j in view.listed()
        }
        before, self._jobs = self._jobs, now
        if before is None:
            return []
        return [("job", j) for j in view.listed() if before.get(j.id) != now[j.id]]

    def zones(self, view: ZonesView | None) -> list[tuple[str, BaseModel]]:
        """A `zone` event for each zone closed (or closed anew) and each opened."""
        zones = [] if view is None else view.zones
        now = {z.name: z.model_dump_json() for z in zones}
        before, self._zones = self._zones, now
        if before is None:
            return []
        out: list[tuple[str, BaseModel]] = [
            ("zone", ZoneEvent(name=z.name, state="closed", zone=z))
            for z in zones
            if before.get(z.name) != now[z.name]
        ]
        out += [("zone", ZoneEvent(name=n, state="open")) for n in before if n not in now]
        return out

    def stop(
        self, stop: StopView, coordinator: CoordinatorStatus | None
    ) -> list[tuple[str, BaseModel]]:
        """A `stop` event when the fleet's stop engages, releases or its cause changes."""
        cause = stop.cause
        now = (stop.engaged, None if cause is None else f"{cause.by}|{cause.reason}")
        before, self._stop = self._stop, now
        if before is None or before == now:
            return []
        return [("stop", stop_state(stop, coordinator))]

    def coordinator(self, status: CoordinatorStatus | None) -> list[tuple[str, BaseModel]]:
        """A `coordinator` event when its state or its stop changes."""
        if status is None:
            return []
        now = (status.state, status.estop)
        before, self._coordinator = self._coordinator, now
        if before is None or before == now:
            return []
        return [("coordinator", status)]


@dataclass(frozen=True)
class Event:
    """One event of a link: its number, kind and data (JSON text)."""

    number: int
    kind: str
    data: str


class EventLog:
    """The latest KEPT events of one account's link; streams wait on it (thread-safe).

    An event's id is `<run>-<number>`, `run` random per log: an id from another run of the
    dashboard (or one pushed out) cannot be resumed, and the stream says `reset` instead.
    """

    def __init__(self, kept: int = KEPT) -> None:
        self.run = secrets.token_hex(4)
        self._events: deque[Event] = deque(maxlen=kept)
        self._next = 1
        self._changed = threading.Condition()

    def add(self, events: Iterable[tuple[str, BaseModel]]) -> None:
        """Number and keep `events`; wake the streams."""
        with self._changed:
            for kind, data in events:
                self._events.append(Event(self._next, kind, data.model_dump_json()))
                self._next += 1
            self._changed.notify_all()

    @property
    def last(self) -> int:
        """The number of the latest event (0: none yet)."""
        with self._changed:
            return self._next - 1

    def event_id(self, event: Event) -> str:
        """The id a stream gives `event`."""
        return f"{self.run}-{event.number}"

    def resume_from(self, last_event_id: str | None) -> int | None:
        """The number a stream resuming after `last_event_id` goes on from (None: it cannot:
        unknown, from another run, or pushed out); no id: from now."""
        if last_event_id is None:
            return self.last
        run, _, number = last_event_id.partition("-")
        if run != self.run or not number.isdigit():
            return None
        after = int(number)
        with self._changed:
            oldest = self._events[0].number if self._events else self._next
            if after > self._next - 1 or after < oldest - 1:
                return None
        return after

    def after(self, number: int, wait_s: float) -> list[Event]:
        """The events after `number`, waiting up to `wait_s` for one when there are none."""
        deadline = time.monotonic() + wait_s
        with self._changed:
            while self._next - 1 <= number:
                left = deadline - time.monotonic()
                if left <= 0:
                    return []
                self._changed.wait(left)
            return [e for e in self._events if e.number > number]


def sse(event_id: str, kind: str, data: str) -> str:
    """One event in the text/event-stream format (data is one line of JSON)."""
    return f"id: {event_id}\nevent: {kind}\ndata: {data}\n\n"


HEARTBEAT = ": heartbeat\n\n"
