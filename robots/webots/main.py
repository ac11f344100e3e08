"""The body of the `gridfleet_unit` controller: read the GridUnit's fields and run it (or its
mirror) until Webots ends the controller."""

from __future__ import annotations

import asyncio
import logging
import sys

from gridfleet.errors import GridfleetError
from gridfleet.robots.webots.api import Supervisor
from gridfleet.robots.webots.host import WebotsUnit
from gridfleet.robots.webots.mirror import MirrorUnit
from gridfleet.robots.webots.settings import UnitSettings, read_settings
from gridfleet.tasks import stop_on_signals

log = logging.getLogger("gridfleet.robots.webots")


def run_controller(robot: Supervisor) -> int:
    """Join the fleet as the robot's unit, or mirror it; 2 with one line for a bad field."""
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
    unit = MirrorUnit(robot, settings) if settings.mirror else WebotsUnit(robot, settings)
    role = "mirrors its state from" if settings.mirror else "joins the fleet on"
    log.info("%s %s %s (root %s)", settings.unit_id, role, unit.endpoint.brokers, settings.root)
    await unit.run(stop_on_signals())
