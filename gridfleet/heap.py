"""The garbage collector in a long-running service: what start-up made is not scanned again."""

from __future__ import annotations

import asyncio
import gc

SETTLE_S = 5.0  # by then a service has made its connections, sessions and first messages


def freeze() -> None:
    """Collect once, then put every object alive now out of the collector's reach for good.

    CPython's full collection walks every object it tracks, and a service that imported pydantic,
    paho, numpy and amqtt holds hundreds of thousands that live as long as it does: each full
    collection paused the coordinator, the broker or a unit process for 35-90 ms, a few times a
    minute, and every message in flight waited (most of the system bench's p99 latencies).
    """
    gc.collect()
    gc.freeze()


def freeze_after_start(settle_s: float = SETTLE_S) -> None:
    """Freeze now, and once more `settle_s` later on the running loop (after the first sessions)."""
    freeze()
    asyncio.get_running_loop().call_later(settle_s, freeze)
