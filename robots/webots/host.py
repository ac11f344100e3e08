"""A grid unit in Webots on the fleet's broker: its world, the shared unit runner, Webots' clock.

The unit is the same as a headless one: `UnitLogic` decides, `UnitCore` speaks the protocol,
`UnitRunner` and its `Endpoint` keep the MQTT session and step the unit on the wall clock, as
the coordinator and every other unit do. Only its world differs (`WebotsWorld`).

Time. Webots advances its simulation only while the controller is inside `robot.step`, which
returns once one basic time step has been simulated (in real-time mode about as long as that
step takes on the wall). The unit's own steps stay on the wall clock, not the simulation's:
the fleet's orders, timeouts and heartbeats are in wall seconds, and a paused or fast-forwarded
Webots must not change the protocol's timing. So `robot.step` runs over and over on one thread
of its own (the only thread that ever calls Webots), while the asyncio loop serves MQTT and the
unit's steps; a unit step waits for the Webots step in progress (one basic time step at most)
and then senses, moves and lights its LEDs on that thread. Between Webots steps the stepper
waits until the step's wall time is over, so Webots' fast mode (and a test double, whose steps
take no time) is held to real time instead of spinning.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from gridfleet.errors import GridfleetError
from gridfleet.protocol import Topics
from gridfleet.tasks import cancel_and_wait, stop_on_signals
from robots.runner import UnitRunner
from robots.unit import UnitLogic
from robots.webots.adapter import WebotsWorld
from robots.webots.api import Supervisor
from robots.webots.settings import UnitSettings, read_settings

MODEL = "gridfleet-webots"  # the factsheet's `model` of a unit in Webots
log = logging.getLogger("robots.webots")
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


class WebotsUnit:
    """One grid unit: its Webots world and the same runner as a headless unit's, on one broker."""

    def __init__(
        self, robot: Supervisor, settings: UnitSettings, *, reconnect_s: float = 0.1
    ) -> None:
        self.settings = settings
        self.webots = WebotsThread()
        logic = UnitLogic(
            settings.unit_id,
            settings.grid,
            settings.start,
            settings.capacity_kg,
            settings.step_s,
        )
        try:
            self.world = WebotsWorld(
                robot, settings.unit_id, settings.grid, leds=logic.leds, call=self.webots.call
            )
        except BaseException:
            self.webots.close()
            raise
        self.runner = UnitRunner(
            logic,
            self.world,
            settings.broker,
            Topics(settings.root),
            color=settings.color,
            reconnect_s=reconnect_s,
            model=MODEL,
        )

    @property
    def logic(self) -> UnitLogic:
        """The unit's pure state machine."""
        return self.runner.logic

    @property
    def ready(self) -> asyncio.Event:
        """Set while the unit is connected and announced."""
        return self.runner.online

    async def run(self, stop: asyncio.Event) -> None:
        """Run until `stop` is set or Webots ends the controller; the unit says "offline"."""
        stepping = asyncio.create_task(self._keep_stepping(stop), name="webots-steps")
        try:
            await self.runner.run(stop)
        finally:
            await cancel_and_wait(stepping)
            self.webots.close()

    async def _keep_stepping(self, stop: asyncio.Event) -> None:
        """Advance Webots step by step, at most as fast as the wall clock; stop when it ends."""
        loop = asyncio.get_running_loop()
        period = self.world.timestep_ms / 1000
        due = loop.time()
        while not stop.is_set():
            # The LEDs are read here: the logic belongs to the event loop's thread.
            if not await self.webots.run(functools.partial(self.world.advance, self.logic.leds())):
                log.info("%s: Webots ends the controller", self.settings.unit_id)
                stop.set()
                return
            due += period
            delay = due - loop.time()
            if delay < -period:  # Webots runs slower than real time: do not catch up in a burst
                due = loop.time()
            await asyncio.sleep(max(delay, 0.0))


def run_controller(robot: Supervisor) -> int:
    """The controller's body: read the unit's fields, join the fleet, run until Webots ends it."""
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    try:
        asyncio.run(_serve(robot, read_settings(robot)))
    except GridfleetError as exc:
        print(f"gridfleet_unit {robot.getName()}: error: {exc}", file=sys.stderr)
        return 2
    return 0


async def _serve(robot: Supervisor, settings: UnitSettings) -> None:
    unit = WebotsUnit(robot, settings)
    log.info(
        "%s joins the fleet on %s (root %s)",
        settings.unit_id,
        unit.runner.endpoint.where,
        settings.root,
    )
    await unit.run(stop_on_signals())
