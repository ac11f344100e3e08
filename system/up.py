"""`gridfleet up`: the whole system — broker, coordinator, units, dashboard — as supervised processes."""

from __future__ import annotations

import argparse
import asyncio
import re
import sys
from pathlib import Path

from gridfleet.config import check_step
from gridfleet.errors import ConfigError
from gridfleet.options import add_common
from gridfleet.scenario import load_scenario, with_units
from system.supervisor import ChildSpec, Supervisor, run_until_signal

DEFAULT_SCENARIO = Path(__file__).resolve().parent.parent / "maps" / "playfield.toml"
BROKER_READY = re.compile(r"listening on (mqtt://\S+) and (ws://\S+)")
DASHBOARD_READY = re.compile(r"(http://\S+)")


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


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "system.cli", *args]


async def bring_up(args: argparse.Namespace, supervisor: Supervisor) -> str:
    """Start every component in order; returns the dashboard URL."""
    # Checked here, not by each component after the broker is up: one line, nothing started.
    check_step(args.step)
    scenario = with_units(load_scenario(args.scenario))
    if args.broker is None:
        broker = await supervisor.start(
            ChildSpec(
                "broker",
                _cli("broker", "--port", str(args.mqtt_port), "--ws-port", str(args.ws_port)),
                ready=BROKER_READY,
            )
        )
        assert broker.ready_match is not None
        mqtt_url, ws_url = broker.ready_match.group(1), broker.ready_match.group(2)
    else:
        if not args.broker_ws:
            raise ConfigError("with --broker, also give --broker-ws for the dashboard")
        mqtt_url, ws_url = args.broker, args.broker_ws
    common = ["--broker", mqtt_url, "--root", args.root]
    step = ["--step", str(args.step)]
    coordinator = ["coordinator", *common, "--map", str(scenario.map_path), *step]
    if args.db is not None:
        coordinator += ["--db", str(args.db)]
    await supervisor.start(ChildSpec("coordinator", _cli(*coordinator)))
    await supervisor.start(
        ChildSpec("robots", _cli("robots", *common, "--scenario", str(args.scenario), *step))
    )
    dashboard = await supervisor.start(
        ChildSpec(
            "dashboard",
            _cli(
                "dashboard",
                "--broker-ws",
                ws_url,
                "--root",
                args.root,
                "--port",
                str(args.port),
                "--scenario",
                str(args.scenario),
            ),
            ready=DASHBOARD_READY,
        )
    )
    feeder = _cli("feed", *common, "--scenario", str(args.scenario), *step)
    if args.demo:
        feeder.append("--demo")
    await supervisor.start(ChildSpec("operator", feeder, restart=args.demo))
    assert dashboard.ready_match is not None
    return dashboard.ready_match.group(1)


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
