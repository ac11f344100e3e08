"""The I/O shell of one unit: its own MQTT client, the step loop, and reconnecting with back-off."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import uuid

import aiomqtt

from gridfleet.bus import make_client
from gridfleet.errors import ProtocolError
from gridfleet.grid import Cell
from gridfleet.protocol import (
    TOPICS,
    Connection,
    CoordinatorStatus,
    ErrorReport,
    Factsheet,
    Goal,
    HeaderStamper,
    Order,
    Topics,
    UnitState,
    decode,
    decode_direction,
    decode_estop,
    encode,
    encode_direction,
)
from gridfleet.protocol.constants import MAX_TEXT
from gridfleet.tasks import cancel_and_wait, until_stopped
from robots.unit import UnitLogic, step_in
from robots.world import WorldSim

log = logging.getLogger(__name__)


class UnitRunner:
    """Runs one simulated unit: connects with a last will, follows its topics, steps in the world."""

    def __init__(
        self,
        logic: UnitLogic,
        world: WorldSim,
        broker_url: str,
        topics: Topics,
        *,
        color: str = "#607d8b",
        watch_remote: bool = False,
        reconnect_s: float = 0.1,
        max_reconnect_s: float = 5.0,
    ) -> None:
        self.logic = logic
        self.world = world
        self.url = broker_url
        self.topics = topics
        self.color = color
        self.watch_remote = watch_remote  # follow other units' state to place remote units
        self.reconnect_s = reconnect_s
        self.max_reconnect_s = max_reconnect_s
        self.id = logic.unit_id
        self.online = asyncio.Event()  # set while connected and announced
        self.connects = 0  # how many times it has connected (tests watch reconnects)
        self._stamp = HeaderStamper(self.id)
        self._client: aiomqtt.Client | None = None
        self._last_order: float | None = None
        self._started = 0.0
        self._estop_deadline: float | None = None
        self._sent_direction: bytes | None = None
        self.killed = False  # set by kill(): gone for good, as a unit that lost power

    # ---- time -------------------------------------------------------------------------------

    def _now(self) -> float:
        return asyncio.get_running_loop().time()

    def since_order_s(self) -> float:
        """Seconds since the last valid order (or since the unit started)."""
        return self._now() - (self._last_order if self._last_order is not None else self._started)

    # ---- main loops -------------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        """Step and stay connected until `stop` is set; then say "offline" and disconnect."""
        self._started = self._now()
        ticker = asyncio.create_task(self._ticks(stop), name=f"{self.id}-ticks")
        delay = self.reconnect_s
        try:
            while not stop.is_set() and not self.killed:
                try:
                    await self._session(stop)
                    delay = self.reconnect_s
                except aiomqtt.MqttError as exc:
                    if self.killed:
                        return
                    if self._client is None and delay == self.reconnect_s:
                        log.warning(
                            "%s: cannot reach the broker at %s (%s); retrying",
                            self.id,
                            self.url,
                            exc,
                        )
                    self._lost(f"{exc}")
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(stop.wait(), delay)
                    delay = min(delay * 2, self.max_reconnect_s)
        finally:
            await cancel_and_wait(ticker)

    def _lost(self, why: str) -> None:
        if self._client is not None:
            log.warning("%s: lost the broker (%s); holding still and reconnecting", self.id, why)
        self._client = None
        self.online.clear()
        self.logic.connected = False
        self.logic.refresh(self.since_order_s())

    async def _session(self, stop: asyncio.Event) -> None:
        t = self.topics
        will = aiomqtt.Will(
            t.unit("connection", self.id),
            encode(Connection(header=self._stamp("connection"), state="broken")),
            qos=1,
            retain=True,
        )
        client = make_client(self.url, f"{self.id}-{uuid.uuid4().hex[:8]}", will=will)
        async with client:
            subs = [t.fleet("estop")]
            if self.logic.mode == "coordinated":
                subs += [t.unit("order", self.id), t.fleet("coordinator")]
            else:
                subs.append(t.unit("goal", self.id))
            if self.watch_remote:
                subs.append(t.all_units("state"))
            for topic in subs:
                kind, _ = t.parse(topic.replace("+", self.id))
                # High-rate topics at QoS 0: amqtt upgrades delivery to the subscription's QoS.
                await client.subscribe(topic, qos=TOPICS[kind].qos if kind != "state" else 0)
            self._client = client
            self.connects += 1
            self.logic.connected = True
            # Until the retained emergency stop can have arrived, hold still (protocol §5.1).
            self.logic.estop_known = False
            self._estop_deadline = self._now() + min(1.0, max(0.2, self.logic.step_s))
            self._sent_direction = None
            await self._publish(
                "connection", Connection(header=self._stamp("connection"), state="online")
            )
            await self._publish(
                "factsheet",
                Factsheet(
                    header=self._stamp("factsheet"),
                    capacity_kg=self.logic.capacity_kg,
                    step_period_s=self.logic.step_s,
                    color=self.color,
                ),
            )
            self.logic.refresh(self.since_order_s())
            await self.publish_state()
            self.online.set()
            # Raises the MqttError that ends the session; returns when `stop` is set.
            await until_stopped(self._receive(client), stop)
            if not stop.is_set():
                return
            await self._publish(
                "connection", Connection(header=self._stamp("connection"), state="offline")
            )
            self.online.clear()
            self._client = None

    async def _ticks(self, stop: asyncio.Event) -> None:
        step_s = self.logic.step_s
        due = self._now()
        while not stop.is_set() and not self.killed:
            due += step_s
            delay = due - self._now()
            if delay < -step_s:  # fell far behind (e.g. a long pause): do not catch up in a burst
                due = self._now()
            elif delay > 0:
                await asyncio.sleep(delay)
            if stop.is_set() or self.killed:
                return
            self.tick()
            await self.publish_state()

    def tick(self) -> None:
        """One step: sense, decide, move in the world (atomically: nothing awaits in between)."""
        if (
            not self.logic.estop_known
            and self._estop_deadline is not None
            and self._now() >= self._estop_deadline
        ):
            self.logic.estop_known = True  # no retained stop on the broker: it is not engaged
        step_in(self.world, self.logic, self.since_order_s())

    # ---- inbound ----------------------------------------------------------------------------

    async def _receive(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            payload = message.payload
            data = (
                payload if isinstance(payload, bytes | bytearray) else str(payload or "").encode()
            )
            try:
                await self._handle(message.topic.value, bytes(data))
            except aiomqtt.MqttError:
                raise
            except Exception:  # a bug must not take the unit off the broker: log it, carry on
                log.exception("%s: failed to handle a message on %s", self.id, message.topic.value)

    async def _handle(self, topic: str, payload: bytes) -> None:
        try:
            kind, who = self.topics.parse(topic)
        except ProtocolError:
            return
        if kind == "estop":
            await self._on_estop(topic, payload)
        elif kind == "order" and who == self.id:
            await self._on_order(topic, payload)
        elif kind == "goal" and who == self.id:
            await self._on_goal(topic, payload)
        elif kind == "coordinator":
            try:
                status = decode(CoordinatorStatus, payload)
            except ProtocolError:
                return  # the coordinator's own problem; nothing for a unit to change
            self.logic.coordinator_step_s = status.step_period_s
        elif kind == "state" and who is not None and who != self.id:
            self._place_remote(who, payload)

    def _place_remote(self, unit: str, payload: bytes) -> None:
        if unit in self.world.positions and unit not in self.world.remote:
            return  # simulated here: this world already knows the truth
        try:
            state = decode(UnitState, payload)
        except ProtocolError:
            return
        self.world.place(unit, Cell(*state.position))

    async def _on_estop(self, topic: str, payload: bytes) -> None:
        try:
            signal = decode_estop(payload)
        except ProtocolError as exc:
            # Never a release: a bad payload changes nothing.
            self.logic.error("bad_estop", str(exc))
            await self._report(topic, str(exc))
            await self.publish_state()
            return
        self.logic.on_estop(signal.engaged)
        self.logic.refresh(self.since_order_s())
        await self.publish_state()

    async def _on_order(self, topic: str, payload: bytes) -> None:
        try:
            order = decode(Order, payload, TOPICS["order"].max_bytes)
        except ProtocolError as exc:
            self.logic.error("bad_order", str(exc))
            await self._report(topic, str(exc))
            await self.publish_state()
            return
        outcome = self.logic.on_order(order)
        if outcome in ("accepted", "stale"):
            self._last_order = self._now()
        if outcome == "refused":
            await self._report(topic, self.logic.errors[-1].message)
        if outcome == "accepted" or outcome == "refused":
            self.logic.refresh(self.since_order_s())
            await self.publish_state()

    async def _on_goal(self, topic: str, payload: bytes) -> None:
        try:
            goal = decode(Goal, payload, TOPICS["goal"].max_bytes)
        except ProtocolError as exc:
            self.logic.error("bad_goal", str(exc))
            await self._report(topic, str(exc))
            await self.publish_state()
            return
        target = None if goal.target is None else Cell(*goal.target)
        if not self.logic.on_goal(target):
            await self._report(topic, self.logic.errors[-1].message)
        self.logic.refresh(self.since_order_s())
        await self.publish_state()

    # ---- outbound ---------------------------------------------------------------------------

    async def publish_state(self) -> None:
        """Publish the state (and the direction when it changed); skipped while disconnected."""
        if self._client is None:
            return
        # Taken now, before any await: a step must not overtake the state that showed its move.
        state = self.logic.report(self._stamp("state"))
        # The step loop and message handlers both publish. Each send is a task and asyncio starts
        # tasks in the order they were made; paho queues a message in that first, synchronous
        # part of aiomqtt's publish, so states and directions leave in the order taken. Nothing
        # waits for an acknowledgement while holding anything: a publish stuck on a dropped
        # connection must not hold back the states sent on the next one.
        sends = [asyncio.ensure_future(self._publish("state", state))]
        direction = encode_direction(decode_direction(state.direction))
        if direction != self._sent_direction:
            self._sent_direction = direction
            topic = self.topics.unit("direction", self.id)
            sends.append(asyncio.ensure_future(self._send(topic, "direction", direction)))
        await asyncio.gather(*sends)

    async def _report(self, topic: str, reason: str) -> None:
        report = ErrorReport(
            header=self._stamp("errors"), topic=topic[:256], reason=reason[:MAX_TEXT]
        )
        await self._send(self.topics.fleet("errors"), "errors", encode(report))

    async def _publish(self, kind: str, message: Connection | Factsheet | UnitState) -> None:
        await self._send(self.topics.unit(kind, self.id), kind, encode(message))

    async def _send(self, topic: str, kind: str, payload: bytes) -> None:
        client = self._client
        if client is None:
            return
        spec = TOPICS[kind]
        try:
            await client.publish(topic, payload, qos=spec.qos, retain=spec.retained)
        except aiomqtt.MqttError as exc:
            # A send still pending on a connection already replaced (its acknowledgement timed
            # out long after a reconnect) says nothing about the live one: leave that alone.
            if client is self._client:
                self._lost(str(exc))
            else:
                log.debug("%s: a send on an earlier connection failed (%s)", self.id, exc)

    def drop_connection(self) -> None:
        """Cut the TCP connection without a DISCONNECT, as a pulled cable would (for tests)."""
        client = self._client
        if client is None:
            return
        sock = client._client.socket()
        if isinstance(sock, socket.socket):
            sock.shutdown(socket.SHUT_RDWR)

    def kill(self) -> None:
        """Die abruptly, as a unit losing power (for tests): no "offline", no reconnect, no steps.

        The connection is cut without a DISCONNECT, so the broker publishes the last will
        ("broken"); the unit stays where it is in the world.
        """
        self.killed = True
        self.drop_connection()
