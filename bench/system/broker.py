"""A check that a broker given to the system bench answers, before anything starts."""

from __future__ import annotations

import asyncio
import uuid

import aiomqtt

from gridfleet.bus import connect_first
from gridfleet.config import redacted
from gridfleet.errors import ConfigError


async def check_broker(url: str, timeout: float = 5.0) -> None:
    """ConfigError, in one line, when nothing answers MQTT at `url` (or at any of a list)."""
    try:
        async with asyncio.timeout(timeout):
            async with connect_first(url, f"bench-probe-{uuid.uuid4().hex[:6]}"):
                pass
    except (aiomqtt.MqttError, OSError, TimeoutError) as exc:
        raise ConfigError(
            f"cannot reach the broker at {redacted(url)}: {exc or 'timed out'}"
        ) from None
