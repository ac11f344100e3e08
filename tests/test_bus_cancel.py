"""cancel_and_wait ends a task even when it swallows a cancellation (Python 3.11 wait_for)."""

from __future__ import annotations

import asyncio

from gridfleet.bus import cancel_and_wait


async def test_a_task_that_swallows_one_cancel_still_ends() -> None:
    swallowed = 0

    async def stubborn() -> None:
        nonlocal swallowed
        while True:
            try:
                await asyncio.sleep(3600)
            except asyncio.CancelledError:
                swallowed += 1
                if swallowed > 1:
                    raise
                asyncio.current_task().uncancel()  # type: ignore[union-attr]

    task = asyncio.create_task(stubborn())
    await asyncio.sleep(0)
    assert await asyncio.wait_for(cancel_and_wait(task, poll_s=0.01), 5) is None
    assert task.cancelled() and swallowed == 2


async def test_the_error_a_task_ended_with_is_returned() -> None:
    async def failing() -> None:
        raise ValueError("boom")

    task = asyncio.create_task(failing())
    await asyncio.sleep(0)
    error = await cancel_and_wait(task)
    assert isinstance(error, ValueError)
