"""`gridfleet coordinator`: run the coordinator (its shell, `CoordinatorShell`) on a map."""

from __future__ import annotations

import argparse
import asyncio
import math

from gridfleet.config import check_step
from gridfleet.coordinator.audit import DEFAULT_AUDIT_DAYS, Identity
from gridfleet.coordinator.history import DEFAULT_RETENTION_DAYS
from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.coordinator.store import default_db_path
from gridfleet.coordinator.window import DEFAULT_WINDOW, MAX_WINDOW, check_window
from gridfleet.errors import ConfigError
from gridfleet.heap import freeze_after_start
from gridfleet.maps import load_map
from gridfleet.metrics import add_metrics_arguments, metrics_options
from gridfleet.options import accounts_of, add_common, broker_url
from gridfleet.protocol.constants import DEFAULT_STEP_S
from gridfleet.tasks import stop_on_signals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet coordinator`."""
    add_common(parser)
    parser.add_argument("--map", required=True, metavar="FILE", help="Moving AI .map file")
    parser.add_argument(
        "--step",
        type=float,
        default=DEFAULT_STEP_S,
        metavar="S",
        help=f"step period in seconds (default {DEFAULT_STEP_S})",
    )
    parser.add_argument(
        "--db", default=None, metavar="PATH", help=f"job database (default {default_db_path()})"
    )
    parser.add_argument(
        "--window",
        type=int,
        default=DEFAULT_WINDOW,
        metavar="N",
        help=f"squares a unit may be released ahead on a free road, 1 to {MAX_WINDOW} "
        f"(default {DEFAULT_WINDOW}; 1: one square per order)",
    )
    parser.add_argument(
        "--client-id",
        default=None,
        help="MQTT client id and sender (default 'coordinator'; under another --root the client "
        "id names the root too, so fleets can share a broker)",
    )
    parser.add_argument(
        "--audit-days",
        type=float,
        default=DEFAULT_AUDIT_DAYS,
        metavar="DAYS",
        help=f"how long the audit trail keeps an entry (default {DEFAULT_AUDIT_DAYS:g} days)",
    )
    parser.add_argument(
        "--history-days",
        type=float,
        default=DEFAULT_RETENTION_DAYS,
        metavar="DAYS",
        help=f"how long the job history keeps an entry (default {DEFAULT_RETENTION_DAYS:g} days)",
    )
    parser.add_argument(
        "--vouched-senders",
        action="store_true",
        help="the broker drops a request or latch naming a client id its account does not own "
        "(gridfleet broker with --accounts does; Mosquitto does not): with --accounts, the "
        "audit marks the accounts it names verified",
    )
    add_metrics_arguments(parser, "the coordinator")


def run(args: argparse.Namespace) -> int:
    """Run until interrupted (SIGINT/SIGTERM)."""
    check_step(args.step)
    check_window(args.window)
    metrics = metrics_options(args)
    if not args.audit_days > 0:
        raise ConfigError(f"--audit-days {args.audit_days:g}: give more than 0 days")
    if not 0 < args.history_days < math.inf:
        raise ConfigError(f"--history-days {args.history_days:g}: give more than 0 days")
    identity = Identity(accounts_of(args), vouched=args.vouched_senders)
    grid = load_map(args.map)
    coordinator = CoordinatorShell(
        broker_url(args, "coordinator"),
        grid,
        root=args.root,
        step_s=args.step,
        db_path=args.db,
        client_id=args.client_id,
        window=args.window,
        metrics=metrics,
        identity=identity,
        audit_days=args.audit_days,
        history_days=args.history_days,
    )

    async def main() -> None:
        freeze_after_start()
        await coordinator.run(stop_on_signals())

    asyncio.run(main())
    return 0
