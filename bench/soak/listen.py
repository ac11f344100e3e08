"""The soak's listener on `<root>/v1/#`, straight on the broker (not through the faulty proxy):
it records unit states, job states and the stop as checker events, and reconnects after a
broker restart."""

from __future__ import annotations

import asyncio
import time

import aiomqtt

from gridfleet.bench.soak.check import Event, JobSeen, StateSeen, Stop
from gridfleet.bus import connect_first
from gridfleet.endpoint import payload_of
from gridfleet.errors import ProtocolError
from gridfleet.protocol import (
    TOPICS,
    Connection,
    CoordinatorStatus,
    JobsView,
    Topics,
    UnitState,
    decode,
)
from gridfleet.protocol.device import decode_estop, decode_press

RETAINED_S = 0.5  # after (re)subscribing: the retained stop messages have arrived by then


class SoakListener:
    """Records what the fleet says, as `Event`s in `events`, for the whole run."""

    def __init__(self, url: str, topics: Topics, client_id: str) -> None:
        self.url = url
        self.topics = topics
        self.client_id = client_id
        self.events: list[Event] = []
        self.last_state: dict[str, float] = {}  # unit -> wall time of its latest state here
        self.jobs: dict[str, str] = {}  # job -> latest state seen
        self.latch = False
        self.presses: set[str] = set()  # topics of the presses held
        self.connected = asyncio.Event()
        self.last_routes = 0.0  # wall time of the coordinator's latest routes view here
        self.estop_shown: dict[str, bool] = {}  # unit -> whether its latest state shows the stop
        self.errors: list[tuple[float, str]] = []  # what was reported on `errors`, for the log
        self.reported_stopped = False  # the stop as the last Stop event gave it
        self.settling = False  # just (re)connected: the retained stop is still arriving
        self.worst_lag = (0.0, 0.0)  # (seconds a unit's live state took to reach us, when)
        self.broken: dict[str, float] = {}  # unit or "coordinator" -> when its will last came

    @property
    def stopped(self) -> bool:
        """The fleet is stopped while the latch is engaged or any press is held (§5.1)."""
        return self.latch or bool(self.presses)

    async def run(self) -> None:
        """Listen for ever, reconnecting whenever the broker goes away."""
        while True:
            try:
                async with connect_first(self.url, self.client_id, keepalive=2) as client:
                    self.reconnected()
                    await client.subscribe(f"{self.topics.prefix}/#", qos=1)
                    self.connected.set()
                    settle = asyncio.create_task(self._settle())
                    try:
                        async for message in client.messages:
                            self.take(str(message.topic), payload_of(message), time.time())
                    finally:
                        settle.cancel()
            except aiomqtt.MqttError:
                pass  # the broker restarts: try again shortly
            self.connected.clear()
            await asyncio.sleep(0.1)  # pacing of reconnection attempts

    def reconnected(self) -> None:
        """Read the stop afresh, as the units do: a broker restarted without persistence has no
        press left to replay, and holding on to one seen before would see the fleet stopped for
        ever. What the replay leaves is recorded once it settled."""
        self.latch, self.presses, self.settling = False, set(), True

    async def _settle(self) -> None:
        """Once the retained messages had time to arrive: record the stop as it now stands."""
        await asyncio.sleep(RETAINED_S)  # the replay comes right after subscribing
        self.settling = False
        self._note_stop(time.time())

    def _note_stop(self, now: float) -> None:
        if not self.settling and self.stopped != self.reported_stopped:
            self.reported_stopped = self.stopped
            self.events.append(Stop(now, self.stopped))

    def take(self, topic: str, payload: bytes, now: float) -> None:
        """One message; what does not parse is not ours to judge here."""
        try:
            kind, who = self.topics.parse(topic)
            if kind == "state" and who is not None:
                state = decode(UnitState, payload)
                if not self.settling:  # a retained state replayed is old, not late
                    lag = now - state.header.timestamp.timestamp()
                    self.worst_lag = max(self.worst_lag, (lag, now))
                self.last_state[who] = now
                self.estop_shown[who] = state.estop
                # A unit that shows `stopped` is held by a stop: blocked, not stranded.
                busy = state.status != "stopped" and (
                    state.job_id is not None or state.status != "idle"
                )
                square = (state.position.x, state.position.y)
                self.events.append(StateSeen(now, who, square, busy))
            elif kind == "jobs":
                view = decode(JobsView, payload, TOPICS["jobs"].max_bytes)
                for job in view.listed():  # finished jobs are listed apart (protocol 1.4)
                    if self.jobs.get(job.id) != job.state:
                        self.jobs[job.id] = job.state
                        self.events.append(JobSeen(now, job.id, job.state))
            elif kind == "routes":
                self.last_routes = now
            elif kind == "connection" and who is not None:
                if decode(Connection, payload).state == "broken":
                    self.broken[who] = now
            elif kind == "coordinator":
                if decode(CoordinatorStatus, payload).state == "broken":
                    self.broken["coordinator"] = now
            elif kind == "errors":
                self.errors.append((now, payload.decode("utf-8", "replace")))
            elif kind == "estop":
                self.latch = decode_estop(payload).engaged
            elif kind in ("stop", "device_stop") and who is not None:
                if decode_press(payload, who) is None:
                    self.presses.discard(topic)
                else:
                    self.presses.add(topic)
            self._note_stop(now)
        except ProtocolError:
            pass
