"""The broker a system bench run talks to: the one given, or an embedded amqtt of its own."""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import sys
import uuid
from collections.abc import AsyncIterator

import aiomqtt

from gridfleet.bus import make_client
from gridfleet.errors import ConfigError
from system.supervisor import ChildSpec, Supervisor


async def check_broker(url: str, timeout: float = 5.0) -> None:
    """ConfigError, in one line, when nothing answers MQTT at `url`."""
    try:
        async with asyncio.timeout(timeout):
            async with make_client(url, f"bench-probe-{uuid.uuid4().hex[:6]}"):
                pass
    except (aiomqtt.MqttError, OSError, TimeoutError) as exc:
        raise ConfigError(f"cannot reach the broker at {url}: {exc or 'timed out'}") from None


_READY = re.compile(r"listening on (mqtt://\S+)")
_EMBEDDED = ["-m", "system", "broker", "--host", "127.0.0.1", "--port", "0", "--no-ws"]


@contextlib.asynccontextmanager
async def broker_for(url: str | None) -> AsyncIterator[str]:
    """The URL given (checked), or an embedded amqtt on a free loopback port for the block.

    The embedded broker runs in a process of its own (`gridfleet broker`, supervised as `gridfleet
    up` runs it): in this process it would share one interpreter lock with the coordinator and
    every unit.
    """
    if url is not None:
        await check_broker(url)
        yield url
        return
    # An overloaded amqtt can take long to drain when stopped: it has no queue limit.
    with open(os.devnull, "w") as quiet:
        supervisor = Supervisor(out=quiet, stop_timeout=20.0)
        try:
            spec = ChildSpec("broker", [sys.executable, *_EMBEDDED], ready=_READY, restart=False)
            broker = await supervisor.start(spec)
            assert broker.ready_match is not None
            yield broker.ready_match.group(1)
        finally:
            await supervisor.stop()  # last: Ctrl-C reaches the bench, which stops it after the rest
