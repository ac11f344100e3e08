"""`gridfleet robots`: run the simulated units of a scenario (all, or a subset) on a broker."""

from __future__ import annotations

import argparse
import asyncio
import logging
from pathlib import Path

from gridfleet.config import check_step, parse_brokers
from gridfleet.errors import ConfigError
from gridfleet.heap import freeze_after_start
from gridfleet.options import accounts_of, add_common
from gridfleet.protocol.constants import DEFAULT_STEP_S
from gridfleet.robots.fleet import Fleet
from gridfleet.robots.shards import run_sharded
from gridfleet.robots.truth import write_truth
from gridfleet.scenario import load_scenario
from gridfleet.tasks import stop_on_signals

log = logging.getLogger("robots")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet robots`."""
    add_common(parser)
    parser.add_argument("--scenario", required=True, metavar="FILE", help="scenario .toml file")
    parser.add_argument(
        "--units",
        default=None,
        metavar="ID,ID",
        help="run only these units (comma-separated); others are seen through their state",
    )
    parser.add_argument(
        "--step",
        type=float,
        default=DEFAULT_STEP_S,
        metavar="SECONDS",
        help=f"step period (default {DEFAULT_STEP_S})",
    )
    parser.add_argument(
        "--mode",
        choices=["coordinated", "standalone"],
        default="coordinated",
        help="follow the coordinator's orders, or plan to the scenario's goals (default coordinated)",
    )
    parser.add_argument(
        "--state",
        type=Path,
        metavar="FILE",
        help="keep where the units stand, what they carry and their charge in this SQLite file, "
        "and resume from it after a restart (default: start from the scenario)",
    )
    parser.add_argument(
        "--truth",
        type=Path,
        metavar="FILE",
        help="append the simulated world's collisions, moves and squares to FILE as one JSON "
        "line per step (for outside checkers such as `gridfleet bench soak`)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=1,
        metavar="N",
        help="run the units in N processes sharing one simulated world, for large fleets "
        "(default 1: all in this process)",
    )


def build(args: argparse.Namespace) -> Fleet:
    """The fleet the arguments describe; bad input raises a GridfleetError with one clear line."""
    scenario = load_scenario(args.scenario)  # Fleet checks the URL and that it has units
    units = None
    if args.units is not None:
        units = [u.strip() for u in args.units.split(",") if u.strip()]
        if not units:
            raise ConfigError("--units: give at least one unit id")
    return Fleet(
        scenario,
        args.broker,
        root=args.root,
        units=units,
        step=args.step,
        mode=args.mode,
        accounts=accounts_of(args),
        state_path=args.state,
    )


def run(args: argparse.Namespace) -> int:
    """Run until Ctrl-C or SIGTERM; every unit says "offline" on the way out."""
    if args.workers != 1:
        return _run_sharded(args)
    fleet = build(args)
    asyncio.run(_main(fleet, args.truth, args.step))
    return 0


def _run_sharded(args: argparse.Namespace) -> int:
    """`--workers N`: the scenario's units over N processes (checked here, before any starts)."""
    if args.units is not None:
        raise ConfigError("--workers shards every unit of the scenario: leave out --units")
    parse_brokers(args.broker)
    check_step(args.step)
    accounts_of(args)  # a bad accounts file: one line now, not one per worker
    return run_sharded(
        Path(args.scenario),
        args.broker,
        root=args.root,
        workers=args.workers,
        step_s=args.step,
        mode=args.mode,
        accounts=getattr(args, "accounts", None),
        state=args.state,
        truth=args.truth,
    )


async def _main(fleet: Fleet, truth: Path | None = None, step: float = DEFAULT_STEP_S) -> None:
    stop = stop_on_signals()
    freeze_after_start()
    if truth is not None:
        writer = asyncio.create_task(write_truth(fleet.world, truth, step, stop))
    log.info(
        "running %s on %s (%s)",
        ", ".join(fleet.shells),
        fleet.shells[next(iter(fleet.shells))].endpoint.brokers,
        fleet.logic[next(iter(fleet.shells))].mode,
    )
    await fleet.run(stop)
    if truth is not None:
        await writer
    log.info(
        "stopped: %d moves, %d collisions, %d prevented",
        sum(fleet.world.moves.values()),
        fleet.world.collisions,
        fleet.world.prevented,
    )
