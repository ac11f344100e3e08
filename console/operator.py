"""The operator client: sends requests to the coordinator, awaits replies, follows the queue view.

A request is re-sent, the same (same id), until its reply arrives: a loaded broker drops
messages, and the coordinator answers a retry with its first answer (protocol.md §6). It also
follows the emergency stop (the latch and every press) and the coordinator's status, so that
`gridfleet job stop` and `release` know what they change before they change it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
from collections.abc import AsyncIterator, Sequence
from typing import TypeVar

import aiomqtt
from pydantic import ValidationError

from gridfleet.bus import reach_first
from gridfleet.config import broker_login, owned_client_id
from gridfleet.endpoint import payload_of, send
from gridfleet.errors import GridfleetError, ProtocolError
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    TOPICS,
    CancelJob,
    ClearObstacles,
    CloseZone,
    ControlUnit,
    CoordinatorStatus,
    EstopSignal,
    FleetMap,
    HeaderStamper,
    JobHistoryPage,
    JobHistoryQuery,
    JobsView,
    OpenZone,
    RemoveUnit,
    Reply,
    Routes,
    SetGoal,
    SubmitJob,
    Topics,
    ZonesView,
    decode,
    encode_estop,
)
from gridfleet.protocol.codec import describe
from gridfleet.protocol.messages import FINAL_JOB_STATES, AuditPage, AuditQuery, Request
from gridfleet.protocol.stop import STOP_KINDS, StopView, stop_filters
from gridfleet.squares import Cell
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.operator")
Answer = Reply | JobHistoryPage | AuditPage  # what the coordinator answers a request with
R = TypeVar("R", bound=Request)
WAIT_S = 60.0  # how long a request waits for its reply in all, re-sent meanwhile
RETRY_S = 2.0  # the first wait before a request is sent again; it doubles up to RETRY_MOST_S
RETRY_MOST_S = 10.0
# How long to wait for the stop's retained messages when no coordinator status marks their end.
STOP_SETTLE_S = 1.0


class Operator:
    """Sends requests to the coordinator and awaits their replies; tracks the job queue view."""

    def __init__(
        self, client: aiomqtt.Client, topics: Topics, client_id: str, retry_s: float = RETRY_S
    ) -> None:
        self.client = client
        self.topics = topics
        self.client_id = client_id
        self.broker = ""  # the broker it is on, as messages name it (set by operator_session)
        self.stamp = HeaderStamper(client_id)
        self.jobs: JobsView | None = None
        self.jobs_changed = asyncio.Event()
        self.coordinator_online = asyncio.Event()
        self.ended = asyncio.Event()  # set when `listen` ends: the session is gone
        self.coordinator: CoordinatorStatus | None = None  # its latest status, retained
        self.coordinator_heard = asyncio.Event()
        self.stop = StopView()  # the latch and the held presses, as the broker keeps them
        self.stop_changed = asyncio.Event()
        self.planned_units: set[str] = set()  # units in the coordinator's latest routes view
        self.routes_changed = asyncio.Event()
        self.retry_s = retry_s
        self.resent = 0  # requests sent again for want of a reply (figures for the bench)
        self._pending: dict[str, asyncio.Future[Answer]] = {}
        self._count = 0
        self._audit_followed = False  # its replies, subscribed at the first query (operators')
        self.obstacles: frozenset[Cell] = frozenset()  # found by the units (fleet/map)
        self.map: FleetMap | None = None  # the latest fleet/map: its places too
        self.map_changed = asyncio.Event()
        self.zones: ZonesView | None = None  # the latest fleet/zones: the zones closed
        self.zones_changed = asyncio.Event()
        # Request ids must be unique per sender across restarts (the coordinator remembers them),
        # and a client id may be reused: a random part per session.
        self._session = secrets.token_hex(3)

    async def start(self) -> None:
        """Subscribe to the stop, replies, the queue view and, last, the coordinator's status.

        A broker sends a subscription's retained messages before it handles the next one (amqtt
        and Mosquitto alike), so the coordinator's retained status marks the end of the rest.
        """
        t = self.topics
        for topic, qos in stop_filters(t):
            await self.client.subscribe(topic, qos=qos)
        for topic in (
            t.reply(self.client_id),
            t.history_reply(self.client_id),
            t.fleet("jobs"),
            t.fleet("map"),
            t.fleet("routes"),
            t.fleet("zones"),
            t.fleet("coordinator"),
        ):
            await self.client.subscribe(topic, qos=SUBSCRIBE_QOS)

    async def listen(self) -> None:
        """Route inbound messages until the client disconnects (then `ended` is set)."""
        try:
            async for message in self.client.messages:
                self.handle(str(message.topic), payload_of(message))
        finally:
            self.ended.set()

    def handle(self, topic: str, payload: bytes) -> None:
        """Take one inbound message into the views; a bad one is logged and changes nothing."""
        try:
            kind, source = self.topics.parse(topic)
            if kind in STOP_KINDS:
                self.stop.apply(kind, source, topic, payload)
                self.stop_changed.set()
            elif kind in ("reply", "history_reply", "audit_reply"):
                answer: Answer
                if kind == "reply":
                    answer = decode(Reply, payload)
                elif kind == "history_reply":
                    answer = decode(JobHistoryPage, payload, TOPICS[kind].max_bytes)
                else:
                    answer = decode(AuditPage, payload, TOPICS[kind].max_bytes)
                future = self._pending.pop(answer.request_id, None)
                if future is not None and not future.done():
                    future.set_result(answer)
            elif kind == "jobs":
                self.jobs = decode(JobsView, payload, TOPICS["jobs"].max_bytes)
                self.jobs_changed.set()
            elif kind == "map":
                fleet_map = decode(FleetMap, payload, TOPICS["map"].max_bytes)
                self.obstacles = frozenset(fleet_map.obstacles)
                self.map = fleet_map
                self.map_changed.set()
            elif kind == "zones":
                self.zones = decode(ZonesView, payload, TOPICS["zones"].max_bytes)
                self.zones_changed.set()
            elif kind == "routes":
                routes = decode(Routes, payload, TOPICS["routes"].max_bytes)
                self.planned_units = set(routes.routes)
                self.routes_changed.set()
            elif kind == "coordinator":
                status = decode(CoordinatorStatus, payload)
                self.coordinator = status
                self.coordinator_heard.set()
                if status.state == "online":
                    self.coordinator_online.set()
                else:
                    self.coordinator_online.clear()
        except ProtocolError as exc:
            log.warning("ignored a bad message on %s: %s", topic, exc)

    def _next_id(self) -> str:
        self._count += 1
        return f"{self.client_id}-{self._session}-{self._count}"[-64:]

    def _made(self, kind: str, model: type[R], fields: dict[str, object]) -> R:
        """A request of `model` from this client; a bad value is a ProtocolError naming it."""
        try:
            return model(
                header=self.stamp(kind),
                request_id=self._next_id(),
                reply_to=self.client_id,
                **fields,
            )
        except ValidationError as exc:
            raise ProtocolError(f"{kind}: {describe(exc)}") from None

    async def _request(
        self, kind: str, model: type[Request], timeout: float, **fields: object
    ) -> Reply:
        """Build a request, send it, await its reply."""
        answer = await self._send(kind, self._made(kind, model, fields), timeout)
        assert isinstance(answer, Reply)  # only queries are answered with pages
        return answer

    async def job_history(self, timeout: float = WAIT_S, **query: object) -> JobHistoryPage | Reply:
        """One page of the job history (protocol.md §6.10), or the Reply that refused the query."""
        request = self._made("job_history", JobHistoryQuery, query)
        answer = await self._send("job_history", request, timeout)
        assert not isinstance(answer, AuditPage)  # request ids are never shared
        return answer

    async def audit(self, timeout: float = WAIT_S, **query: object) -> AuditPage:
        """One page of the audit trail (protocol.md §6.8); a refusal is a page not `accepted`."""
        request = self._made("audit", AuditQuery, query)
        if not self._audit_followed:
            # Only operators may read the audit: other accounts never follow its replies.
            reply = self.topics.audit_reply(self.client_id)
            await self.client.subscribe(reply, qos=SUBSCRIBE_QOS)
            self._audit_followed = True
        why = "is it running, and may this account read the audit?"
        answer = await self._send("audit", request, timeout, why)
        assert isinstance(answer, AuditPage)
        return answer

    async def _send(
        self, kind: str, request: Request, timeout: float, why: str = "is it running?"
    ) -> Answer:
        """Send `request` until its answer arrives, backing off; give up after `timeout` s."""
        loop = asyncio.get_running_loop()
        future: asyncio.Future[Answer] = loop.create_future()
        rid = request.request_id
        self._pending[rid] = future
        out = Outbound.of(kind, self.topics.request(kind), request)
        deadline = loop.time() + timeout
        pause, tries = self.retry_s, 0
        try:
            while (left := deadline - loop.time()) > 0:
                if tries:
                    self.resent += 1
                    log.info(
                        "no reply to %s %s yet: sending it again (try %d)", kind, rid, tries + 1
                    )
                tries += 1
                # A publish the broker is slow to acknowledge must not eat the whole wait.
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(send(self.client, out), left)
                left = deadline - loop.time()
                with contextlib.suppress(TimeoutError):
                    return await asyncio.wait_for(asyncio.shield(future), max(0, min(pause, left)))
                pause = min(2 * pause, RETRY_MOST_S)
        finally:
            self._pending.pop(rid, None)
        raise GridfleetError(
            f"no reply from the coordinator to {kind} {rid} after {_tries(tries)} over "
            f"{timeout:.0f} s: {why}"
        )

    async def submit_job(
        self,
        pickup: Cell | str,
        dropoff: Cell | str,
        mass_kg: float,
        job_id: str | None = None,
        priority: int = 0,
        timeout: float = WAIT_S,
    ) -> Reply:
        """Queue a job (pickup and dropoff: squares, or places by name); returns the reply."""
        return await self._request(
            "submit_job",
            SubmitJob,
            timeout,
            pickup=pickup,
            dropoff=dropoff,
            mass_kg=mass_kg,
            priority=priority,
            job_id=job_id,
        )

    async def set_goal(self, unit: str, target: Cell | None, timeout: float = WAIT_S) -> Reply:
        """Send one unit to `target` (None clears its goal)."""
        return await self._request("set_goal", SetGoal, timeout, unit=unit, target=target)

    async def cancel_job(self, job_id: str, timeout: float = WAIT_S) -> Reply:
        """Delete a queued job or abort an active one."""
        return await self._request("cancel_job", CancelJob, timeout, job_id=job_id)

    async def control_unit(self, unit: str, command: str, timeout: float = WAIT_S) -> Reply:
        """Pause or resume one unit, take it out of service or back, or send it to charge
        (protocol.md §6.4)."""
        return await self._request("control_unit", ControlUnit, timeout, unit=unit, command=command)

    async def remove_unit(
        self, unit: str, reason: str | None = None, timeout: float = WAIT_S
    ) -> Reply:
        """Remove a lost unit that is off the floor for good (protocol.md §6.11)."""
        return await self._request("remove_unit", RemoveUnit, timeout, unit=unit, reason=reason)

    async def close_zone(
        self, name: str, first: Cell, last: Cell, reason: str, timeout: float = WAIT_S
    ) -> Reply:
        """Close the rectangle `first`..`last` as zone `name`, for `reason` (protocol.md §6.12)."""
        return await self._request(
            "close_zone", CloseZone, timeout, name=name, first=first, last=last, reason=reason
        )

    async def open_zone(self, name: str, timeout: float = WAIT_S) -> Reply:
        """Open the closed zone `name` again (protocol.md §6.13)."""
        return await self._request("open_zone", OpenZone, timeout, name=name)

    async def clear_obstacles(self, squares: list[Cell] | None, timeout: float = WAIT_S) -> Reply:
        """Forget discovered obstacles that are gone (None: all of them; protocol.md §6.6)."""
        return await self._request("clear_obstacles", ClearObstacles, timeout, squares=squares)

    async def set_estop(self, engaged: bool, reason: str) -> EstopSignal:
        """Engage or release the fleet-wide emergency stop (retained: it latches); returns it."""
        signal = EstopSignal(engaged, self.client_id, reason)
        await send(
            self.client, Outbound.of("estop", self.topics.fleet("estop"), encode_estop(signal))
        )
        return signal

    async def stop_as_kept(self, wait_s: float = STOP_SETTLE_S) -> StopView:
        """The stop as the broker keeps it (its retained latch and presses), to read before acting.

        They have all arrived once the coordinator's retained status has (subscribed to last);
        with no coordinator status on the broker, after `wait_s`.
        """
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self.coordinator_heard.wait(), wait_s)
        return self.stop

    @property
    def coordinator_stopped(self) -> bool:
        """Whether a coordinator that is online says the fleet is stopped (its own view)."""
        status = self.coordinator
        return status is not None and status.state == "online" and status.estop

    async def wait_for_units(self, units: Sequence[str], timeout: float = 30.0) -> None:
        """Wait until the coordinator plans for every unit in `units` (it knows their state)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while missing := sorted(set(units) - self.planned_units):
            self.routes_changed.clear()
            try:
                await asyncio.wait_for(self.routes_changed.wait(), deadline - loop.time())
            except TimeoutError:
                raise GridfleetError(
                    f"the coordinator has not heard from {', '.join(missing)} within {timeout:.0f} s"
                ) from None

    def active_jobs(self) -> int:
        """Jobs in the queue view that are not final."""
        if self.jobs is None:
            return 0
        return sum(1 for j in self.jobs.jobs if j.state not in FINAL_JOB_STATES)


def _tries(n: int) -> str:
    return "1 try" if n == 1 else f"{n} tries"


@contextlib.asynccontextmanager
async def operator_session(
    url: str, topics: Topics, client_id: str, retry_s: float = RETRY_S
) -> AsyncIterator[Operator]:
    """A connected Operator, subscribed and listening in the background until the block ends."""
    # Logged in with an account, the id (the requests' sender) is one that account owns.
    client_id = owned_client_id(broker_login(url), client_id)
    async with reach_first(url, client_id) as reached:
        operator = Operator(reached.client, topics, client_id, retry_s)
        operator.broker = str(reached)
        await operator.start()
        listener = asyncio.create_task(operator.listen())
        try:
            yield operator
        finally:
            await cancel_and_wait(listener)
