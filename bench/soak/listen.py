"""The soak's listener on `<root>/v1/#`, straight on the broker (not through the faulty proxy):
it records unit states, job states and the stop as checker events, and reconnects after a
broker restart."""

from __future__ import annotations

import asyncio
import time

import aiomqtt

from gridfleet.bench.soak.check import Event, Held, JobSeen, StateSeen, Stop
from gridfleet.bus import reach_first
from gridfleet.endpoint import payload_of
from gridfleet.errors import ProtocolError
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    TOPICS,
    Connection,
    CoordinatorStatus,
    JobsView,
    Topics,
    UnitState,
    decode,
)
from gridfleet.protocol.device import decode_estop, decode_press
from gridfleet.tasks import cancel_and_wait

RETAINED_S = 0.5  # after (re)subscribing: the retained stop messages have arrived by then
# Live only (a cluster): a session that hears nothing this long is deaf (a node that lost the
# cluster's traffic: the fleet publishes every step), and is left for the next node.
DEAF_S = 3.0


class SoakListener:
    """Records what the fleet says, as `Event`s in `events`, for the whole run."""

    def __init__(self, url: str, topics: Topics, client_id: str, live_only: bool = False) -> None:
        self.url = url  # one broker, or a cluster's nodes (read again at each reconnect)
        # On a cluster: only what was published since it subscribed, never a retained replay. A
        # node it moves to replays what that node kept (on RabbitMQ an old stop or jobs view:
        # retained messages are node-local), and a replayed state is no sign of a live unit.
        self.live_only = live_only
        self.on = ""  # the broker it is on now, as messages show it (no password)
        self.sessions: list[tuple[float, str]] = []  # (when, the broker it got on, or why it left)
        self.heard = 0.0  # wall time of the latest message of this session
        self.topics = topics
        self.client_id = client_id
        self.events: list[Event] = []
        self.last_state: dict[str, float] = {}  # unit -> wall time of its latest state here
        self.jobs: dict[str, str] = {}  # job -> latest state seen
        self.latch = False
        self.presses: set[str] = set()  # topics of the presses held
        # Live only: the stop as the coordinator's status last said it. A node the coordinator
        # moved to may replay an old latch (RabbitMQ's retained messages are node-local), which
        # the coordinator obeys, and which nobody publishes live: the fleet is held, by no stop
        # anybody engaged (not a stop the units must obey: the checks do not count it as one).
        self.coordinator_stop = False
        self.coordinator_held: bool | None = None  # the stop in its latest status, as heard
        self.unasked_stops: list[float] = []  # when the coordinator held a stop nobody engaged
        self.connected = asyncio.Event()
        self.last_routes = 0.0  # wall time of the coordinator's latest routes view here
        self.estop_shown: dict[str, bool] = {}  # unit -> whether its latest state shows the stop
        self.errors: list[tuple[float, str]] = []  # what was reported on `errors`, for the log
        self.reported_stopped = False  # the stop as the last Stop event gave it
        self.settling = False  # just (re)connected: the retained stop is still arriving
        self.worst_lag = (0.0, 0.0)  # (seconds a unit's live state took to reach us, when)
        self.broken: dict[str, float] = {}  # unit or "coordinator" -> when its will last came
        self.squares: dict[str, tuple[int, int]] = {}  # unit -> its square in its latest state
        self.last_move = 0.0  # wall time of the latest state showing a unit on a new square

    @property
    def stopped(self) -> bool:
        """The fleet is stopped while the latch is engaged or any press is held (§5.1)."""
        return self.latch or bool(self.presses)

    @property
    def held(self) -> bool:
        """Stopped, or (live only) the coordinator says it holds the stop."""
        return self.stopped or self.coordinator_stop

    async def run(self) -> None:
        """Listen for ever, reconnecting whenever the broker goes away."""
        while True:
            try:
                async with reach_first(self.url, self.client_id, keepalive=2) as reached:
                    client = reached.client
                    self.on = reached.broker
                    self.sessions.append((time.time(), f"on {reached}"))
                    self.reconnected()
                    await client.subscribe(f"{self.topics.prefix}/#", qos=SUBSCRIBE_QOS)
                    self.connected.set()
                    self.heard = time.time()
                    settle = asyncio.create_task(self._settle())
                    receive = asyncio.create_task(self._receive(client))
                    deaf = asyncio.create_task(self._deaf(reached.index))
                    try:
                        done, _ = await asyncio.wait(
                            {receive, deaf}, return_when=asyncio.FIRST_COMPLETED
                        )
                    finally:
                        for task in (settle, receive, deaf):
                            await cancel_and_wait(task)
                    for task in done:
                        task.result()  # the session's end: an MqttError
            except aiomqtt.MqttError as exc:
                self.sessions.append((time.time(), f"left: {exc}"))  # try again shortly
            self.connected.clear()
            self.on = ""
            await asyncio.sleep(0.1)  # pacing of reconnection attempts

    async def _receive(self, client: aiomqtt.Client) -> None:
        """Take every message of the session (a retained replay too, unless live only)."""
        async for message in client.messages:
            self.heard = time.time()
            if not (self.live_only and message.retain):
                self.take(str(message.topic), payload_of(message), time.time())
        raise aiomqtt.MqttError("the session ended")

    async def _deaf(self, index: int) -> None:
        """Live only: end a session that hears nothing for DEAF_S, its broker last in the list."""
        if not self.live_only:
            await asyncio.Event().wait()  # only the session's end ends it
        while time.time() - self.heard < DEAF_S:
            await asyncio.sleep(0.5)  # a coarse look at the session's last message
        urls = self.url.split(",")
        self.url = ",".join(urls[index + 1 :] + urls[: index + 1])
        raise aiomqtt.MqttError(f"deaf for {DEAF_S:g} s")

    def reconnected(self) -> None:
        """Read the stop afresh, as the units do: a broker restarted without persistence has no
        press left to replay, and holding on to one seen before would see the fleet stopped for
        ever. What the replay leaves is recorded once it settled. Live only (a cluster): the stop
        stands as heard live, as the cluster's other nodes kept it."""
        if self.live_only:
            return
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
                if self.squares.get(who, square) != square:
                    self.last_move = now
                self.squares[who] = square
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
                status = decode(CoordinatorStatus, payload)
                if status.state == "broken":
                    self.broken["coordinator"] = now
                elif status.state == "online" and status.estop != self.coordinator_held:
                    # Stamped by the coordinator: when it held or let go, however late heard.
                    self.coordinator_held = status.estop
                    self.events.append(Held(status.header.timestamp.timestamp(), status.estop))
                if status.state != "broken" and self.live_only:
                    if status.estop and not self.coordinator_stop and not self.stopped:
                        self.unasked_stops.append(now)
                    self.coordinator_stop = status.estop
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
