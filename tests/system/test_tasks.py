"""Ending tasks: cancel_and_wait survives a swallowed cancel; signals and stops end work."""

from __future__ import annotations

import asyncio
import os
import signal

from gridfleet.tasks import cancel_and_wait, stop_on_signals, until_stopped


async def test_a_task_that_swallows_the_first_cancellation_still_ends() -> None:
    swallowed = 0

    async def stubborn() -> None:
        nonlocal swallowed
        while True:
            try:
                await asyncio.Event().wait()
            except asyncio.CancelledError:
                if swallowed:
                    raise
                swallowed += 1  # as 3.11's wait_for does when its future completes at once

    task = asyncio.create_task(stubborn())
    await asyncio.sleep(0)  # let it start waiting
    await asyncio.wait_for(cancel_and_wait(task, retry_s=0.01), timeout=5)
    assert task.cancelled() and swallowed == 1


async def test_a_task_that_ended_with_an_error_is_not_raised_again() -> None:
    async def broken() -> None:
        raise RuntimeError("gone")

    task = asyncio.create_task(broken())
    await asyncio.wait({task})
    await cancel_and_wait(task)
    assert isinstance(task.exception(), RuntimeError)


async def test_until_stopped_returns_the_result_of_work_that_ends() -> None:
    async def work() -> int:
        return 7

    assert await until_stopped(work(), asyncio.Event()) == 7


async def test_until_stopped_cancels_the_work_when_the_stop_comes() -> None:
    started, stop = asyncio.Event(), asyncio.Event()
    cancelled = False

    async def forever() -> None:
        nonlocal cancelled
        started.set()
        try:
            await asyncio.Event().wait()
        except asyncio.CancelledError:
            cancelled = True
            raise

    running = asyncio.create_task(until_stopped(forever(), stop))
    await started.wait()
    stop.set()
    assert await asyncio.wait_for(running, 5) is None and cancelled


async def test_sigterm_sets_the_stop_event() -> None:
    stop = stop_on_signals()
    os.kill(os.getpid(), signal.SIGTERM)
    await asyncio.wait_for(stop.wait(), 5)
