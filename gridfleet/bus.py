"""The MQTT client every asyncio component uses: aiomqtt (on paho) set up from a broker URL."""

from __future__ import annotations

import asyncio
from typing import Any

import aiomqtt

from gridfleet.config import BrokerURL, parse_broker_url


def make_client(
    url: str | BrokerURL,
    client_id: str,
    will: aiomqtt.Will | None = None,
    keepalive: int = 10,
    max_queued_outgoing: int | None = 10_000,
) -> aiomqtt.Client:
    """An unconnected aiomqtt client for `url` (use it as `async with`)."""
    broker = url if isinstance(url, BrokerURL) else parse_broker_url(url)
    return aiomqtt.Client(
        hostname=broker.host,
        port=broker.port,
        identifier=client_id,
        transport=broker.transport,  # type: ignore[arg-type]
        websocket_path=broker.path if broker.scheme == "ws" else None,
        will=will,
        keepalive=keepalive,
        clean_session=True,
        max_queued_outgoing_messages=max_queued_outgoing,
    )


async def cancel_and_wait(task: asyncio.Task[Any], poll_s: float = 0.05) -> BaseException | None:
    """Cancel `task` and wait until it has ended; its exception (None if cancelled or returned).

    On Python 3.11 `asyncio.wait_for` (aiomqtt awaits every publish with it) can swallow a
    cancellation that lands as the publish completes, so one `cancel()` may leave a receiving
    task running for ever and `await task` never returns: cancel again until it is done.
    """
    while not task.done():
        task.cancel()
        await asyncio.wait({task}, timeout=poll_s)
    return None if task.cancelled() else task.exception()
