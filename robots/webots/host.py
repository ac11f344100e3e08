"""A grid unit in Webots on the fleet's broker: its world and the same shell as a headless unit.

The unit is the same as a headless one: `UnitLogic` decides, `UnitCore` speaks the protocol,
`UnitShell` and its `Endpoint` keep the MQTT session and step the unit on the wall clock, as
the coordinator and every other unit do. Only its world differs (`WebotsWorld`), and Webots'
clock runs beside (`robots.webots.clock`).
"""

from __future__ import annotations

import asyncio

from gridfleet.endpoint import Endpoint
from gridfleet.protocol import Topics
from gridfleet.robots.battery import Battery
from gridfleet.robots.shell import UnitShell
from gridfleet.robots.unit import UnitLogic
from gridfleet.robots.webots.adapter import WebotsWorld
from gridfleet.robots.webots.api import Supervisor
from gridfleet.robots.webots.clock import WebotsThread, keep_stepping
from gridfleet.robots.webots.settings import UnitSettings
from gridfleet.tasks import cancel_and_wait

MODEL = "gridfleet-webots"  # the factsheet's `model` of a unit in Webots


class WebotsUnit:
    """One grid unit: its Webots world and the same shell as a headless unit's, on one broker."""

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
            battery=None if settings.battery is None else Battery.from_spec(settings.battery),
            chargers=settings.chargers,
        )
        try:
            self.world = WebotsWorld(
                robot, settings.unit_id, settings.grid, leds=logic.leds, call=self.webots.call
            )
        except BaseException:
            self.webots.close()
            raise
        self.runner = UnitShell(
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

    @property
    def endpoint(self) -> Endpoint:
        """The unit's MQTT session."""
        return self.runner.endpoint

    async def run(self, shutdown: asyncio.Event) -> None:
        """Run until `stop` is set or Webots ends the controller; the unit says "offline"."""
        name = self.settings.unit_id
        stepping = asyncio.create_task(
            keep_stepping(self.webots, self.world, self.logic.leds, shutdown, name),
            name="webots-steps",
        )
        try:
            await self.runner.run(shutdown)
        finally:
            await cancel_and_wait(stepping)
            self.webots.close()
