"""A listener on a whole fleet's topics: unit states, jobs, routes, and a count of messages."""

from __future__ import annotations

import asyncio
import logging

import aiomqtt

from gridfleet.endpoint import payload_of
from gridfleet.errors import ProtocolError
from gridfleet.protocol import (
    TOPICS,
    FleetMap,
    JobsView,
    JobView,
    Routes,
    Topics,
    UnitState,
    decode,
)

log = logging.getLogger("gridfleet.monitor")


class FleetMonitor:
    """Subscribes to `<root>/v1/#` at QoS 0 and keeps the latest view of the fleet."""

    def __init__(self, client: aiomqtt.Client, topics: Topics, record: bool = False) -> None:
        self.client = client
        self.topics = topics
        self.record = record
        self.history: list[UnitState] = []  # every state seen, when `record` is set
        self.routes: list[Routes] = []  # every routes view seen, when `record` is set
        self.states: dict[str, UnitState] = {}
        self.jobs: JobsView | None = None
        self.every_job: dict[str, JobView] = {}  # every job any view listed, as last listed
        self.map: FleetMap | None = None
        self.step = 0
        self.messages = 0
        self.changed = asyncio.Event()

    async def start(self) -> None:
        """Subscribe to everything under the root."""
        await self.client.subscribe(f"{self.topics.prefix}/#", qos=0)

    async def listen(self) -> None:
        """Consume messages until the client disconnects."""
        async for message in self.client.messages:
            self.messages += 1
            topic = str(message.topic)
            payload = payload_of(message)
            kind: str | None = None
            try:
                kind, unit = self.topics.parse(topic)
                if self.seen(kind, unit, topic, payload):
                    self.changed.set()
            except ProtocolError as exc:
                self.bad(topic, kind, exc)

    def seen(self, kind: str, unit: str | None, topic: str, payload: bytes) -> bool:
        """Take in one message (ProtocolError when malformed); True when the view changed."""
        if kind == "state" and unit is not None:
            self.on_state(unit, decode(UnitState, payload))
        elif kind == "jobs":
            self.jobs = decode(JobsView, payload, TOPICS["jobs"].max_bytes)
            # A view lists only the latest finished jobs: a run's report needs every one.
            self.every_job.update((j.id, j) for j in self.jobs.listed())
        elif kind == "map":
            self.map = decode(FleetMap, payload, TOPICS["map"].max_bytes)
        elif kind == "routes":
            routes = decode(Routes, payload, TOPICS["routes"].max_bytes)
            self.step = max(self.step, routes.step)
            if self.record:
                self.routes.append(routes)
        else:
            return False
        return True

    def on_state(self, unit: str, state: UnitState) -> None:
        """A unit's state arrived."""
        self.states[unit] = state
        if self.record:
            self.history.append(state)

    def bad(self, topic: str, kind: str | None, exc: ProtocolError) -> None:
        """A message that does not parse (`kind` None: not even its topic)."""
        log.warning("ignored a bad message on %s: %s", topic, exc)
