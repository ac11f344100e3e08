"""`gridfleet up`: the whole system — broker, coordinator, units, dashboard — as supervised processes."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from gridfleet.config import check_step
from gridfleet.options import add_common
from gridfleet.scenario import load_scenario, with_units
from system.assembly import Assembly, SystemSpec
from system.supervisor import Supervisor, run_until_signal

DEFAULT_SCENARIO = Path(__file__).resolve().parent.parent / "maps" / "playfield.toml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet up`."""
    parser.add_argument(
        "--scenario",
        type=Path,
        default=DEFAULT_SCENARIO,
        help="scenario file (default maps/playfield.toml)",
    )
    parser.add_argument(
        "--step",
        type=float,
        default=0.5,
        help="step period in seconds for units and coordinator (default 0.5)",
    )
    parser.add_argument(
        "--demo", action="store_true", help="keep a stream of random feasible jobs coming"
    )
    add_common(parser, own_broker="the embedded broker, on --mqtt-port")
    parser.add_argument(
        "--mqtt-port",
        type=int,
        default=1883,
        help="port of the embedded broker (default 1883; 0 picks a free one)",
    )
    parser.add_argument(
        "--ws-port",
        type=int,
        default=9001,
        help="websocket port of the embedded broker (default 9001; 0 free)",
    )
    parser.add_argument(
        "--broker-ws", metavar="URL", help="websocket URL of an external broker (with --broker)"
    )
    parser.add_argument("--port", type=int, default=5000, help="dashboard port (default 5000)")
    parser.add_argument("--db", type=Path, help="coordinator job database (default: per user)")


async def bring_up(args: argparse.Namespace, supervisor: Supervisor) -> str:
    """Start every component in order, as processes; returns the dashboard URL."""
    # Checked here, not by each component after the broker is up: one line, nothing started.
    check_step(args.step)
    spec = SystemSpec(
        scenario=with_units(load_scenario(args.scenario)),
        broker=args.broker,
        broker_ws=args.broker_ws,
        root=args.root,
        step_s=args.step,
        db_path=args.db,
        mqtt_port=args.mqtt_port,
        ws_port=args.ws_port,
        dashboard_port=args.port,
        feed=True,
        demo=args.demo,
    )
    system = await Assembly(spec, "processes", supervisor).start_processes()
    assert system.dashboard_url is not None
    return system.dashboard_url


async def _main(args: argparse.Namespace) -> int:
    supervisor = Supervisor()
    try:
        url = await bring_up(args, supervisor)
    except BaseException:
        await supervisor.stop()
        raise
    supervisor.say("up", f"gridfleet is running: open {url} (Ctrl-C stops everything)")
    return await run_until_signal(supervisor)


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet up`."""
    return asyncio.run(_main(args))
