"""Webots' clock beside asyncio's: the one thread that calls Webots, and the stepper.

Webots advances its simulation only while the controller is inside `robot.step`, which returns
once one basic time step has been simulated (in real-time mode about as long as that step takes
on the wall). A unit's own steps stay on the wall clock, not the simulation's: the fleet's
orders, timeouts and heartbeats are in wall seconds, and a paused or fast-forwarded Webots must
not change the protocol's timing. So `robot.step` runs over and over on a thread of its own, the
only thread that ever calls Webots, while the asyncio loop serves MQTT and the unit's steps; a
unit step waits for the Webots step in progress (one basic time step at most) and then senses,
moves and lights its LEDs on that thread. Between Webots steps the stepper waits until the
step's wall time is over, so Webots' fast mode (and a test double, whose steps take no time) is
held to real time instead of spinning.
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from gridfleet.protocol.messages import Leds
from gridfleet.robots.webots.adapter import WebotsWorld

log = logging.getLogger("gridfleet.robots.webots")
T = TypeVar("T")


class WebotsThread:
    """The one thread that talks to Webots: every controller API call runs on it, one at a time."""

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="webots")

    def call(self, work: Callable[[], T]) -> T:
        """Run `work` on the Webots thread and wait for it (after the call in progress, if any)."""
        return self._pool.submit(work).result()

    async def run(self, work: Callable[[], T]) -> T:
        """Run `work` on the Webots thread without holding up the event loop."""
        return await asyncio.wrap_future(self._pool.submit(work))

    def close(self) -> None:
        """Let the call in progress finish, then end the thread."""
        self._pool.shutdown(wait=True)


async def keep_stepping(
    webots: WebotsThread,
    world: WebotsWorld,
    leds: Callable[[], Leds],
    shutdown: asyncio.Event,
    name: str,
) -> None:
    """Advance Webots step by step showing `leds()`, at most as fast as the wall clock.

    `leds` is read on the event loop's thread (the unit's state belongs to it). When Webots
    ends the controller, `stop` is set.
    """
    loop = asyncio.get_running_loop()
    period = world.timestep_ms / 1000
    due = loop.time()
    while not shutdown.is_set():
        if not await webots.run(functools.partial(world.advance, leds())):
            log.info("%s: Webots ends the controller", name)
            shutdown.set()
            return
        due += period
        delay = due - loop.time()
        if delay < -period:  # Webots runs slower than real time: do not catch up in a burst
            due = loop.time()
        await asyncio.sleep(max(delay, 0.0))
