"""A mirror: a unit that runs elsewhere (another Webots, a simulated unit), shown in this world.

As the course has it for robots in several Webots instances: a local robot that copies a remote
one's moves, so that this world shows the whole fleet and its own units' distance sensors see
the remote ones. It follows the unit's `state` (position and LEDs) and publishes nothing.
"""

from __future__ import annotations

import asyncio
import logging
import uuid

from gridfleet.endpoint import Endpoint
from gridfleet.errors import ProtocolError
from gridfleet.protocol import Topics, UnitState, decode
from gridfleet.protocol.messages import Leds
from gridfleet.robots.webots.adapter import WebotsWorld
from gridfleet.robots.webots.api import Supervisor
from gridfleet.robots.webots.clock import WebotsThread, keep_stepping
from gridfleet.robots.webots.settings import UnitSettings
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.robots.webots")


class MirrorUnit:
    """Shows where unit `settings.unit_id` is, and its LEDs, as its published state says."""

    def __init__(self, robot: Supervisor, settings: UnitSettings) -> None:
        self.settings = settings
        self.leds = Leds(N=False, E=False, S=False, W=False)
        self.webots = WebotsThread()
        try:
            self.world = WebotsWorld(
                robot, settings.unit_id, settings.grid, leds=self._leds, call=self.webots.call
            )
        except BaseException:
            self.webots.close()
            raise
        self.topic = Topics(settings.root).unit("state", settings.unit_id)
        self.endpoint = Endpoint(
            settings.broker,
            f"mirror-{settings.unit_id}-{uuid.uuid4().hex[:8]}",
            name=f"mirror of {settings.unit_id}",
            subscriptions=lambda: [(self.topic, 0)],
        )
        self.states = 0  # states followed (tests watch it)

    def _leds(self) -> Leds:
        return self.leds

    @property
    def ready(self) -> asyncio.Event:
        """Set while subscribed to the unit's state."""
        return self.endpoint.online

    async def run(self, shutdown: asyncio.Event) -> None:
        """Follow the unit's state until `stop` is set or Webots ends the controller."""
        name = f"mirror of {self.settings.unit_id}"
        stepping = asyncio.create_task(
            keep_stepping(self.webots, self.world, self._leds, shutdown, name), name="webots-steps"
        )
        try:
            await self.endpoint.run(shutdown, self._follow)
        finally:
            await cancel_and_wait(stepping)
            self.webots.close()

    async def _follow(self, topic: str, payload: bytes) -> None:
        try:
            state = decode(UnitState, payload)
        except ProtocolError as exc:
            log.warning("mirror of %s: ignored a state: %s", self.settings.unit_id, exc)
            return
        self.leds = state.leds
        if state.position != self.world.position(self.settings.unit_id):
            self.world.resume(self.settings.unit_id, state.position)
        self.states += 1
