"""`gridfleet clean`: clear a topic root's retained messages, for a fresh start on a shared broker.

A broker keeps every retained message until it is replaced or cleared (an empty retained
message): units' states and connections, the stop, the fleet's views. A run on a root inherits
what the last run there left. This clears it. Stop the fleet that uses the root first: a running
one publishes its retained messages again at once.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import uuid

import aiomqtt

from gridfleet.bus import connect_first
from gridfleet.errors import ConfigError, ProtocolError
from gridfleet.options import add_common, broker_url
from gridfleet.protocol import SUBSCRIBE_QOS, Topics

QUIET_S = 0.5  # the retained replay after subscribing is over once nothing came for this long
MOST_S = 10.0  # and at most this long, even on a root where a fleet is still running


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet clean`."""
    add_common(parser)


async def retained_topics(client: aiomqtt.Client, root: str) -> set[str]:
    """Topics under `root` that hold a retained message (subscribes, collects the replay)."""
    await client.subscribe(f"{root}/#", qos=SUBSCRIBE_QOS)
    found: set[str] = set()
    loop = asyncio.get_running_loop()
    deadline = loop.time() + MOST_S
    messages = aiter(client.messages)
    while loop.time() < deadline:
        try:
            message = await asyncio.wait_for(anext(messages), QUIET_S)
        except TimeoutError:
            break  # the replay is over
        if message.retain and message.payload:
            found.add(str(message.topic))
    await client.unsubscribe(f"{root}/#")
    return found


async def clean_root(url: str, root: str) -> tuple[int, int]:
    """Clear every retained message under `root`: (cleared, still there after clearing).

    Some may stay: an account may not write every topic of the root (protocol.md §10).
    """
    client_id = f"clean-{uuid.uuid4().hex[:8]}"
    async with connect_first(url, client_id) as client:
        found = await retained_topics(client, root)
        for topic in sorted(found):
            await client.publish(topic, b"", qos=1, retain=True)
    async with connect_first(url, client_id) as client:
        left = await retained_topics(client, root)
    return len(found - left), len(left)


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet clean`."""
    try:
        root = Topics(args.root).root
    except ProtocolError as exc:
        raise ConfigError(f"--root: {exc}") from None
    cleared, left = asyncio.run(clean_root(broker_url(args, "operator"), root))
    print(f"cleared {cleared} retained message{'s' * (cleared != 1)} under {root!r}")
    if left:
        print(
            f"gridfleet clean: {left} could not be cleared: is a fleet still running on "
            f"{root!r}, or may this account not write them?",
            file=sys.stderr,
        )
        return 1
    return 0
