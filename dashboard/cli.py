"""`gridfleet dashboard`: serve the browser dashboard."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import ssl
from collections.abc import Mapping
from pathlib import Path

from gridfleet.accounts import load_accounts
from gridfleet.config import DEFAULT_WS_URL, is_loopback
from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.server import DashboardServer
from gridfleet.dashboard.settings import INSTALL_HINT, DashboardSettings, browser_broker_url
from gridfleet.errors import ConfigError
from gridfleet.grid import GridMap
from gridfleet.maps import load_map
from gridfleet.options import add_common
from gridfleet.scenario import load_scenario
from gridfleet.tls import server_context

log = logging.getLogger("gridfleet.dashboard")
SECRET_ENV = "GRIDFLEET_DASHBOARD_SECRET"
MIN_SECRET = 32


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet dashboard`."""
    parser.add_argument(
        "--broker-ws",
        default=DEFAULT_WS_URL,
        metavar="URL[,URL...]",
        help=f"the broker's MQTT-over-websocket URL, ws:// or wss://, as the browser reaches it "
        f"(default {DEFAULT_WS_URL}; a 0.0.0.0 host: the host the browser loaded the page from); "
        "a comma-separated list of a cluster's brokers: the page is on one at a time and moves "
        "to the next when it dies",
    )
    parser.add_argument(
        "--accounts",
        metavar="FILE",
        help="accounts file ('gridfleet accounts init'): people log in with an operator or "
        "dashboard account, and the page uses that account on the broker; the session secret "
        f"is random per start (everybody logs in again after a restart) unless ${SECRET_ENV} "
        f"holds one of at least {MIN_SECRET} characters",
    )
    parser.add_argument(
        "--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)"
    )
    parser.add_argument("--port", type=int, default=5000, help="HTTP port (default 5000; 0 free)")
    parser.add_argument(
        "--client-prefix", default="dashboard", help="prefix of the page's MQTT client ids"
    )
    parser.add_argument(
        "--tls-cert",
        type=Path,
        metavar="FILE",
        help="serve the page over HTTPS with this certificate (the broker's, from 'gridfleet "
        "accounts tls', does): the login's password then crosses the network encrypted",
    )
    parser.add_argument("--tls-key", type=Path, metavar="FILE", help="its private key")
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--scenario", metavar="FILE", help="show this scenario's map until fleet/map arrives"
    )
    where.add_argument("--map", metavar="FILE", help="show this .map file until fleet/map arrives")
    parser.add_argument(
        "--audit-broker",
        metavar="URL[,URL...]",
        help="the broker the dashboard itself talks to: its HTTP API (/api/v1) reaches the fleet "
        "there, as each caller's account; with --accounts it also reports logins, logouts and "
        "failed logins to the coordinator's audit, and (--session-passwords) takes page "
        "sessions' broker passwords back, as the dashboard account (default: --broker-ws, a "
        "0.0.0.0 host read as 127.0.0.1); a comma-separated list: the first that answers",
    )
    parser.add_argument(
        "--session-passwords",
        action="store_true",
        help="with --accounts, for gridfleet's embedded broker only: hand each page session a "
        "broker password of its own, made from the account's and taken back at logout (told "
        "to the broker at --audit-broker, as a dashboard account) instead of the account's "
        "password; 'gridfleet up' sets it when it runs its own broker with accounts. Mosquitto "
        "and other brokers cannot check these: leave it out there",
    )
    add_common(parser, broker=False)


def secret_from(environ: Mapping[str, str]) -> bytes | None:
    """The session secret from the environment (None: a random one per start)."""
    secret = environ.get(SECRET_ENV)
    if secret is None:
        return None
    if len(secret) < MIN_SECRET:
        raise ConfigError(f"${SECRET_ENV}: give at least {MIN_SECRET} random characters")
    return secret.encode()


def settings_from(
    args: argparse.Namespace, environ: Mapping[str, str] = os.environ
) -> DashboardSettings:
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
        accounts=None if args.accounts is None else load_accounts(args.accounts),
        accounts_file=None if args.accounts is None else Path(args.accounts),
        secret_key=secret_from(environ),
        https=args.tls_cert is not None,
        # Also the HTTP API's way to the fleet (without accounts too, when given).
        audit_broker=None
        if args.accounts is None and args.audit_broker is None
        else audit_broker(args),
        session_passwords=args.session_passwords,
    )


def audit_broker(args: argparse.Namespace) -> str:
    """Where the dashboard reports logins: --audit-broker, else the broker's websocket URL (or
    URLs)."""
    if args.audit_broker is not None:
        return str(args.audit_broker)
    return browser_broker_url(args.broker_ws, "127.0.0.1")


def tls_from(args: argparse.Namespace) -> ssl.SSLContext | None:
    """The HTTPS context --tls-cert and --tls-key ask for (None: plain HTTP)."""
    if args.tls_cert is None and args.tls_key is None:
        return None
    if args.tls_cert is None or args.tls_key is None:
        raise ConfigError("HTTPS needs both --tls-cert FILE and --tls-key FILE")
    return server_context(args.tls_cert, args.tls_key)


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C."""
    settings = settings_from(args)
    if settings.accounts is None and not is_loopback(args.host):
        raise ConfigError(
            f"serving on {args.host} without --accounts lets anyone on that network drive the "
            "fleet: give --accounts FILE (people then log in), or serve on 127.0.0.1"
        )
    if not settings.mqtt_bundle.is_file():
        log.warning("%s", INSTALL_HINT)
    server = DashboardServer(create_app(settings), args.host, args.port, tls_from(args)).bind()
    login = ", login required" if settings.accounts is not None else ""
    log.info(
        "dashboard on %s (broker %s, root %r%s)",
        server.url,
        settings.broker_ws,
        settings.root,
        login,
    )
    # SIGTERM is how `gridfleet up` (and systemd) ask for a stop: leave cleanly with code 0.
    signal.signal(signal.SIGTERM, _leave)
    server.serve_forever()
    return 0


def _leave(signum: int, frame: object) -> None:
    raise SystemExit(0)
