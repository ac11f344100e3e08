"""`GET /events` over a real fleet: job, zone and stop changes pushed as server-sent events,
heartbeats, resuming with Last-Event-ID, a `reset` for an id that cannot be resumed, and at most
so many streams at once."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import httpx
import pytest

from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.api_client import TEST_CONFIG, ApiServer, online, problem, serving
from support.wait import wait_for

RunSystem = Callable[..., tuple[ServiceThread, ServiceThread]]
CONFIG = replace(TEST_CONFIG, heartbeat_s=0.2, stream_s=20.0, max_streams=2)


@dataclass
class Sse:
    """One event, or a heartbeat (kind None)."""

    id: str | None
    kind: str | None
    data: dict[str, object] | None


def parse(lines: Iterator[str]) -> Iterator[Sse]:
    """The events and heartbeats of a text/event-stream."""
    fields: dict[str, str] = {}
    for line in lines:
        if line.startswith(":"):
            yield Sse(None, None, None)
        elif line == "":
            if "event" in fields:
                yield Sse(fields.get("id"), fields["event"], json.loads(fields["data"]))
            fields = {}
        else:
            name, _, value = line.partition(": ")
            fields[name] = value


class Stream:
    """An event stream read in a thread of its own, its events collected."""

    def __init__(self, served: ApiServer, last_event_id: str | None = None) -> None:
        headers = {} if last_event_id is None else {"Last-Event-ID": last_event_id}
        api = served.client(timeout=10)  # its own: one connection, read by this thread alone
        self.events: list[Sse] = []
        self.heartbeats = 0
        self.status: int | None = None
        self._stop = threading.Event()
        self._opened = threading.Event()
        self._thread = threading.Thread(target=self._read, args=(api, headers), daemon=True)
        self._thread.start()
        assert self._opened.wait(10), "the stream did not open"

    def _read(self, api: httpx.Client, headers: dict[str, str]) -> None:
        with api, api.stream("GET", "/events", headers=headers) as answer:
            self.status = answer.status_code
            self.content_type = answer.headers.get("content-type", "")
            self._opened.set()
            if answer.status_code != 200:
                return
            for event in parse(answer.iter_lines()):
                if event.kind is None:
                    self.heartbeats += 1
                else:
                    self.events.append(event)
                if self._stop.is_set():
                    return

    def of(self, kind: str) -> list[Sse]:
        return [e for e in self.events if e.kind == kind]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)


def until(test: Callable[[], object], what: str = "the events") -> None:
    wait_for(test, timeout=15, interval=0.05, what=what)


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
def test_the_fleets_changes_are_pushed_and_a_stream_resumes_where_it_broke(
    broker: BrokerThread, root: str, run_system: RunSystem, playfield: Path
) -> None:
    run_system(playfield)
    with serving(broker.url, root, config=CONFIG) as served, served.client(timeout=10) as api:
        online(api)
        stream = Stream(served)
        assert stream.status == 200 and stream.content_type.startswith("text/event-stream")
        job = api.post("/jobs", json={"pickup": "A1", "dropoff": "P1", "mass_kg": 1.5}).json()
        until(lambda: any(e.data and e.data["id"] == job["id"] for e in stream.of("job")))
        first = next(e for e in stream.of("job") if e.data and e.data["id"] == job["id"])
        assert first.data is not None and first.data["pickup_place"] == "A1"
        assert (
            api.put(
                "/zones/dock", json={"first": [9, 9], "last": [9, 9], "reason": "pallets"}
            ).status_code
            == 200
        )
        until(lambda: stream.of("zone"))
        zone = stream.of("zone")[0].data
        assert zone is not None and zone["name"] == "dock" and zone["state"] == "closed"
        assert api.delete("/zones/dock").status_code == 200
        until(lambda: len(stream.of("zone")) == 2)
        assert stream.of("zone")[1].data == {"name": "dock", "state": "open", "zone": None}
        assert api.post("/stop", json={"reason": "drill"}).status_code == 200
        until(lambda: stream.of("stop"))
        stop = stream.of("stop")[0].data
        assert stop is not None and stop["engaged"] is True
        assert api.delete("/stop").status_code == 200
        until(lambda: len(stream.of("stop")) >= 2 and stream.heartbeats > 0)
        stream.close()

        # A stream that broke goes on after the last event it got: nothing lost, none twice.
        ids = [e.id for e in stream.events]
        assert all(ids) and len(set(ids)) == len(ids)
        resumed = Stream(served, last_event_id=first.id)
        until(lambda: len(resumed.events) >= len(stream.events) - 1)
        after = ids[ids.index(first.id) + 1 :]
        assert [e.id for e in resumed.events][: len(after)] == after
        resumed.close()

        # An id it cannot resume from (another run's): `reset` first, then the live events.
        stranger = Stream(served, last_event_id="0000-7")
        until(lambda: stranger.events)
        assert stranger.events[0].kind == "reset"
        stranger.close()

        # At most max_streams at once: one more is told to come back later (once the streams
        # closed above have seen their ends, at their next heartbeat, two open again).
        held: list[Stream] = []

        def opened() -> bool:
            attempt = Stream(served)
            if attempt.status == 200:
                held.append(attempt)
            return len(held) == 2

        until(opened)
        crowded = api.get("/events")
        problem(crowded, 429, "too_many_streams")
        assert int(crowded.headers["Retry-After"]) >= 1
        for s in held:
            s.close()
