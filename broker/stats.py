"""What the embedded broker counts about itself: plain numbers, read by its metrics (metrics.py)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

REFUSALS = ("connect", "websocket", "publish")  # what a refusal turned away


@dataclass
class BrokerStats:
    """Running totals since the broker started."""

    received: int = 0  # messages clients published (and wills), routed to subscribers
    delivered: int = 0  # copies handed to subscribers' connections
    dropped: int = 0  # copies dropped: the subscriber's backlog was full (it does not read)
    refused: Counter[str] = field(default_factory=Counter)  # by REFUSALS


@dataclass(frozen=True)
class BrokerFigures:
    """The broker as one scrape sees it: its totals and its state now."""

    clients: int  # connections now
    sessions: int  # sessions kept, persistent ones of disconnected clients included
    queued_messages: int  # copies waiting in connected clients' backlogs
    queued_bytes: int
    retained: int  # retained messages held
    routing: int  # messages waiting to be routed
    received: int
    delivered: int
    dropped: int
    refused: dict[str, int]
