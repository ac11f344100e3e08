"""One MQTT endpoint for every long-running component: the session kept up, publishes by topic kind.

A component hands its endpoint what to say when it connects and leaves (last will, `online`,
`offline`), what to follow, and a handler for what arrives; the endpoint does the rest: connect,
subscribe, greet, receive, reconnect with back-off, and say goodbye on a clean stop. Decisions stay
in the component's core; this module only moves bytes.

A handler that raises (a bug) never takes the component off the broker, nor goes unheard: each
failure is counted (`handler_failures`), its traceback logged, and told on `errors` through the
component's `report` (the topic, and the exception's class alone: gridfleet/failures.py), the
first at once and then at most once a second per topic, with the count of those in between.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import Any

import aiomqtt

from gridfleet.bus import make_client
from gridfleet.config import parse_brokers
from gridfleet.failures import OTHER, FailureReports
from gridfleet.outbound import Outbound
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.endpoint")
GOODBYE_S = 5.0  # the longest a clean stop waits for its goodbye to be acknowledged
# A connection accepted and then dropped before the CONNACK (a broker going down, a proxy whose
# broker is down) is never refused: without a bound of its own the connect waits out aiomqtt's
# 10 s, and recovery after a broker restart took ~11 s (bench soak). Acknowledgements of
# subscriptions and publishes keep the longer bound: a loaded broker is slow, not gone.
CONNECT_S = 3.0
ACK_S = 10.0

Handler = Callable[[str, bytes], Awaitable[None]]
Hook = Callable[[], Awaitable[None]]
# A failure report: (the topic of the message a handler failed on, the reason) -> what to send
# on `errors` (stamped by the component, as its other reports).
Report = Callable[[str, str], Outbound]


def as_will(out: Outbound) -> aiomqtt.Will:
    """`out` as an MQTT last will."""
    return aiomqtt.Will(out.topic, out.payload, qos=out.qos, retain=out.retain)


async def _finish(work: Awaitable[Any]) -> Any:
    return await work


async def send(client: aiomqtt.Client, out: Outbound, ack_s: float = ACK_S) -> None:
    """Publish `out` on `client` with its QoS and retain flag (a QoS 1 waits `ack_s` at most)."""
    await client.publish(out.topic, out.payload, qos=out.qos, retain=out.retain, timeout=ack_s)


def payload_of(message: aiomqtt.Message) -> bytes:
    """A received message's payload as bytes (aiomqtt may hand over str, numbers or None)."""
    payload = message.payload
    if isinstance(payload, bytes | bytearray):
        return bytes(payload)
    return b"" if payload is None else str(payload).encode()


@dataclass(frozen=True)
class Backoff:
    """Seconds between connection attempts: doubling from `first` up to `most`."""

    first: float = 0.1
    most: float = 5.0


class Endpoint:
    """A component's MQTT session, kept up until stopped: `await endpoint.run(stop, handler)`."""

    def __init__(
        self,
        url: str,
        client_id: str,
        *,
        name: str | None = None,
        subscriptions: Callable[[], Sequence[tuple[str, int]]] = tuple,
        will: Callable[[], Outbound] | None = None,
        online: Callable[[], Outbound] | None = None,
        offline: Callable[[], Outbound] | None = None,
        backoff: Backoff = Backoff(),
        ack_s: float = ACK_S,
        component: str | None = None,
        report: Report | None = None,
    ) -> None:
        self.url = url
        # A send not acknowledged within this ends the session (then it is sent again on the next).
        self.ack_s = ack_s
        # One broker, or the nodes of a cluster, on one at a time; a bad list is refused now,
        # not retried forever.
        self._brokers = parse_brokers(url)
        self._at = 0  # the one it is on, or tries next
        self.client_id = client_id
        self.name = name or client_id
        self._subscriptions = subscriptions
        self._will = will
        self._online = online
        self._offline = offline
        self.backoff = backoff
        self.online = asyncio.Event()  # set while connected, subscribed and announced
        # Whether the message the handler is given now is one the broker kept and replayed on
        # subscribing (MQTT's retain flag on delivery), not one published since: read it before
        # the handler's first await (the coordinator does, for the stop across a failover).
        self.retained = False
        self.connects = 0  # sessions begun (tests watch reconnects)
        self.killed = False
        self._client: aiomqtt.Client | None = None
        self._broken: asyncio.Event | None = None  # set when a send finds the session dead
        # Failed handlers: told on `errors` by `report` (None: counted and logged only), as
        # `component` (its kind: coordinator, unit, vda5050, device, alerts).
        self._report = report
        self.failures = FailureReports(component or OTHER)
        self._reporting: set[asyncio.Task[None]] = set()
        self._flushing: asyncio.Task[None] | None = None

    async def run(
        self,
        shutdown: asyncio.Event,
        handle: Handler,
        *,
        on_connect: Hook | None = None,
        on_disconnect: Callable[[str], None] | None = None,
        during: Callable[[asyncio.Event], Awaitable[None]] | None = None,
        on_stop: Hook | None = None,
    ) -> None:
        """Stay connected until `stop` is set (then say `offline`) or `kill()`.

        `on_connect` runs once subscribed and announced, `during` for as long as each session
        lasts, `on_disconnect` with the reason whenever a session is lost, `on_stop` on a clean
        stop just before `offline`.
        """
        delay = self.backoff.first
        tried = 0  # brokers tried since the last session, in this round of the list
        try:
            while not shutdown.is_set() and not self.killed:
                try:
                    await self._session(shutdown, handle, on_connect, during, on_stop)
                    delay, tried = self.backoff.first, 0
                except aiomqtt.MqttError as exc:
                    if self.killed:
                        return
                    was_on = self._client is not None
                    if was_on or delay == self.backoff.first:
                        log.warning("%s: broker %s: %s; retrying", self.name, self.where, exc)
                    self._lose()
                    if on_disconnect is not None:
                        on_disconnect(str(exc))
                    if was_on:
                        delay, tried = self.backoff.first, 0
                    # The next broker of a list at once; once each was tried, wait and go round.
                    self._at = (self._at + 1) % len(self._brokers)
                    tried += 1
                    if tried < len(self._brokers):
                        continue
                    tried = 0
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(shutdown.wait(), delay)
                    delay = min(delay * 2, self.backoff.most)
        finally:
            for task in (*self._reporting, self._flushing):
                if task is not None:
                    await cancel_and_wait(task)

    async def _session(
        self,
        shutdown: asyncio.Event,
        handle: Handler,
        on_connect: Hook | None,
        during: Callable[[asyncio.Event], Awaitable[None]] | None,
        on_stop: Hook | None,
    ) -> None:
        will = as_will(self._will()) if self._will is not None else None
        broker = self._brokers[self._at]
        async with make_client(broker, self.client_id, will=will, timeout=CONNECT_S) as client:
            for topic, qos in self._subscriptions():
                await client.subscribe(topic, qos=qos, timeout=ACK_S)
            self._client = client
            self._broken = asyncio.Event()
            self.connects += 1
            if len(self._brokers) > 1 or self.connects == 1:
                log.info("%s: on broker %s", self.name, self.where)
            if self._online is not None:
                await self.publish(self._online())
            if on_connect is not None:
                await on_connect()
            self.online.set()
            work = during(shutdown) if during is not None else shutdown.wait()
            waits: set[asyncio.Task[Any]] = {
                asyncio.create_task(self._receive(client, handle)),
                asyncio.create_task(self._broken.wait()),
                asyncio.create_task(_finish(work)),
            }
            stopper = asyncio.create_task(shutdown.wait())
            try:
                done, _ = await asyncio.wait({*waits, stopper}, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for task in (*waits, stopper):
                    await cancel_and_wait(task)
            for task in done:
                error = None if task.cancelled() else task.exception()
                if error is not None:
                    raise error
            if self._broken.is_set() or not shutdown.is_set():
                raise aiomqtt.MqttError("the session ended")
            # Bounded: a broker stopping at the same moment never acknowledges the goodbye, and
            # each QoS 1 publish would wait out aiomqtt's 10 s timeout (seen with SIGTERM to
            # broker and coordinator together); the last will covers a goodbye that did not go.
            with contextlib.suppress(aiomqtt.MqttError, TimeoutError):
                async with asyncio.timeout(GOODBYE_S):
                    if on_stop is not None:
                        await on_stop()
                    if self._offline is not None:
                        await send(client, self._offline())
            self._lose()

    async def _receive(self, client: aiomqtt.Client, handle: Handler) -> None:
        async for message in client.messages:
            self.retained = bool(message.retain)
            try:
                await handle(message.topic.value, payload_of(message))
            except aiomqtt.MqttError:
                raise
            except Exception as exc:  # a bug must not take the component off the broker
                self._failed(message.topic.value, exc)
        raise aiomqtt.MqttError("message stream ended")

    @property
    def where(self) -> str:
        """The broker it is on, or tries next, for messages: never the password."""
        return str(self._brokers[self._at])

    @property
    def brokers(self) -> str:
        """The broker it uses, or of a list each it may be on, for messages (not the password)."""
        if len(self._brokers) == 1:
            return self.where
        return "one of " + ", ".join(str(broker) for broker in self._brokers)

    @property
    def handler_failures(self) -> int:
        """Messages its handler raised on, since it started (told on `errors` or not)."""
        return self.failures.failures

    def _failed(self, topic: str, exc: Exception) -> None:
        """A handler raised on a message on `topic`: counted, logged, told on `errors` (soon)."""
        try:
            reason = self.failures.failed(topic, type(exc).__name__, time.monotonic())
            if reason is None:  # told with the next report on this topic
                log.debug("%s: failed again on %s", self.name, topic, exc_info=exc)
                self._flush_later()
                return
            log.error("%s: failed to handle a message on %s", self.name, topic, exc_info=exc)
            self._tell(topic, reason)
        except Exception:  # reporting must never take the receiver down
            log.exception("%s: could not report a failure on %s", self.name, topic)

    def _tell(self, topic: str, reason: str) -> None:
        """Send the report about `topic` on `errors`, without holding up the receiver."""
        if self._report is None:
            return
        task = asyncio.create_task(self._send_report(topic, reason))
        self._reporting.add(task)
        task.add_done_callback(self._reporting.discard)

    async def _send_report(self, topic: str, reason: str) -> None:
        try:
            assert self._report is not None
            await self.publish(self._report(topic, reason))
        except Exception:  # a report that cannot be made or sent is lost, never raised
            log.exception("%s: could not report a failure on %s", self.name, topic)

    def _flush_later(self) -> None:
        """Tell the failures held back once their time comes (one timer for all topics)."""
        if self._report is not None and (self._flushing is None or self._flushing.done()):
            self._flushing = asyncio.create_task(self._flush())

    async def _flush(self) -> None:
        try:
            while (at := self.failures.next_due(time.monotonic())) is not None:
                await asyncio.sleep(max(0.0, at - time.monotonic()) + 0.001)  # the report's time
                for topic, reason in self.failures.due(time.monotonic()):
                    self._tell(topic, reason)
        except Exception:  # never raised: the count stays, the next failure tries again
            log.exception("%s: could not report the failures held back", self.name)

    def _lose(self) -> None:
        self._client = None
        self.online.clear()

    @property
    def connected(self) -> bool:
        """Whether a session is up (messages can be sent)."""
        return self._client is not None

    async def publish(self, out: Outbound) -> bool:
        """Send `out` on the live session; False when there is none or the send failed."""
        client = self._client
        if client is None:
            return False
        try:
            await send(client, out, self.ack_s)
        except aiomqtt.MqttError as exc:
            # A send still pending on a connection already replaced (its acknowledgement timed
            # out long after a reconnect) says nothing about the live one: leave that alone.
            if client is self._client and self._broken is not None:
                log.debug("%s: send failed (%s); the session is over", self.name, exc)
                self._broken.set()
            return False
        return True

    def drop(self) -> None:
        """Cut the TCP connection without a DISCONNECT, as a pulled cable would (for tests)."""
        client = self._client
        if client is None:
            return
        sock = client._client.socket()
        if isinstance(sock, socket.socket):
            sock.shutdown(socket.SHUT_RDWR)

    def kill(self) -> None:
        """Die abruptly, as a device losing power: no `offline`, no reconnect; the will goes out."""
        self.killed = True
        self.drop()
