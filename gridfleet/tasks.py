"""Ending asyncio tasks reliably."""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Awaitable
from typing import Any, TypeVar

T = TypeVar("T")


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


async def first_of(*events: asyncio.Event, timeout: float | None = None) -> None:
    """Until any of `events` is set, or `timeout` seconds have passed (None: no limit)."""
    waits = [asyncio.create_task(e.wait()) for e in events]
    try:
        await asyncio.wait(waits, timeout=timeout, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for w in waits:
            w.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await w


def stop_on_signals() -> asyncio.Event:
    """An event set by SIGINT, SIGTERM or SIGHUP (Ctrl-C, `gridfleet up`, systemd, a closed
    terminal): the way to stop."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    hangup = getattr(signal, "SIGHUP", None)  # not on Windows
    for sig in (signal.SIGINT, signal.SIGTERM, *([hangup] if hangup else [])):
        with contextlib.suppress(NotImplementedError):  # no signal handlers on Windows' loop
            loop.add_signal_handler(sig, stop.set)
    return stop


async def until_stopped(work: Awaitable[T], shutdown: asyncio.Event) -> T | None:
    """Run `work` until it ends (its result) or `stop` is set (cancelled; None)."""
    task = asyncio.ensure_future(work)
    stopper = asyncio.create_task(shutdown.wait())
    try:
        await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        stopper.cancel()
    if task.done():
        return task.result()
    await cancel_and_wait(task)
    return None
