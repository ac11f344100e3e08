"""Command-line flags every component shares: where the broker is and which topic root to use."""

from __future__ import annotations

import argparse

from gridfleet.accounts import Accounts, load_accounts
from gridfleet.config import DEFAULT_MQTT_URL, with_credentials
from gridfleet.protocol.constants import DEFAULT_ROOT


def add_common(
    parser: argparse.ArgumentParser, *, broker: bool = True, own_broker: str | None = None
) -> None:
    """Flags that most components share: --broker and --root.

    `own_broker` says what a command that starts its own broker does without --broker (the
    default is then None).
    """
    if broker:
        parser.add_argument(
            "--broker",
            default=None if own_broker else DEFAULT_MQTT_URL,
            metavar="URL",
            help=f"MQTT broker URL, mqtt://[user:pass@]host:port (default "
            f"{own_broker or DEFAULT_MQTT_URL})",
        )
        if own_broker is None:
            parser.add_argument(
                "--accounts", metavar="FILE", help="accounts file ('gridfleet accounts init')"
            )
            parser.add_argument(
                "--account", metavar="NAME", help="the account to log in as (default: per command)"
            )
    parser.add_argument(
        "--root",
        default=DEFAULT_ROOT,
        help=f"topic root, so fleets can share a broker (default {DEFAULT_ROOT!r})",
    )


def accounts_of(args: argparse.Namespace) -> Accounts | None:
    """The accounts file named by --accounts, or None."""
    path = getattr(args, "accounts", None)
    return None if path is None else load_accounts(path)


def broker_url(args: argparse.Namespace, account: str) -> str:
    """--broker, logging in as --account (default `account`) when --accounts names a file."""
    accounts = accounts_of(args)
    if accounts is None:
        return str(args.broker)
    chosen = accounts.get(getattr(args, "account", None) or account)
    return with_credentials(args.broker, chosen.name, chosen.password)
