"""`gridfleet dashboard`: serve the browser dashboard."""

from __future__ import annotations

import argparse
import logging
import signal

from dashboard.app import create_app
from dashboard.server import DashboardServer
from dashboard.settings import INSTALL_HINT, DashboardSettings
from gridfleet.config import DEFAULT_WS_URL
from gridfleet.grid import GridMap
from gridfleet.maps import load_map
from gridfleet.options import add_common
from gridfleet.scenario import load_scenario

log = logging.getLogger("gridfleet.dashboard")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet dashboard`."""
    parser.add_argument(
        "--broker-ws",
        default=DEFAULT_WS_URL,
        metavar="URL",
        help=f"the broker's MQTT-over-websocket URL, as the browser reaches it (default {DEFAULT_WS_URL})",
    )
    parser.add_argument(
        "--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)"
    )
    parser.add_argument("--port", type=int, default=5000, help="HTTP port (default 5000; 0 free)")
    parser.add_argument(
        "--client-prefix", default="dashboard", help="prefix of the page's MQTT client ids"
    )
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--scenario", metavar="FILE", help="show this scenario's map until fleet/map arrives"
    )
    where.add_argument("--map", metavar="FILE", help="show this .map file until fleet/map arrives")
    add_common(parser, broker=False)


def settings_from(args: argparse.Namespace) -> DashboardSettings:
    """Settings from parsed flags; bad files or URLs raise GridfleetError with the reason."""
    grid: GridMap | None = None
    colors: dict[str, str] = {}
    if args.scenario:
        scenario = load_scenario(args.scenario)
        grid = scenario.grid
        colors = {u.id: u.color for u in scenario.units}
    elif args.map:
        grid = load_map(args.map)
    return DashboardSettings(
        broker_ws=args.broker_ws,
        root=args.root,
        client_prefix=args.client_prefix,
        map=grid,
        colors=colors,
    )


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C."""
    settings = settings_from(args)
    if not settings.mqtt_bundle.is_file():
        log.warning("%s", INSTALL_HINT)
    server = DashboardServer(create_app(settings), args.host, args.port).bind()
    log.info("dashboard on %s (broker %s, root %r)", server.url, settings.broker_ws, settings.root)
    # SIGTERM is how `gridfleet up` (and systemd) ask for a stop: leave cleanly with code 0.
    signal.signal(signal.SIGTERM, _leave)
    server.serve_forever()
    return 0


def _leave(signum: int, frame: object) -> None:
    raise SystemExit(0)
