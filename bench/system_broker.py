"""The broker a system bench run talks to: the one given, or an embedded amqtt of its own."""

from __future__ import annotations

import asyncio
import contextlib
import re
import sys
import uuid
from collections.abc import AsyncIterator

import aiomqtt

from gridfleet.bus import make_client
from gridfleet.errors import ConfigError, GridfleetError


async def check_broker(url: str, timeout: float = 5.0) -> None:
    """ConfigError, in one line, when nothing answers MQTT at `url`."""
    try:
        async with asyncio.timeout(timeout):
            async with make_client(url, f"bench-probe-{uuid.uuid4().hex[:6]}"):
                pass
    except (aiomqtt.MqttError, OSError, TimeoutError) as exc:
        raise ConfigError(f"cannot reach the broker at {url}: {exc or 'timed out'}") from None


@contextlib.asynccontextmanager
async def broker_for(url: str | None) -> AsyncIterator[str]:
    """The URL given (checked), or an embedded amqtt on a free loopback port for the block.

    The embedded broker runs in a process of its own (`gridfleet broker`, as `gridfleet up` runs
    it): in this process it would share one interpreter lock with the coordinator and every unit.
    """
    if url is not None:
        await check_broker(url)
        yield url
        return
    args = ["-m", "gridfleet", "broker", "--host", "127.0.0.1", "--port", "0", "--no-ws"]
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        *args,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.DEVNULL,
        start_new_session=True,  # Ctrl-C reaches the bench, which stops the broker last
    )
    try:
        assert proc.stdout is not None
        try:
            line = await asyncio.wait_for(proc.stdout.readline(), 60)
        except TimeoutError:
            line = b""
        match = re.search(rb"listening on (mqtt://\S+)", line)
        if match is None:
            raise GridfleetError(f"the embedded broker did not start (it said {line!r})")
        yield match.group(1).decode()
    finally:
        with contextlib.suppress(ProcessLookupError):
            proc.terminate()
        try:
            await asyncio.wait_for(proc.wait(), 20)
        except TimeoutError:  # an overloaded amqtt can take long to drain: it has no queue limit
            proc.kill()
            await proc.wait()
