"""Exact-publish helpers for the pure cores (coordinator, unit, device): one fixed clock, one reader.

A core whose headers are stamped by `stamper` carries FIXED in every header, so a test can pin
whole payloads: `header` builds such a header as a model (to feed a core), `header_json` as it
appears in a payload (to compare), and `published` turns what a core returns into
(topic, payload, QoS, retain) tuples.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime
from typing import Any, Protocol, runtime_checkable

from gridfleet.outbound import Outbound
from gridfleet.protocol import Header, HeaderStamper

FIXED = datetime(2026, 11, 21, 10, 0, 0, tzinfo=UTC)
STAMP = "2026-11-21T10:00:00Z"  # FIXED as it appears in a payload

Published = tuple[str, Any, int, bool]


@runtime_checkable
class Carrying(Protocol):
    """What carries messages among other things, as the coordinator core's `Effects` does."""

    @property
    def publish(self) -> Sequence[Outbound]: ...


def stamper(sender: str) -> HeaderStamper:
    """Headers from `sender`, every one at FIXED."""
    return HeaderStamper(sender, clock=lambda: FIXED)


def header(sender: str, seq: int = 0) -> Header:
    """A header from `sender` at FIXED."""
    return Header(seq=seq, timestamp=FIXED, sender=sender)


def header_json(sender: str, seq: int) -> dict[str, Any]:
    """A header from `sender` at FIXED as a payload carries it (parsed JSON)."""
    return {"version": "1.6", "seq": seq, "timestamp": STAMP, "sender": sender}


def published(
    outs: Iterable[Outbound] | Carrying, root: str = "", *, events: bool = False
) -> list[Published]:
    """(topic, payload, QoS, retain) of each message, in order.

    The payload is parsed when it is JSON, else kept as text (the device topics are plain text);
    `root` is cut off the front of every topic, which must start with it. The coordinator's
    history view (`fleet/events`) follows most changes: it is left out unless `events`
    (tests/coordinator/test_coordinator_events.py is about it).
    """
    sent = []
    for out in outs.publish if isinstance(outs, Carrying) else outs:
        assert out.topic.startswith(root), (out.topic, root)
        if not events and out.topic.endswith("/fleet/events"):
            continue
        text = out.payload.decode()
        payload = json.loads(text) if text.startswith("{") else text
        sent.append((out.topic.removeprefix(root), payload, out.qos, out.retain))
    return sent
