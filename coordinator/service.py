"""The coordinator's I/O shell: MQTT in and out, the step loop, reconnects; decisions are in core."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from collections.abc import Callable
from pathlib import Path

import aiomqtt

from coordinator.core import CoordinatorCore
from coordinator.jobs import JobBook
from coordinator.orders import OrderPlan
from coordinator.requests import Outcome
from coordinator.store import JobStore, default_db_path
from coordinator.world import World
from gridfleet import __version__
from gridfleet.bus import make_client
from gridfleet.errors import ProtocolError
from gridfleet.grid import GridMap
from gridfleet.protocol import (
    TOPICS,
    CancelJob,
    Connection,
    CoordinatorStatus,
    ErrorReport,
    Factsheet,
    HeaderStamper,
    Order,
    Reply,
    Routes,
    SetGoal,
    SubmitJob,
    Topics,
    UnitState,
    decode,
    decode_estop,
    encode,
)
from gridfleet.protocol.constants import MAX_REQUEST_BYTES, MIN_TIMEOUT_S
from gridfleet.protocol.messages import Message
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.coordinator")

# Longest a step waits past its period for units to acknowledge the moves of the previous step:
# half the shortest hold timeout, so units never hold for want of orders while we wait.
ACK_WAIT_S = MIN_TIMEOUT_S / 2
# A burst of requests (a script queueing hundreds of jobs) gets one queue view per this period,
# not one per request: each view lists every job, so one per request grows as the square.
VIEWS_BATCH_S = 0.05

_REQUESTS: dict[str, type[SubmitJob] | type[CancelJob] | type[SetGoal]] = {
    "submit_job": SubmitJob,
    "cancel_job": CancelJob,
    "set_goal": SetGoal,
}


class Coordinator:
    """The coordinator service: `await Coordinator(...).run(stop)`; `ready` is set once online."""

    def __init__(
        self,
        broker: str,
        grid: GridMap,
        *,
        root: str = "gridfleet",
        step_s: float = 1.0,
        db_path: str | Path | None = None,
        client_id: str = "coordinator",
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.broker = broker
        self.topics = Topics(root)
        self.step_s = step_s
        self.client_id = client_id
        self.clock = clock
        self.store = JobStore(db_path if db_path is not None else default_db_path())
        self.world = World(grid, step_period_s=step_s)
        self.core = CoordinatorCore(
            self.world, JobBook(self.store.load()), nonce=secrets.token_hex(3), seed=seed
        )
        self._persist()
        self.stamp = HeaderStamper(client_id)
        self.ready = asyncio.Event()
        self.errors_sent = 0
        self._client: aiomqtt.Client | None = None
        self._map_dirty = True
        self._jobs_dirty = True
        # Moves sent and not yet acknowledged by the unit's state: unit -> (order id, update id).
        self._awaiting: dict[str, tuple[str, int]] = {}
        self._acked = asyncio.Event()
        self._views_at = -VIEWS_BATCH_S  # loop time of the last views published for a request
        self._views_later: asyncio.Task[None] | None = None

    # ---- lifecycle ---------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        """Serve until `stop` is set; reconnects with back-off when the broker goes away."""
        backoff = 0.1
        try:
            while not stop.is_set():
                try:
                    await self._session(stop)
                    backoff = 0.1
                except aiomqtt.MqttError as exc:
                    self.ready.clear()
                    log.warning("broker connection lost (%s); retrying in %.1f s", exc, backoff)
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(stop.wait(), backoff)
                    backoff = min(backoff * 2, 2.0)
        finally:
            self.store.close()

    async def _session(self, stop: asyncio.Event) -> None:
        will = aiomqtt.Will(
            self.topics.fleet("coordinator"),
            encode(self._status("broken")),
            qos=1,
            retain=True,
        )
        async with make_client(self.broker, self.client_id, will=will) as client:
            self._client = client
            t = self.topics
            for kind in ("connection", "factsheet"):
                await client.subscribe(t.all_units(kind), qos=1)
            await client.subscribe(t.all_units("state"), qos=0)
            await client.subscribe(t.fleet("estop"), qos=1)
            await client.subscribe(t.all_requests, qos=1)
            self._map_dirty = self._jobs_dirty = True
            await self._publish_status("online")
            await self._publish_views()
            self.ready.set()
            log.info("coordinator online at %s (root %s)", self.broker, t.root)
            receiver = asyncio.create_task(self._receive(client))
            try:
                await self._step_loop(stop, receiver)
            finally:
                await cancel_and_wait(receiver)
                if self._views_later is not None:
                    await cancel_and_wait(self._views_later)
            if stop.is_set():
                with contextlib.suppress(aiomqtt.MqttError):
                    await self._publish_status("offline")
                    await self._send_holds()
            self._client = None

    async def _step_loop(self, stop: asyncio.Event, receiver: asyncio.Task[None]) -> None:
        next_at = self.clock()
        while not stop.is_set():
            if receiver.done():
                receiver.result()  # re-raises the broker error
                return
            ticked = self.clock()
            await self.tick()
            next_at += self.step_s
            delay = max(0.0, next_at - self.clock())
            if delay == 0.0:
                next_at = self.clock()
            await self._pause(stop, receiver, delay)
            # Back-pressure: when states come back late (an overloaded broker), a step before
            # the units acknowledged the last moves would only add load; they could not move.
            ack_by = ticked + max(self.step_s, ACK_WAIT_S)
            if self._awaiting and not stop.is_set() and self.clock() < ack_by:
                self._acked.clear()
                await self._pause(stop, receiver, ack_by - self.clock(), self._acked)
                next_at = max(next_at, self.clock())

    async def _pause(
        self,
        stop: asyncio.Event,
        receiver: asyncio.Task[None],
        timeout: float,
        until: asyncio.Event | None = None,
    ) -> None:
        waits = {asyncio.create_task(stop.wait())}
        if until is not None:
            waits.add(asyncio.create_task(until.wait()))
        await asyncio.wait({*waits, receiver}, timeout=timeout, return_when=asyncio.FIRST_COMPLETED)
        for w in waits:
            w.cancel()

    def _note_ack(self, unit_id: str, state: UnitState) -> None:
        awaited = self._awaiting.get(unit_id)
        if awaited is not None and (
            state.order_id == awaited[0] and state.order_update_id >= awaited[1]
        ):
            del self._awaiting[unit_id]
            if not self._awaiting:
                self._acked.set()

    async def _receive(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            payload = message.payload
            data = payload if isinstance(payload, bytes | bytearray) else str(payload).encode()
            await self.handle(str(message.topic), bytes(data))

    # ---- inbound -----------------------------------------------------------------------

    async def handle(self, topic: str, payload: bytes) -> None:
        """Route one inbound message; bad ones are reported on `errors` and change nothing."""
        try:
            kind, ident = self.topics.parse(topic)
        except ProtocolError:
            return  # not ours to judge
        try:
            if kind == "connection" and ident is not None:
                self.world.on_connection(ident, decode(Connection, payload))
            elif kind == "factsheet" and ident is not None:
                self.world.on_factsheet(ident, decode(Factsheet, payload))
            elif kind == "state" and ident is not None:
                msg = decode(UnitState, payload)
                self._note_ack(ident, msg)
                if self.world.on_state(ident, msg, self.clock()):
                    self.core.on_new_obstacles()
                    self._map_dirty = True
            elif kind == "estop":
                signal = decode_estop(payload)
                if self.core.set_estop(signal.engaged):
                    log.warning(
                        "emergency stop %s by %s: %s",
                        "ENGAGED" if signal.engaged else "released",
                        signal.by,
                        signal.reason,
                    )
                    if signal.engaged:
                        await self._send_holds()
                    await self._publish_status("online")
            elif kind in _REQUESTS:
                await self._request(kind, topic, payload)
        except ProtocolError as exc:
            await self._error(topic, str(exc), None)

    async def _request(self, kind: str, topic: str, payload: bytes) -> None:
        model = _REQUESTS[kind]
        try:
            req = decode(model, payload, MAX_REQUEST_BYTES)
        except ProtocolError as exc:
            await self._error(topic, str(exc), None)
            return
        sender = req.header.sender
        outcome: Outcome
        if isinstance(req, SubmitJob):
            outcome = self.core.submit(req, sender)
        elif isinstance(req, CancelJob):
            outcome = self.core.cancel(req, sender)
        else:
            outcome = self.core.set_goal(req)
        self._persist()
        if not outcome.accepted:
            await self._error(topic, f"{model.__name__}: {outcome.reason}", req.request_id)
        if req.reply_to is not None:
            reply = Reply(
                header=self.stamp("reply"),
                request_id=req.request_id,
                accepted=outcome.accepted,
                reason=outcome.reason,
                job_id=outcome.job_id,
            )
            await self._publish("reply", self.topics.reply(req.reply_to), reply)
        if self._jobs_dirty:  # set by _persist above
            await self._views_soon()

    async def _views_soon(self) -> None:
        """Publish the changed views now, or once the batch period is over (one pending at most)."""
        wait = self._views_at + VIEWS_BATCH_S - asyncio.get_running_loop().time()
        if wait <= 0:
            self._views_at = asyncio.get_running_loop().time()
            await self._publish_views()
        elif self._views_later is None or self._views_later.done():
            self._views_later = asyncio.create_task(self._views_after(wait))

    async def _views_after(self, delay: float) -> None:
        await asyncio.sleep(delay)  # pacing: the end of the batch period, not synchronisation
        self._views_at = asyncio.get_running_loop().time()
        with contextlib.suppress(aiomqtt.MqttError):  # the receiver sees a lost broker first
            await self._publish_views()

    # ---- the step ----------------------------------------------------------------------

    async def tick(self) -> None:
        """One coordinator step: decide, then send orders and changed views."""
        result = self.core.step(self.clock())
        if self.core.jobs.changed:
            self._jobs_dirty = True
        self._persist()
        self._awaiting = {u: a for u, a in self._awaiting.items() if u in result.orders}
        for unit_id, plan in result.orders.items():
            if self.core.estop and plan.released:
                continue  # the stop arrived while this step was being sent: its holds already went
            # Every order is acknowledged by the unit's next state (its `order_update_id`).
            self._awaiting[unit_id] = (plan.order_id, plan.update_id)
            await self._send_order(unit_id, plan)
        routes = Routes(header=self.stamp("routes"), step=result.step, routes=result.routes)
        await self._publish("routes", self.topics.fleet("routes"), routes)
        await self._publish_views()

    async def _send_order(self, unit_id: str, plan: OrderPlan) -> None:
        order = Order(
            header=self.stamp("order"),
            order_id=plan.order_id,
            update_id=plan.update_id,
            step=plan.step,
            released=plan.released,  # type: ignore[arg-type]
            planned=plan.planned,  # type: ignore[arg-type]
            target=plan.target,
            action=plan.action,
        )
        await self._publish("order", self.topics.unit("order", unit_id), order)

    async def _send_holds(self) -> None:
        # The emergency stop wins at once: every unit gets a hold now, not at the next step.
        self._awaiting.clear()
        self._acked.set()
        for unit_id, plan in self.core.holds().items():
            await self._send_order(unit_id, plan)

    # ---- outbound ----------------------------------------------------------------------

    def _persist(self) -> None:
        changed = self.core.jobs.changed
        if changed:
            self.store.save(self.core.jobs.jobs[j] for j in sorted(changed))
            changed.clear()
            self._jobs_dirty = True

    def _status(self, state: str) -> CoordinatorStatus:
        return CoordinatorStatus(
            header=self.stamp("coordinator"),
            state=state,  # type: ignore[arg-type]
            step=self.core.step_no,
            step_period_s=self.step_s,
            estop=self.core.estop,
            version=__version__,
        )

    async def _publish_status(self, state: str) -> None:
        await self._publish("coordinator", self.topics.fleet("coordinator"), self._status(state))

    async def _publish_views(self) -> None:
        if self._map_dirty:
            self._map_dirty = False
            fleet_map = self.world.fleet_map(self.stamp("map"))
            await self._publish("map", self.topics.fleet("map"), fleet_map)
        if self._jobs_dirty:
            self._jobs_dirty = False
            view = self.core.jobs.view(self.stamp("jobs"))
            await self._publish("jobs", self.topics.fleet("jobs"), view)

    async def _error(self, topic: str, reason: str, request_id: str | None) -> None:
        self.errors_sent += 1
        log.info("refused a message on %s: %s", topic, reason)
        report = ErrorReport(
            header=self.stamp("errors"),
            topic=topic[:256],
            reason=reason[:500],
            request_id=request_id,
        )
        await self._publish("errors", self.topics.fleet("errors"), report)

    async def _publish(self, kind: str, topic: str, message: Message) -> None:
        if self._client is None:
            return
        spec = TOPICS[kind]
        await self._client.publish(topic, encode(message), qos=spec.qos, retain=spec.retained)
