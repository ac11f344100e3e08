"""The amqtt broker gridfleet embeds, mended where amqtt 0.12.1 lets one client hurt the others."""

# amqtt is untyped: its objects are `Any` here. Every override names the amqtt 0.12.1 behaviour
# it changes; check them again when amqtt is upgraded.

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
import weakref
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

from amqtt.adapters import (
    StreamReaderAdapter,
    StreamWriterAdapter,
    WebSocketsReader,
    WebSocketsWriter,
)
from amqtt.broker import Action, Broker
from amqtt.errors import MQTTError
from amqtt.mqtt.connack import NOT_AUTHORIZED, ConnackPacket
from amqtt.mqtt.protocol.broker_handler import BrokerProtocolHandler
from amqtt.mqtt.publish import PublishPacket
from amqtt.utils import gen_client_id

from gridfleet.broker import origins
from gridfleet.broker.gate import Gate
from gridfleet.broker.limits import Limits
from gridfleet.broker.quiet import GONE, quiet_normal_closes
from gridfleet.broker.routing import Subscriptions
from gridfleet.broker.stats import BrokerFigures, BrokerStats
from gridfleet.session_login import read_session_password

log = logging.getLogger("gridfleet.broker")


_TAKEOVER_WAIT_S = 5.0  # how long a newcomer waits for the connection it displaces to end
_HANDLER_STOP_S = 1.0  # how long a connection's handler may take to stop before it is hung up on
_PRUNE_FLOOR = 1024  # finished deliveries amqtt may keep before we sweep them out
_YIELD_EVERY = 64  # messages routed in a row before other tasks get a turn
_BROADCAST_STOP_S = 5.0  # at shutdown, how long deliveries still under way may take
KEEP_ALIVE_GRACE = 1.5  # a client silent this many keep-alive periods is gone (MQTT-3.1.2-24)
_REFUSAL_LOG_S = 1.0  # refused CONNECTs: at most one log line this often (a flood is one line/s)


@dataclass
class Backlog:
    """One connection's live messages not yet written out (QoS 0) or acknowledged (QoS 1)."""

    client_id: str
    messages: int = 0
    bytes: int = 0
    dropped: int = 0  # messages refused because the backlog was full

    def admit(self, size: int, limits: Limits) -> bool:
        """Count in a message of `size` bytes, or count it dropped when the backlog is full."""
        full = self.messages >= limits.max_queued_messages or (
            self.messages > 0 and self.bytes + size > limits.max_queued_bytes
        )
        if full:
            self.dropped += 1
            return False
        self.messages += 1
        self.bytes += size
        return True

    def release(self, size: int) -> None:
        """Count out a message that was written out, acknowledged, or abandoned."""
        self.messages -= 1
        self.bytes -= size


def make_broker(
    config: dict[str, Any],
    *,
    gate: Gate | None = None,
    limits: Limits | None = None,
    ws_origins: tuple[str, ...] = (),
) -> GridfleetBroker:
    """An amqtt broker for `config` (amqtt's configuration dictionary) with these limits; with a
    `gate`, only its accounts get in (`config` then carries their topic rules, no auth plugin);
    `ws_origins`: web pages let in besides those on the broker's own host."""
    quiet_normal_closes()
    return GridfleetBroker(config, limits or Limits(), gate, ws_origins)


class _GuardedReader:
    """A connection's amqtt reader that hangs up, at its fixed header, on a packet over the limit."""

    # amqtt 0.12.1 has no packet size limit: it reads a PUBLISH body of any remaining length (up to
    # the protocol's 256 MiB) into memory, then relays and retains it. It reads each fixed header a
    # byte at a time and then exactly the body's remaining length, so this reader can follow the
    # packet boundaries and refuse before the body is read; amqtt then sees the end of the stream.

    def __init__(self, reader: Any, hang_up: Callable[[], object], limit: int, peer: str) -> None:
        self._reader = reader
        self._hang_up = hang_up
        self._limit = limit
        self.peer = peer
        self.client_id: str | None = None  # known once CONNECT is read
        self._header = bytearray()  # the fixed header read so far
        self._left = 0  # bytes of the current packet's body amqtt has not read yet
        self.closed = False

    async def read(self, n: int = -1) -> bytes:
        """Up to `n` bytes, as amqtt's ReaderAdapter; b"" once the connection is refused."""
        if self.closed:
            return b""
        if self._left == 0:  # at a fixed header: amqtt reads it one byte at a time
            if n != 1:
                return self._refuse(f"a read of {n} bytes where a packet header starts")
            data: bytes = await self._reader.read(1)
            if data:
                self._header += data
                if len(self._header) > 1 and not data[0] & 0x80:  # the last length byte
                    return self._end_of_header(data)
                if len(self._header) > 5:  # amqtt would refuse it too (MQTT-2.2.3)
                    return self._refuse("a remaining length of more than 4 bytes")
            return data
        if n < 0 or n > self._left:  # a malformed packet: amqtt lost track of its boundaries
            return self._refuse(f"a read of {n} bytes with {self._left} left in the packet")
        data = await self._reader.read(n)
        self._left -= len(data)
        return data

    def _end_of_header(self, last: bytes) -> bytes:
        body = sum((b & 0x7F) << (7 * i) for i, b in enumerate(self._header[1:]))
        size = len(self._header) + body
        self._header.clear()
        if size > self._limit:
            return self._refuse(f"a {size}-byte packet, over the {self._limit}-byte limit")
        self._left = body
        return last

    def _refuse(self, why: str) -> bytes:
        who = f"client {self.client_id}" if self.client_id else "a client"
        log.warning("broker: %s from %s sent %s: disconnected", who, self.peer, why)
        self.hang_up()
        return b""

    def hang_up(self) -> None:
        """Close the connection now, without waiting for the client to read what is pending."""
        self.closed = True
        self._hang_up()

    def feed_eof(self) -> None:
        """As amqtt's ReaderAdapter."""
        self._reader.feed_eof()


class _Outlet:
    """A client's handler as amqtt's delivery code sees it: live messages pass its Backlog."""

    # amqtt 0.12.1 starts one task per message and subscriber; for a subscriber that does not read
    # they wait for ever, each holding its message, so the broker grows without bound. Here a
    # message past the backlog's limit is dropped instead, and logged once per connection.

    def __init__(self, handler: Any, backlog: Backlog, limits: Limits, stats: BrokerStats) -> None:
        self._handler = handler
        self._backlog = backlog
        self._limits = limits
        self._stats = stats

    def mqtt_publish(
        self, topic: str, data: bytes, qos: int, retain: bool, ack_timeout: int | None = None
    ) -> Any:
        """A future of the delivery (a coroutine for retained replays, as amqtt expects)."""
        if retain:
            # amqtt 0.12.1 sets retain only when it replays retained messages to a subscriber:
            # bounded by the retained store, one subscription at a time (it awaits each replay
            # before reading the client's next packet), and never dropped.
            return self._handler.mqtt_publish(topic, data, qos, retain, ack_timeout)
        size = len(data)
        backlog = self._backlog
        if qos == 0 and self._write_now(topic, data):
            return _done()
        if not backlog.admit(size, self._limits):
            self._stats.dropped += 1
            if backlog.dropped == 1:
                log.warning(
                    "broker: client %s is not reading: dropping its messages beyond %d queued "
                    "(%d bytes), first on %s (logged once per connection)",
                    backlog.client_id,
                    backlog.messages,
                    backlog.bytes,
                    topic,
                )
            return _done()
        # amqtt wraps this in asyncio.ensure_future, which returns a task as it is; counting out
        # on completion also covers a task cancelled before it ever ran.
        task = asyncio.ensure_future(self._send(topic, data, qos, ack_timeout))
        task.add_done_callback(lambda _: backlog.release(size))
        return task

    def _write_now(self, topic: str, data: bytes) -> bool:
        """Write a QoS 0 message to the socket at once, when that keeps order and costs nothing.

        amqtt 0.12.1 delivers each message to each subscriber in a task of its own (wait_for,
        a write lock, drain): at a fleet's thousands of messages a second that bookkeeping was
        most of the broker's time. A QoS 0 message needs none of it while the client keeps up:
        nothing of its is queued behind (so order holds) and its socket takes what is written
        (asyncio buffers nothing). Otherwise the queued path below, with its limits, takes it.
        """
        writer = getattr(self._handler, "writer", None)
        if not isinstance(writer, StreamWriterAdapter):
            return False  # websockets (the page) frame each message in drain: the queued path
        if writer.is_closed or self._backlog.messages:
            return False
        transport = writer._writer.transport
        if transport.is_closing() or transport.get_write_buffer_size():
            return False
        packet = PublishPacket.build(topic, bytes(data), None, False, 0, False)
        writer.write(packet.to_bytes())
        return True

    async def _send(self, topic: str, data: bytes, qos: int, ack_timeout: int | None) -> None:
        # Returns nothing: amqtt keeps finished tasks a while, and the message is not needed.
        # amqtt 0.12.1 gives a QoS 1 message up after 5 s without PUBACK, logging a warning; its
        # broadcast loop would log each again, with a traceback, as a failed task.
        # A client that has gone (a reloaded browser tab) has nothing more to receive.
        with contextlib.suppress(TimeoutError, *GONE):
            await self._handler.mqtt_publish(topic, data, qos, False, ack_timeout)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._handler, name)


def _done() -> asyncio.Future[None]:
    """A delivery already over (written at once, or dropped): what amqtt awaits for it."""
    done: asyncio.Future[None] = asyncio.get_running_loop().create_future()
    done.set_result(None)
    return done


def _peer(info: Iterable[Any] | None) -> str:
    host, port, *_ = info or ("?", "?")
    return f"{host}:{port}"


class GridfleetBroker(Broker):  # type: ignore[misc]
    """amqtt's Broker with gridfleet's limits, and its client-id takeover behind authentication."""

    def __init__(
        self,
        config: dict[str, Any],
        limits: Limits | None = None,
        gate: Gate | None = None,
        ws_origins: tuple[str, ...] = (),
    ) -> None:
        super().__init__(config)
        self.gate = gate  # None: amqtt's auth plugins decide (anonymous on loopback)
        self.ws_origins = ws_origins  # web pages let in besides the broker's own host
        self._refusals_logged_at = -_REFUSAL_LOG_S
        self._refusals_unlogged = 0
        self._subscriptions = Subscriptions()  # empty, as amqtt made it
        self.limits = limits or Limits()
        self._backlogs: weakref.WeakKeyDictionary[Any, Backlog] = weakref.WeakKeyDictionary()
        self._ended: weakref.WeakKeyDictionary[Any, asyncio.Event] = weakref.WeakKeyDictionary()
        # Connections made with a page session's password: hung up on at the session's end.
        self._session_ends: weakref.WeakKeyDictionary[Any, asyncio.TimerHandle] = (
            weakref.WeakKeyDictionary()
        )
        # Client id -> the accounts of CONNECTs taking it over now (from the gate's look until
        # their session is amqtt's): no other account's slips in while one waits in _displace.
        self._claims: dict[str, list[str | None]] = {}
        self._prune_at = _PRUNE_FLOOR
        self.stats = BrokerStats()
        self._shutting_down = False

    def figures(self) -> BrokerFigures:
        """Its totals and its state now (call it on the broker's loop)."""
        backlogs = list(self._backlogs.values())
        stats = self.stats
        return BrokerFigures(
            clients=sum(s.transitions.state == "connected" for s, _ in self._sessions.values()),
            sessions=len(self._sessions),
            queued_messages=sum(b.messages for b in backlogs),
            queued_bytes=sum(b.bytes for b in backlogs),
            retained=len(self._retained_messages),
            routing=self._broadcast_queue.qsize(),
            received=stats.received,
            delivered=stats.delivered,
            dropped=stats.dropped,
            refused=dict(stats.refused),
        )

    def bound_port(self, listener: str = "default") -> int:
        """The port `listener` listens on (the one the OS picked for port 0)."""
        return int(self._servers[listener].instance.sockets[0].getsockname()[1])

    def backlog(self, client_id: str) -> Backlog | None:
        """A copy of connected client `client_id`'s backlog (None: not connected or no message)."""
        entry = self._sessions.get(client_id)
        found = None if entry is None else self._backlogs.get(entry[1])
        return None if found is None else replace(found)

    # ---- packet size -------------------------------------------------------------------------

    async def stream_connected(self, reader: Any, writer: Any, listener_name: str) -> None:
        """A TCP (or TLS) connection: amqtt's, with the packet size guard on its reader."""
        guard = _GuardedReader(
            StreamReaderAdapter(reader),
            writer.transport.abort,
            self.limits.max_packet_bytes,
            _peer(writer.get_extra_info("peername")),
        )
        await self._client_connected(listener_name, guard, StreamWriterAdapter(writer))

    async def ws_connected(self, websocket: Any, listener_name: str) -> None:
        """A websocket connection: amqtt's, with the packet size guard on its reader; a page from
        another site (its Origin) or a DNS-rebinding one (its Host) is closed at once."""
        headers = websocket.request.headers if websocket.request is not None else {}
        refused = origins.refusal(
            headers.get("Host"),
            headers.get("Origin"),
            self.ws_origins,
            accounts=self.gate is not None,
        )
        if refused is not None:
            self.stats.refused["websocket"] += 1
            self._log_refusal(f"a websocket from {_peer(websocket.remote_address)}: {refused}")
            await websocket.close(1008, "origin not allowed")  # 1008: policy violation
            return
        # The websockets library caps one frame at 1 MiB, but amqtt joins frames into packets.
        guard = _GuardedReader(
            WebSocketsReader(websocket),
            websocket.transport.abort,
            self.limits.max_packet_bytes,
            _peer(websocket.remote_address),
        )
        await self._client_connected(listener_name, guard, WebSocketsWriter(websocket))

    # ---- authentication before takeover ------------------------------------------------------

    async def _initialize_client_session(
        self, reader: Any, writer: Any, remote_address: str, remote_port: int
    ) -> tuple[Any, Any]:
        """Read CONNECT, check the credentials, and only then take over an existing session."""
        # amqtt 0.12.1 deletes (clean session) or adopts (persistent session) the session of a
        # client already using the newcomer's client id as soon as it has read CONNECT, and checks
        # the credentials only afterwards: a stranger with a wrong password connecting as
        # `coordinator` cut the coordinator off. Its clean-session takeover also left the displaced
        # connection open without subscriptions, where MQTT-3.1.4-2 requires it be disconnected;
        # its persistent takeover could mark the adopted session disconnected under the newcomer.
        # The session bookkeeping after the check is amqtt's own, copied.
        peer = f"{remote_address}:{remote_port}"
        try:
            handler, incoming = await BrokerProtocolHandler.init_from_connect(
                reader, writer, self.plugins_manager
            )
        except Exception as exc:  # anything unreadable ends the connection
            # amqtt 0.12.1 left the socket open after some of these; close it.
            with contextlib.suppress(Exception):
                await writer.close()
            raise MQTTError(f"{peer}: no valid CONNECT ({exc!r})") from None
        refusal = await self._refusal(incoming, remote_address)
        if refusal is None and self.gate is not None and incoming.client_id:
            # Nothing is awaited from this look to the claim below: no CONNECT comes between.
            holder = self._holder(incoming.client_id)
            refusal = self.gate.takeover_refusal(incoming.username, incoming.client_id, holder)
        if refusal is not None:
            self.stats.refused["connect"] += 1
            self._log_refusal(f"{peer} (client id {incoming.client_id!r}): {refusal}")
            # A refused client may hang up first (over TLS a reset surfaced as a traceback).
            with contextlib.suppress(ConnectionError):
                await ConnackPacket.build(0, NOT_AUTHORIZED).to_stream(writer)
                await writer.close()
            raise MQTTError(f"{peer}: client id {incoming.client_id!r} not authorized")
        if isinstance(reader, _GuardedReader):
            reader.client_id = incoming.client_id
        claimed = incoming.client_id or None
        if claimed is not None:
            self._claims.setdefault(claimed, []).append(incoming.username)
        try:
            if claimed is not None:
                await self._displace(claimed)
            # The claim ends as this returns; amqtt's _handle_client_session then awaits only
            # _authenticate (below: it returns at once for this session, never suspending)
            # before it takes the session in.
            return await self._adopt_session(handler, incoming, reader)
        finally:
            if claimed is not None:
                self._unclaim(claimed, incoming.username)

    async def _adopt_session(self, handler: Any, incoming: Any, reader: Any) -> tuple[Any, Any]:
        """The session a CONNECT let in continues or starts, as amqtt 0.12.1 makes it."""
        # amqtt 0.12.1 from here on (plus will_retain and is_anonymous, which it did not carry
        # over to a resumed session).
        session = incoming
        kept = self._sessions.get(incoming.client_id) if incoming.client_id else None
        if kept is not None and kept[0].username != incoming.username and self.gate is not None:
            # Another account's session, kept while its client is away (an id no account owns:
            # the gate let this one in): never inherited, its subscriptions and queued orders
            # thrown away, and a fresh session starts. Kept for it, it would lock that id out
            # for good (amqtt never expires a session); binding the id protects it (accounts.py).
            await self._delete_session(incoming.client_id)
        if incoming.clean_session:
            if incoming.client_id:
                await self._delete_session(incoming.client_id)
            else:
                incoming.client_id = gen_client_id()
            incoming.parent = 0
        elif incoming.client_id in self._sessions:
            session = self._sessions[incoming.client_id][0]
            for name in (
                "will_flag",
                "will_message",
                "will_topic",
                "will_qos",
                "will_retain",
                "keep_alive",
                "username",
                "password",
                "is_anonymous",
            ):
                setattr(session, name, getattr(incoming, name))
            session.parent = 1
        else:
            incoming.parent = 0
        delay = self.config.get("timeout-disconnect-delay", 0)
        if session.keep_alive > 0:
            # MQTT-3.1.2-24: silent for one and a half keep-alive periods, a client is gone.
            session.keep_alive *= KEEP_ALIVE_GRACE
            if isinstance(delay, int):
                session.keep_alive += delay
        if isinstance(reader, _GuardedReader):
            # amqtt 0.12.1 waits that long for each packet, then does nothing and waits again
            # (its handle_read_timeout is empty): a unit whose link died without a FIN stayed
            # connected, its will unsent and its `online` standing, for good.
            handler.handle_read_timeout = partial(
                self._keep_alive_expired, reader, session.client_id, session.keep_alive
            )

        session.attributes["gridfleet.authenticated"] = True  # for _authenticate, next
        self._ended[handler] = asyncio.Event()
        claim = read_session_password(incoming.password)
        if claim is not None and self.gate is not None and isinstance(reader, _GuardedReader):
            # A page session's password ends with the session: so does a connection made with it.
            left = max(0.0, claim.expires - self.gate.wall())
            self._session_ends[handler] = asyncio.get_running_loop().call_later(
                left, reader.hang_up
            )
        return handler, session

    def _keep_alive_expired(self, reader: _GuardedReader, client_id: str, after_s: float) -> None:
        """Close a connection silent for 1.5 keep-alive periods: amqtt then sends its will."""
        log.warning(
            "broker: client %s from %s silent for %.1f s (1.5 keep-alive periods): disconnected",
            client_id,
            reader.peer,
            after_s,
        )
        reader.hang_up()

    def _log_refusal(self, what: str) -> None:
        """Log a refusal (a CONNECT, a websocket, a message dropped): at most one line a second,
        saying how many went unlogged, so a flood is not a flood of the log too."""
        now = time.monotonic()
        if now - self._refusals_logged_at < _REFUSAL_LOG_S:
            self._refusals_unlogged += 1
            return
        more = self._refusals_unlogged
        also = f" ({more} more refused in the last {now - self._refusals_logged_at:.0f} s)"
        log.warning("broker: refused %s%s", what, also if more else "")
        self._refusals_logged_at, self._refusals_unlogged = now, 0

    async def _refusal(self, incoming: Any, address: str) -> str | None:
        """Why this CONNECT is refused (None: let it in): its account, client id and will."""
        if self.gate is None:
            # amqtt's _authenticate ignores its listener argument in 0.12.1.
            if not await super()._authenticate(incoming, None):
                return "not authorized"
            return None
        refusal = self.gate.refusal(
            incoming.username, incoming.password, incoming.client_id or "", address
        )
        if refusal is not None:
            return refusal
        # amqtt 0.12.1 sends and retains a will without asking the topic rules: a device's will
        # on the stop's latch released an operator's stop. A will goes out only as a publish of
        # the account's own would; one it could not publish is refused now, not dropped later,
        # so the client learns at once that its will would never be heard.
        if incoming.will_flag and not await self._topic_filtering(
            incoming, topic=incoming.will_topic, action=Action.PUBLISH
        ):
            return f"{incoming.username!r} may not publish its will's topic {incoming.will_topic!r}"
        # Nor what it says: amqtt sends a will past _handle_message_delivery's checks below (as
        # found: a will naming `operator` was audited as the operator's act, verified).
        if incoming.will_flag:
            why = self.gate.refused_will(
                incoming.username, incoming.will_topic, bytes(incoming.will_message or b"")
            )
            if why is not None:
                return f"its will on {incoming.will_topic!r}: {why}"
        return None

    async def _handle_message_delivery(
        self, client_session: Any, handler: Any, wait_deliver: asyncio.Future[Any]
    ) -> bool:
        """amqtt's, after the gate's word on what the message claims (its sender, its rate)."""
        message = wait_deliver.result()
        if (
            self.gate is not None
            and message is not None
            and message.topic == self.gate.revoke_topic
        ):
            await self._revoke(client_session, bytes(message.data or b""))
            return True  # the broker's alone: passed to nobody
        if self.gate is not None and message is not None and message.topic:
            refused = self.gate.refused_publish(
                client_session.username,
                client_session.client_id or "",
                message.topic,
                bytes(message.data or b""),
            )
            if refused is not None:
                who = f"client {client_session.client_id} ({client_session.username})"
                self.stats.refused["publish"] += 1
                self._log_refusal(f"a message of {who} on {message.topic}: {refused}")
                return True  # dropped; the connection stays
        return bool(await super()._handle_message_delivery(client_session, handler, wait_deliver))

    async def _revoke(self, client_session: Any, data: bytes) -> None:
        """A dashboard's revocation: its session's password opens nothing more, and every
        connection that logged in with it is closed now."""
        assert self.gate is not None
        revocation = self.gate.revocation(client_session.username, data)
        if revocation.sid is None:
            who = f"client {client_session.client_id} ({client_session.username})"
            self.stats.refused["publish"] += 1
            self._log_refusal(f"a message of {who} on {self.gate.revoke_topic}: {revocation.words}")
            return
        closed = 0
        for session, handler in list(self._sessions.values()):
            claim = read_session_password(session.password)
            if claim is None or claim.sid != revocation.sid:
                continue
            if session.transitions.state != "connected" or handler is None:
                continue
            closed += 1
            if isinstance(handler.reader, _GuardedReader):
                handler.reader.hang_up()
            await handler.handle_connection_closed()  # as a takeover: amqtt ends its session
        log.info("broker: %s; %d connection(s) with its password closed", revocation.words, closed)

    async def _authenticate(self, session: Any, listener: Any) -> bool:
        """amqtt's check, skipped for the session just authenticated above (Argon2 costs ~30 ms)."""
        if session.attributes.pop("gridfleet.authenticated", False):
            return True
        return bool(await super()._authenticate(session, listener))

    def _holder(self, client_id: str) -> str | None:
        """The account holding `client_id`: a CONNECT taking it over now, or a connected session
        (None: nobody; a session kept while its client is away holds nothing)."""
        claims = self._claims.get(client_id)
        if claims:
            return claims[0]
        entry = self._sessions.get(client_id)
        if entry is None:
            return None
        session = entry[0]
        if session.transitions.state == "connected":
            return None if session.username is None else str(session.username)
        return None  # away: another account starts afresh over it (_adopt_session)

    def _unclaim(self, client_id: str, username: str | None) -> None:
        """A CONNECT's claim on `client_id` ends: its session is amqtt's now, or it failed."""
        claims = self._claims.get(client_id, [])
        if username in claims:
            claims.remove(username)
        if not claims:
            self._claims.pop(client_id, None)

    async def _displace(self, client_id: str) -> None:
        """Disconnect the connection holding `client_id` and wait until amqtt has let it go."""
        entry = self._sessions.get(client_id)
        if entry is None or entry[0].transitions.state != "connected":
            return
        old = entry[1]
        log.info("broker: client id %s taken over by a new connection", client_id)
        ended = self._ended.get(old)
        if isinstance(old.reader, _GuardedReader):
            old.reader.hang_up()  # at once, even if it does not read what is pending
        # As amqtt's own takeover: its message loop sees a disconnection and ends the session
        # (sending its will) before the newcomer's first message.
        await old.handle_connection_closed()
        if ended is not None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(ended.wait(), _TAKEOVER_WAIT_S)

    # ---- ended sessions ------------------------------------------------------------------------

    async def shutdown(self) -> None:
        """amqtt's; from here on every session is cleaned up, connected or not."""
        self._shutting_down = True
        await super().shutdown()

    async def _cleanup_session(self, client_id: str) -> None:
        """amqtt's, for an ended session only (or any, at shutdown): never a newcomer's."""
        # amqtt 0.12.1's session monitor lists the ended clean sessions, then cleans each up in
        # turn by client id, awaiting each: a client back under one of those ids meanwhile had
        # its new, connected session taken and its connection stopped.
        entry = self._sessions.get(client_id)
        ended = entry is None or entry[0].transitions.state == "disconnected"
        if ended or self._shutting_down:
            await super()._cleanup_session(client_id)

    async def _del_all_subscriptions(self, session: Any) -> None:
        """Drop the subscriptions of this session alone, not of another under its client id."""
        # amqtt 0.12.1 dropped every subscription held under the session's client id, after
        # awaiting the old connection's end: a client back under that id, which had subscribed
        # meanwhile, stayed connected but deaf (to the emergency stop too).
        for a_filter, holders in self._subscriptions.items():
            kept = [(held, qos) for held, qos in holders if held is not session]
            if len(kept) == len(holders):
                continue
            if kept:
                holders[:] = kept
            else:
                del self._subscriptions[a_filter]

    async def _stop_handler(self, handler: Any) -> None:
        """amqtt's, made sure to end: a handler that has not stopped after _HANDLER_STOP_S has its
        connection hung up on, which ends its reader."""
        # On Python 3.11 asyncio.wait_for loses a cancellation that arrives in the same turn as the
        # data it waits for; amqtt's reader loop (a wait_for per packet) then reads on and its
        # handler.stop() waits for that loop for good: the broker's shutdown hung, holding its
        # ports, on a connection busy at that moment (seen about once in ten restarts under load).
        stopping = asyncio.ensure_future(super()._stop_handler(handler))
        done, _ = await asyncio.wait({stopping}, timeout=_HANDLER_STOP_S)
        if not done and isinstance(handler.reader, _GuardedReader):
            log.debug("broker: a connection's handler did not stop: hanging up on it")
            handler.reader.hang_up()
        await stopping

    async def _handle_client_session(
        self,
        reader: Any,
        writer: Any,
        client_session: Any,
        handler: Any,
        server: Any,
        listener_name: str,
    ) -> None:
        """amqtt's; then tells a newcomer waiting in `_displace` that this connection ended."""
        try:
            await super()._handle_client_session(
                reader, writer, client_session, handler, server, listener_name
            )
        finally:
            ended = self._ended.pop(handler, None)
            if ended is not None:
                ended.set()
            timer = self._session_ends.pop(handler, None)
            if timer is not None:
                timer.cancel()

    # ---- per-client queue ----------------------------------------------------------------------

    def _get_handler(self, session: Any) -> Any:
        """The session's handler behind its backlog (amqtt 0.12.1 only publishes through this)."""
        handler = super()._get_handler(session)
        if handler is None:
            return None
        backlog = self._backlogs.get(handler)
        if backlog is None:
            backlog = self._backlogs[handler] = Backlog(str(session.client_id))
        return _Outlet(handler, backlog, self.limits, self.stats)

    async def _broadcast_loop(self) -> None:
        """amqtt's loop, without a task and a wait per message: each is routed as it is taken."""
        # amqtt 0.12.1 starts a task for every message, and waits on it and on the shutdown
        # future; a queue holding a burst is drained here in one go (yielding now and then).
        running: deque[asyncio.Future[Any]] = self._tasks_queue
        queue = self._broadcast_queue
        try:
            taken = 0
            while True:
                if queue.empty() or taken >= _YIELD_EVERY:
                    taken = 0
                    getter = asyncio.ensure_future(queue.get())
                    shutdown = self._broadcast_shutdown_waiter
                    await asyncio.wait([getter, shutdown], return_when=asyncio.FIRST_COMPLETED)
                    if shutdown.done():
                        getter.cancel()
                        return
                    broadcast = getter.result()
                else:
                    broadcast = queue.get_nowait()
                taken += 1
                try:
                    await self._route(broadcast, running)
                except Exception:  # one message that cannot be routed must not stop the rest
                    log.exception("broker: could not route a message on %s", broadcast["topic"])
                self._prune(running)
        finally:
            for task in running:
                task.cancel()
            if running:
                await asyncio.wait(running, timeout=_BROADCAST_STOP_S)

    async def _route(self, broadcast: dict[str, Any], running: deque[asyncio.Future[Any]]) -> None:
        """Deliver one message to every subscription it matches, as amqtt 0.12.1 does."""
        topic, data = broadcast["topic"], broadcast["data"]
        forced = broadcast.get("qos")  # amqtt delivers at the subscription's QoS unless forced
        checking = self.plugins_manager.is_topic_filtering_enabled()
        self.stats.received += 1
        for a_filter in self._subscriptions.matching(topic, self._matches):
            for session, sub_qos in tuple(self._subscriptions.get(a_filter, ())):
                qos = sub_qos if forced is None else forced
                if checking and not await self._topic_filtering(
                    session, topic=topic, action=Action.RECEIVE
                ):
                    continue
                if session.transitions.state != "connected":
                    # Kept for a persistent session that logged in, at QoS 1 and 2 (MQTT 3.1.2.4).
                    if not session.clean_session and qos in (1, 2) and not session.is_anonymous:
                        await self._retain_broadcast_message(broadcast, qos, session)
                    continue
                handler = self._get_handler(session)
                if handler is not None:
                    self.stats.delivered += 1
                    delivery = asyncio.ensure_future(
                        handler.mqtt_publish(topic, data, qos, retain=False)
                    )
                    if not delivery.done():
                        running.append(delivery)

    def _prune(self, running: deque[asyncio.Future[Any]]) -> None:
        """Drop finished deliveries once they pile up (amortised: when the deque has doubled)."""
        # amqtt 0.12.1 (_broadcast_loop) dropped finished deliveries only from the front of this
        # deque: one delivery stuck on a client that does not read kept every later one, of every
        # client, in memory.
        if len(running) <= self._prune_at:
            return
        pending = [t for t in running if not t.done()]
        for task in running:
            if task.done() and not task.cancelled() and task.exception() is not None:
                log.debug("broker: a delivery failed: %r", task.exception())
        running.clear()
        running.extend(pending)
        self._prune_at = max(_PRUNE_FLOOR, 2 * len(running))

    # ---- retained messages -------------------------------------------------------------------

    async def _publish_retained_messages_for_subscription(
        self, subscription: tuple[str, int], session: Any
    ) -> None:
        """amqtt's, only for filters the session itself holds."""
        # amqtt 0.12.1 replays, to every client that connects, the retained messages matching
        # *every* filter any client ever subscribed to (it loops over the broker-wide
        # subscription table instead of the session's own).
        holders = self._subscriptions.get(subscription[0], ())
        if any(s is session or s.client_id == session.client_id for s, _ in holders):
            await super()._publish_retained_messages_for_subscription(subscription, session)
