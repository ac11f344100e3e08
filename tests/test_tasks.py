"""cancel_and_wait ends a task even when it swallows a cancellation."""

from __future__ import annotations

import asyncio

from gridfleet.tasks import cancel_and_wait


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
