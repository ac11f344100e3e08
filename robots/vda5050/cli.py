"""`gridfleet vda5050`: run the VDA 5050 vehicles of a vehicles file as units of the fleet."""

from __future__ import annotations

import argparse
import asyncio
import logging
from pathlib import Path

from gridfleet.config import check_step
from gridfleet.errors import ConfigError
from gridfleet.maps import load_map
from gridfleet.options import add_common, broker_url
from gridfleet.protocol import Topics
from gridfleet.robots.vda5050.config import load_vehicles
from gridfleet.robots.vda5050.schemas import Schemas
from gridfleet.robots.vda5050.shell import AdapterShell
from gridfleet.scenario import load_scenario
from gridfleet.tasks import stop_on_signals

log = logging.getLogger("gridfleet.vda5050")
DEFAULT_STEP_S = 0.5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet vda5050`."""
    add_common(parser)
    parser.add_argument(
        "--vehicles", required=True, type=Path, metavar="FILE", help="the vehicles file (.toml)"
    )
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--scenario", type=Path, metavar="FILE", help="the fleet's scenario (.toml)")
    where.add_argument("--map", type=Path, metavar="FILE", help="the fleet's map (.map)")
    parser.add_argument(
        "--step",
        type=float,
        default=DEFAULT_STEP_S,
        metavar="SECONDS",
        help="how often each vehicle's unit is heard at least (a third of this: its state), and "
        f"the step period its factsheet gives (default {DEFAULT_STEP_S})",
    )
    parser.add_argument(
        "--schemas",
        type=Path,
        metavar="DIR",
        help="hold every message to the official VDA 5050 JSON schemas in DIR (2.0.0/, 2.1.0/)",
    )


def build(args: argparse.Namespace) -> AdapterShell:
    """The adapter the arguments describe; bad input raises a GridfleetError in one line."""
    check_step(args.step)
    vehicles = load_vehicles(args.vehicles)
    if not vehicles:
        raise ConfigError(f"{args.vehicles}: no [[vehicles]]: nothing to carry")
    grid = load_scenario(args.scenario).grid if args.scenario is not None else load_map(args.map)
    schemas = Schemas(args.schemas) if args.schemas is not None else None
    return AdapterShell(
        vehicles,
        grid,
        broker_url(args, "vda5050"),
        Topics(args.root),
        step_s=args.step,
        schemas=schemas,
    )


def run(args: argparse.Namespace) -> int:
    """Run until Ctrl-C or SIGTERM; every vehicle's unit says `offline` on the way out."""
    adapter = build(args)

    async def main() -> None:
        stop = stop_on_signals()
        log.info(
            "carrying %s on %s",
            ", ".join(f"{c.id} ({c.vehicle.prefix})" for c in adapter.cores),
            adapter.endpoint.brokers,
        )
        await adapter.run(stop)

    asyncio.run(main())
    return 0
