"""Drive the pure coordinator core with protocol messages as bytes, and read what it publishes.

A core made by `make_core` stamps every header with the same fixed time, so a test can pin exact
payloads; `published` turns Effects into (topic, payload as parsed JSON, QoS, retain) tuples.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from typing import Any

from coordinator.core import CoordinatorCore
from coordinator.effects import Effects
from coordinator.jobs import Job, JobBook
from coordinator.world import World
from gridfleet.grid import GridMap
from gridfleet.protocol import (
    Connection,
    Factsheet,
    Header,
    HeaderStamper,
    Order,
    Reply,
    Topics,
    UnitState,
    decode,
    encode,
)
from gridfleet.protocol.messages import Message, Request

FIXED = datetime(2026, 11, 21, 10, 0, 0, tzinfo=UTC)
STAMP = "2026-11-21T10:00:00Z"  # FIXED as it appears in a payload
TOPICS = Topics("gridfleet")

Published = tuple[str, Any, int, bool]


def make_core(
    grid: GridMap, *, jobs: list[Job] | None = None, step_s: float = 1.0, seed: int = 0
) -> CoordinatorCore:
    """A core on `grid` under the root `gridfleet`, order nonce `n`, every header at FIXED."""
    return CoordinatorCore(
        World(grid, step_period_s=step_s),
        JobBook(jobs),
        nonce="n",
        seed=seed,
        topics=TOPICS,
        stamp=HeaderStamper("coordinator", clock=lambda: FIXED),
    )


def header(sender: str, seq: int = 0) -> Header:
    """A header from `sender` at FIXED."""
    return Header(seq=seq, timestamp=FIXED, sender=sender)


def from_unit(
    core: CoordinatorCore, kind: str, unit_id: str, message: Message | bytes, now: float
) -> Effects:
    """`message` arrives on the unit's topic of `kind` (connection, factsheet, state)."""
    payload = message if isinstance(message, bytes) else encode(message)
    return core.on_message(TOPICS.unit(kind, unit_id), payload, now)


def request(core: CoordinatorCore, kind: str, message: Request | bytes, now: float) -> Effects:
    """`message` arrives on the request topic of `kind` (submit_job, cancel_job, set_goal)."""
    payload = message if isinstance(message, bytes) else encode(message)
    return core.on_message(TOPICS.request(kind), payload, now)


def meet(core: CoordinatorCore, state: UnitState, capacity_kg: float, step_s: float = 1.0) -> None:
    """The unit of `state` says it is online, describes itself and reports its state (at 0 s)."""
    unit_id = state.header.sender
    from_unit(core, "connection", unit_id, Connection(header=header(unit_id), state="online"), 0)
    fs = Factsheet(header=header(unit_id), capacity_kg=capacity_kg, step_period_s=step_s)
    from_unit(core, "factsheet", unit_id, fs, 0.0)
    from_unit(core, "state", unit_id, state, 0.0)


def published(effects: Effects) -> list[Published]:
    """Every message to publish, as (topic, payload parsed as JSON, QoS, retain)."""
    out = []
    for m in effects.publish:
        try:
            payload: Any = json.loads(m.payload)
        except ValueError:
            payload = m.payload  # plain text (none today, but the device topics are)
        out.append((m.topic, payload, m.qos, m.retain))
    return out


def orders_in(effects: Effects) -> dict[str, Order]:
    """The orders among `effects`, by unit."""
    out = {}
    for m in effects.publish:
        kind, unit = TOPICS.parse(m.topic)
        if kind == "order" and unit is not None:
            out[unit] = decode(Order, m.payload)
    return out


def reply_in(effects: Effects) -> Reply:
    """The one reply among `effects`."""
    (reply,) = [decode(Reply, m.payload) for m in effects.publish if "/replies/" in m.topic]
    return reply
