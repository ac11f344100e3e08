"""The bus's client leaves nothing open when its block ends, even when cancelled in its goodbye:
paho would close the socket when the client is collected, after the loop closed, and print the
loop's error (it did in `gridfleet up`'s output as its feed stopped)."""

from __future__ import annotations

import asyncio
import gc
import socket
import sys

import aiomqtt
import pytest

from gridfleet import bus
from gridfleet.bus import make_client
from gridfleet.system.broker_thread import BrokerThread


def test_a_client_cancelled_in_its_goodbye_closes_its_socket_before_the_loop_ends(
    broker: BrokerThread, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(bus, "DISCONNECT_S", 120.0)  # only the second cancel ends the goodbye
    clients: list[aiomqtt.Client] = []

    async def hold(client: aiomqtt.Client) -> None:
        async with client:
            await asyncio.Event().wait()  # until cancelled

    async def main() -> None:
        client = make_client(broker.url, "goodbye-cut")  # made in the loop, as aiomqtt's are
        clients.append(client)
        task = asyncio.create_task(hold(client))
        while client._client.socket() is None or not client._connected.done():
            await asyncio.sleep(0.01)  # polling the connection, with the test's timeout
        # The goodbye can never be written, as to a broker that stopped reading: the block's
        # exit waits for a close that never comes, until a second cancel cuts it short.
        client._client.on_socket_register_write = lambda *_: None
        task.cancel()
        await asyncio.sleep(0.2)  # the exit is waiting (no wait ends it: the write never goes)
        assert not task.done() and client._client.socket() is not None
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert client._client.socket() is None

    unraisable: list[str] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: unraisable.append(repr(u.exc_value)))
    asyncio.run(main())
    clients.clear()
    gc.collect()
    assert unraisable == []


def test_a_goodbye_that_cannot_go_out_ends_the_block_in_its_time_with_the_socket_closed(
    broker: BrokerThread, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(bus, "DISCONNECT_S", 0.5)

    async def main() -> None:
        client = make_client(broker.url, "goodbye-stuck")
        async with client:
            client._client.on_socket_register_write = lambda *_: None  # the write never goes
        # aiomqtt alone would wait here for ever: the block ended, its socket closed.
        assert client._client.socket() is None

    asyncio.run(asyncio.wait_for(main(), 30))


def test_a_client_cancelled_while_connecting_closes_its_socket_before_the_loop_ends(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    unraisable: list[str] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: unraisable.append(repr(u.exc_value)))
    clients: list[aiomqtt.Client] = []
    with socket.create_server(("127.0.0.1", 0)) as mute:  # takes the connection, never answers

        async def main() -> None:
            client = make_client(f"mqtt://127.0.0.1:{mute.getsockname()[1]}", "connect-cut")
            clients.append(client)
            task = asyncio.create_task(client.__aenter__())
            while client._client.socket() is None:
                await asyncio.sleep(0.01)  # polling the connection, with the test's timeout
            task.cancel()  # waiting for the CONNACK that never comes
            with pytest.raises(asyncio.CancelledError):
                await task
            assert client._client.socket() is None

        asyncio.run(main())
    clients.clear()
    gc.collect()
    assert unraisable == []
