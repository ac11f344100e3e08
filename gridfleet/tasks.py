"""Ending asyncio tasks reliably."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any


async def cancel_and_wait(task: asyncio.Task[Any], retry_s: float = 0.05) -> None:
    """Cancel `task` and wait until it has ended, cancelling again if a cancellation was lost.

    Python 3.11's `asyncio.wait_for` (used by aiomqtt's publish) returns the result instead of
    raising when the cancellation arrives just as the awaited future completes; the task then
    carries on (e.g. reading the next message) and a single cancel() would be waited on forever.
    The task's own exception, if it ended with one, is not raised here.
    """
    while not task.done():
        task.cancel()
        await asyncio.wait({task}, timeout=retry_s)
    with contextlib.suppress(asyncio.CancelledError, Exception):
        task.result()
