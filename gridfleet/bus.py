"""The MQTT client every asyncio component uses: aiomqtt (on paho) set up from a broker URL."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import ssl
from collections.abc import AsyncIterator
from contextlib import AsyncExitStack, asynccontextmanager
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Self

import aiomqtt

from gridfleet.config import BrokerURL, owned_client_id, parse_broker_url, parse_brokers
from gridfleet.errors import ConfigError

# Without TCP_NODELAY a unit's direction, sent right after its state, waits for the broker's
# delayed ACK of the state (~40 ms): every step then waits on it (`gridfleet bench system`).
SOCKET_OPTIONS: tuple[tuple[int, int, int], ...] = ((socket.IPPROTO_TCP, socket.TCP_NODELAY, 1),)


def tls_context(ca_file: str | None) -> ssl.SSLContext:
    """A client TLS context that verifies the broker's certificate and name against `ca_file`
    (None: the system's trusted CAs); ConfigError when the file is missing or holds no CA."""
    try:
        return ssl.create_default_context(cafile=ca_file)
    except FileNotFoundError:
        raise ConfigError(
            f"{ca_file}: no such CA file ('gridfleet accounts tls' makes one)"
        ) from None
    except (ssl.SSLError, OSError) as exc:
        raise ConfigError(f"{ca_file}: cannot read a CA certificate from it ({exc})") from None


# QoS 1 messages in flight before paho holds the rest back until acknowledgements come: paho's
# 20 made a coordinator's step of 100 orders wait for five round trips to the broker.
MAX_INFLIGHT = 1000


# Every gridfleet client's MQTT keep-alive: a broker ends a session silent for 1.5 times it and
# sends the client's will (protocol.md §4.1).
KEEP_ALIVE_S = 10
DISCONNECT_S = 5.0  # the longest a client's DISCONNECT may take to go out before its socket closes


class Client(aiomqtt.Client):
    """aiomqtt's client, whose socket is closed when its block ends, however it ends.

    aiomqtt leaves it open when connecting or saying goodbye is cut short (cancelled: aiomqtt
    #377); paho then closes it when the client is collected, after the event loop has closed,
    and prints the loop's error (seen as `gridfleet up` stopped its feed mid-connect).
    """

    async def __aenter__(self) -> Self:
        """Connect; if that fails or is cancelled, close what was opened."""
        try:
            return await super().__aenter__()
        except BaseException:
            self._close_socket()
            raise

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Say goodbye, for at most DISCONNECT_S (aiomqtt waits without a limit), then close."""
        try:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(DISCONNECT_S):
                    await super().__aexit__(exc_type, exc, tb)
        finally:
            self._close_socket()

    def _close_socket(self) -> None:
        """Close the socket now, while the loop runs: aiomqtt unregisters it and its timer."""
        if self._client.socket() is not None:
            self._client._reset_sockets()

    def _on_socket_close(self, client: Any, userdata: Any, sock: Any) -> None:
        """aiomqtt's, unless the loop has closed (a socket opened as connecting was cancelled,
        in aiomqtt's connect thread, is closed when collected): nothing is left to unregister."""
        if not self._loop.is_closed():
            super()._on_socket_close(client, userdata, sock)


def make_client(
    url: str | BrokerURL,
    client_id: str,
    will: aiomqtt.Will | None = None,
    keepalive: int = KEEP_ALIVE_S,
    max_queued_outgoing: int | None = 10_000,
    timeout: float = 10.0,
    max_inflight: int = MAX_INFLIGHT,
) -> aiomqtt.Client:
    """An unconnected aiomqtt client for `url` (use it as `async with`).

    `timeout` bounds connecting, and every call that is not given a timeout of its own. Logging
    in with an account, the client id is one that account owns (`owned_client_id`).
    """
    broker = url if isinstance(url, BrokerURL) else parse_broker_url(url)
    client = Client(
        hostname=broker.host,
        port=broker.port,
        identifier=owned_client_id(broker.username, client_id),
        transport=broker.transport,  # type: ignore[arg-type]
        websocket_path=broker.path if broker.websocket else None,
        username=broker.username,
        password=broker.password,
        will=will,
        keepalive=keepalive,
        clean_session=True,
        max_queued_outgoing_messages=max_queued_outgoing,
        socket_options=SOCKET_OPTIONS,
        tls_context=tls_context(broker.ca_file) if broker.tls else None,
        timeout=timeout,
        max_inflight_messages=max_inflight,
    )
    # A coordinator sends a step's orders to hundreds of units at once, each publish awaiting
    # its own acknowledgement: that many in flight is the normal case, not a sign of trouble.
    client.pending_calls_threshold = max_inflight
    return client


log = logging.getLogger("gridfleet.bus")


@dataclass(frozen=True)
class Reached:
    """The broker of a list that `reach_first` got on, and those before it that did not answer
    (as messages show them: never a password)."""

    client: aiomqtt.Client
    broker: str
    index: int  # its place in the list, from 0
    count: int  # brokers in the list
    missed: tuple[str, ...] = ()

    def __str__(self) -> str:
        if self.count == 1:
            return self.broker
        tail = f"; {', '.join(self.missed)} did not answer" if self.missed else ""
        return f"{self.broker} ({self.index + 1} of {self.count}{tail})"


@asynccontextmanager
async def reach_first(urls: str, client_id: str, **options: Any) -> AsyncIterator[Reached]:
    """connect_first's client, with which broker of the list it is on (`Reached`)."""
    brokers = parse_brokers(urls)  # a bad list is a ConfigError before anything connects
    failures: list[str] = []
    missed: list[str] = []
    for index, broker in enumerate(brokers):
        stack = AsyncExitStack()
        try:
            client = await stack.enter_async_context(make_client(broker, client_id, **options))
        except aiomqtt.MqttError as exc:
            if len(brokers) == 1:
                raise
            missed.append(str(broker))
            failures.append(f"{broker}: {exc}")
            if index + 1 < len(brokers):  # the last one's is in the error raised below
                log.info("broker %s: %s; trying the next", broker, exc)
            continue
        async with stack:
            yield Reached(client, str(broker), index, len(brokers), tuple(missed))
        return
    raise aiomqtt.MqttError("no broker answered: " + "; ".join(failures))


@asynccontextmanager
async def connect_first(urls: str, client_id: str, **options: Any) -> AsyncIterator[aiomqtt.Client]:
    """A client connected to the first broker of `urls` (a comma-separated list, or one URL)
    that answers, in the list's order; MqttError naming each when none does.

    `options` are make_client's. With one URL, its own error is raised as it came.
    """
    async with reach_first(urls, client_id, **options) as reached:
        yield reached.client
