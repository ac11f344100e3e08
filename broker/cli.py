"""`gridfleet broker`: run the embedded broker until Ctrl-C."""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import sys
from dataclasses import replace
from pathlib import Path

from gridfleet.accounts import load_accounts
from gridfleet.broker.embedded import BrokerSettings, EmbeddedBroker, load_settings
from gridfleet.broker.origins import dashboard_origins
from gridfleet.heap import freeze_after_start
from gridfleet.metrics import (
    MetricsOptions,
    MetricsServer,
    add_metrics_arguments,
    metrics_options,
    read_on_loop,
)
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.tasks import stop_on_signals

log = logging.getLogger("gridfleet.broker")
LEFTOVERS_S = 2.0  # after the broker stopped: how long its remaining tasks get to end


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet broker`; flags win over the config file."""
    parser.add_argument("--config", metavar="FILE", help="TOML file with a [broker] table")
    parser.add_argument("--host", help="address to bind (default 127.0.0.1: loopback only)")
    parser.add_argument("--port", type=int, help="MQTT TCP port (default 1883; 0 picks a free one)")
    parser.add_argument(
        "--ws-port",
        type=int,
        help="MQTT-over-websocket port for the dashboard (default 9001; 0 free)",
    )
    parser.add_argument("--no-ws", action="store_true", help="do not open the websocket listener")
    parser.add_argument(
        "--ws-origin",
        action="append",
        default=[],
        metavar="URL",
        help="a web page's origin (scheme://host:port) that may use the websocket listener "
        "(repeatable; default: the dashboard's on port 5000 of 127.0.0.1 and localhost, https "
        "with --tls-cert); with --accounts, pages on the host the browser reaches the broker "
        "at get in too",
    )
    parser.add_argument(
        "--accounts",
        metavar="FILE",
        help="accounts file ('gridfleet accounts init'): only they may connect, each in its role; "
        "required to listen beyond loopback",
    )
    parser.add_argument(
        "--root",
        default=DEFAULT_ROOT,
        help=f"topic root the accounts' rules use ({DEFAULT_ROOT!r})",
    )
    parser.add_argument(
        "--tls-cert",
        type=Path,
        metavar="FILE",
        help="server certificate (PEM; 'gridfleet accounts tls' makes it): the listeners are "
        "then mqtts:// and wss://",
    )
    parser.add_argument("--tls-key", type=Path, metavar="FILE", help="its private key (PEM)")
    add_metrics_arguments(parser, "the broker")


def settings_from(args: argparse.Namespace) -> BrokerSettings:
    """Defaults, then the config file, then the flags."""
    settings = load_settings(args.config) if args.config else BrokerSettings()
    changes = {
        k: v
        for k, v in (
            ("host", args.host),
            ("port", args.port),
            ("ws_port", args.ws_port),
            ("tls_cert", args.tls_cert),
            ("tls_key", args.tls_key),
        )
        if v is not None
    }
    if args.ws_origin:
        changes["ws_origins"] = tuple(args.ws_origin)
    if args.accounts is not None:
        changes["accounts"] = load_accounts(args.accounts)
        changes["root"] = args.root
    settings = BrokerSettings(**{**settings.__dict__, **changes})
    if not settings.ws_origins:  # the default dashboard's page, and no other (broker/origins.py)
        settings = replace(settings, ws_origins=dashboard_origins(tls=settings.tls))
    if args.no_ws:
        settings = BrokerSettings(**{**settings.__dict__, "ws_port": None})
    return settings


async def serve(settings: BrokerSettings, metrics: MetricsOptions | None = None) -> None:
    """Run the broker until SIGINT or SIGTERM (and its metrics, when asked for)."""
    stop = stop_on_signals()
    async with EmbeddedBroker(settings) as broker:
        ws = f" and {broker.ws_url}" if broker.ws_url else ""
        print(f"gridfleet broker listening on {broker.url}{ws}", flush=True)
        server = None
        if metrics is not None:
            from gridfleet.broker.metrics import broker_registry  # prometheus: only when asked

            loop = asyncio.get_running_loop()
            registry = broker_registry(lambda: read_on_loop(loop, broker.figures))
            server = MetricsServer(registry, metrics).start()
            print(f"gridfleet broker metrics on {server.url}", flush=True)
        try:
            freeze_after_start()
            await stop.wait()
        finally:
            if server is not None:
                server.stop()
    # amqtt's own tasks can outlive its shutdown, and asyncio.run would wait for them for good
    # (in the network soak a broker that had logged "broker stopped" was still running 15 s
    # after SIGTERM, its connections still open). Cancelled, they get LEFTOVERS_S; then the
    # process ends anyway (its sockets close with it): a supervisor is waiting to restart it.
    others = asyncio.all_tasks() - {asyncio.current_task()}
    if broker.abandoned or not await _leftovers_ended(others, LEFTOVERS_S):
        logging.shutdown()
        sys.stdout.flush()
        os._exit(0)


async def _leftovers_ended(others: set[asyncio.Task[object]], within_s: float) -> bool:
    """Cancel `others`; whether they all ended within `within_s`."""
    for task in others:
        task.cancel()
    if not others:
        return True
    _, pending = await asyncio.wait(others, timeout=within_s)
    if pending:
        log.warning("%d of the broker's tasks outlived its shutdown; ending anyway", len(pending))
    return not pending


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet broker`."""
    settings, metrics = settings_from(args), metrics_options(args)
    asyncio.run(serve(settings, metrics))
    return 0
