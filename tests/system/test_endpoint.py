"""The one MQTT endpoint every component uses: will, online/offline, resubscribe, back-off."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import pytest

from gridfleet.endpoint import CONNECT_S, GOODBYE_S, Backoff, Endpoint
from gridfleet.outbound import Outbound
from gridfleet.protocol import Topics
from gridfleet.system.broker_thread import BrokerThread

from support.probe import MqttProbe
from support.wait import async_wait_for

pytestmark = pytest.mark.every_broker  # wills, resubscription and back-off against the broker


def make(url: str, topics: Topics) -> Endpoint:
    """An endpoint that follows the stop topic and says who it is on `devices/d1/connection`."""
    where = topics.device("device_connection", "d1")
    return Endpoint(
        url,
        "endpoint-test",
        subscriptions=lambda: [(topics.fleet("estop"), 1)],
        will=lambda: Outbound(where, b"broken", 1, True),
        online=lambda: Outbound(where, b"online", 1, True),
        offline=lambda: Outbound(where, b"offline", 1, True),
        backoff=Backoff(0.05, 0.2),
    )


@asynccontextmanager
async def running(
    endpoint: Endpoint, received: list[tuple[str, bytes]]
) -> AsyncIterator[asyncio.Event]:
    """Run `endpoint` until the block ends; what it receives goes to `received`."""

    async def handle(topic: str, payload: bytes) -> None:
        received.append((topic, payload))

    stop = asyncio.Event()
    task = asyncio.create_task(endpoint.run(stop, handle))
    try:
        await async_wait_for(lambda: endpoint.online.is_set() or task.done(), what="online")
        yield stop
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)


def connection_of(probe: MqttProbe, topics: Topics) -> list[bytes]:
    """Every payload the probe saw on the endpoint's connection topic."""
    return [m.payload for m in probe.received(topics.device("device_connection", "d1"))]


async def test_online_then_offline_on_a_clean_stop(broker: BrokerThread, topics: Topics) -> None:
    probe = MqttProbe(broker.url).connect()
    probe.subscribe(f"{topics.root}/v1/devices/+/connection")
    received: list[tuple[str, bytes]] = []
    endpoint = make(broker.url, topics)
    async with running(endpoint, received):
        await async_wait_for(lambda: connection_of(probe, topics) == [b"online"], what="online")
        probe.publish(topics.fleet("estop"), b"engaged|probe|test")
        await async_wait_for(lambda: received, what="the stop delivered")
        assert received == [(topics.fleet("estop"), b"engaged|probe|test")]
        assert await endpoint.publish(Outbound(topics.fleet("errors"), b"x", 0, False))
    await async_wait_for(
        lambda: connection_of(probe, topics) == [b"online", b"offline"], what="offline"
    )
    assert not endpoint.connected
    assert not await endpoint.publish(Outbound(topics.fleet("errors"), b"x", 0, False))
    probe.close()


async def test_kill_leaves_the_will_and_ends_without_reconnecting(
    broker: BrokerThread, topics: Topics
) -> None:
    probe = MqttProbe(broker.url).connect()
    probe.subscribe(f"{topics.root}/v1/devices/+/connection")
    received: list[tuple[str, bytes]] = []
    endpoint = make(broker.url, topics)
    stop = asyncio.Event()

    async def handle(topic: str, payload: bytes) -> None:
        received.append((topic, payload))

    task = asyncio.create_task(endpoint.run(stop, handle))
    await async_wait_for(lambda: endpoint.online.is_set(), what="online")
    endpoint.kill()
    await asyncio.wait_for(task, 10)
    await async_wait_for(
        lambda: connection_of(probe, topics)[-1:] == [b"broken"], what="the last will"
    )
    assert endpoint.connects == 1
    probe.close()


async def test_reconnects_and_resubscribes_after_a_broker_restart(
    fresh_broker: BrokerThread, topics: Topics
) -> None:
    received: list[tuple[str, bytes]] = []
    endpoint = make(fresh_broker.url, topics)
    lost: list[str] = []

    async def handle(topic: str, payload: bytes) -> None:
        received.append((topic, payload))

    stop = asyncio.Event()
    task = asyncio.create_task(endpoint.run(stop, handle, on_disconnect=lost.append))
    try:
        await async_wait_for(lambda: endpoint.online.is_set(), what="online")
        await asyncio.to_thread(fresh_broker.restart)
        await async_wait_for(lambda: endpoint.connects == 2 and endpoint.online.is_set(), 20)
        assert lost, "the lost session was reported"
        with MqttProbe(fresh_broker.url) as probe:
            probe.publish(topics.fleet("estop"), b"released|probe|x")
        await async_wait_for(lambda: received, what="a message after resubscribing")
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)


async def test_during_runs_per_session_and_its_error_ends_the_run(
    broker: BrokerThread, topics: Topics
) -> None:
    endpoint = make(broker.url, topics)

    async def during(shutdown: asyncio.Event) -> None:
        raise ValueError("a bug in the session's work")

    async def handle(topic: str, payload: bytes) -> None:
        pass

    stop = asyncio.Event()
    try:
        await asyncio.wait_for(endpoint.run(stop, handle, during=during), 10)
    except ValueError as exc:
        assert "a bug" in str(exc)
    else:
        raise AssertionError("the error of `during` was swallowed")


async def test_on_stop_runs_before_offline_and_only_on_a_clean_stop(
    broker: BrokerThread, topics: Topics
) -> None:
    probe = MqttProbe(broker.url).connect()
    probe.subscribe(f"{topics.root}/v1/#")
    endpoint = make(broker.url, topics)
    goodbye = Outbound(topics.fleet("errors"), b"last words", 1, False)

    async def on_stop() -> None:
        await endpoint.publish(goodbye)

    async def handle(topic: str, payload: bytes) -> None:
        pass

    stop = asyncio.Event()
    task = asyncio.create_task(endpoint.run(stop, handle, on_stop=on_stop))
    # Generous: on a loaded machine the shared broker took over 10 s to let it in (CI run D).
    await async_wait_for(lambda: endpoint.online.is_set(), timeout=30, what="online")
    stop.set()
    await asyncio.wait_for(task, 10)
    await async_wait_for(lambda: connection_of(probe, topics)[-1:] == [b"offline"], what="bye")
    words = probe.received(goodbye.topic)
    offline = probe.received(topics.device("device_connection", "d1"))[-1]
    assert [m.payload for m in words] == [b"last words"] and words[0].at <= offline.at

    killed = make(broker.url, topics)
    calls: list[str] = []

    async def record() -> None:
        calls.append("on_stop")

    task = asyncio.create_task(killed.run(asyncio.Event(), handle, on_stop=record))
    await async_wait_for(lambda: killed.online.is_set(), timeout=30, what="online again")
    killed.kill()
    await asyncio.wait_for(task, 10)
    await async_wait_for(lambda: connection_of(probe, topics)[-1:] == [b"broken"], what="will")
    assert calls == []  # no goodbye from a unit that lost power
    probe.close()


@pytest.mark.amqtt_only  # freezes the embedded broker's own event loop
async def test_a_clean_stop_does_not_wait_long_for_a_broker_that_stopped_answering(
    fresh_broker: BrokerThread, topics: Topics
) -> None:
    # The broker stops answering (as one stopping at the same moment): the goodbye is never
    # acknowledged. The stop waits at most GOODBYE_S for it, not aiomqtt's 10 s per publish.
    endpoint = make(fresh_broker.url, topics)
    stop = asyncio.Event()
    task = asyncio.create_task(endpoint.run(stop, lambda topic, payload: asyncio.sleep(0)))
    await async_wait_for(lambda: endpoint.online.is_set() or task.done(), what="online")
    loop = fresh_broker._loop  # freezing the broker's own loop is the point here
    assert loop is not None
    frozen = threading.Event()
    loop.call_soon_threadsafe(lambda: frozen.wait(GOODBYE_S + 6))  # blocks the broker's loop
    try:
        stop.set()
        await asyncio.wait_for(task, GOODBYE_S + 3)
    finally:
        frozen.set()


async def test_a_broker_that_accepts_and_never_answers_is_retried_soon(topics: Topics) -> None:
    # As a broker going down, or a proxy in front of one: the TCP connection is accepted, no
    # CONNACK comes. Each try gives up after CONNECT_S, not aiomqtt's 10 s, and tries again.
    accepted: list[asyncio.StreamWriter] = []

    async def silent(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        accepted.append(writer)

    server = await asyncio.start_server(silent, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    endpoint = make(f"mqtt://127.0.0.1:{port}", topics)
    stop = asyncio.Event()
    task = asyncio.create_task(endpoint.run(stop, lambda topic, payload: asyncio.sleep(0)))
    try:
        await async_wait_for(lambda: len(accepted) >= 2, 2 * CONNECT_S + 2, what="a second try")
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)
        for writer in accepted:
            writer.close()
        server.close()
        await server.wait_closed()
