"""Command-line flags every component shares: where the broker is and which topic root to use."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from gridfleet.accounts import Accounts, load_accounts
from gridfleet.config import DEFAULT_MQTT_URL, with_ca_file, with_credentials
from gridfleet.protocol.constants import DEFAULT_ROOT


class _BrokerWithCA(argparse.Action):
    """Stores --broker or --ca-file and keeps the CA folded into the broker URL (`?cafile=`).

    Folding while parsing means `args.broker` is complete whichever order the flags come in, so
    every command that reads it (not only through `broker_url`) trusts the CA.
    """

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        setattr(namespace, self.dest, values)
        url, ca_file = getattr(namespace, "broker", None), getattr(namespace, "ca_file", None)
        if url is not None and ca_file is not None:
            namespace.broker = with_ca_file(url, ca_file)


def add_common(
    parser: argparse.ArgumentParser, *, broker: bool = True, own_broker: str | None = None
) -> None:
    """Flags that most components share: --broker (with --ca-file for TLS) and --root.

    `own_broker` says what a command that starts its own broker does without --broker (the
    default is then None).
    """
    if broker:
        parser.add_argument(
            "--broker",
            default=None if own_broker else DEFAULT_MQTT_URL,
            metavar="URL",
            action=_BrokerWithCA,
            help=f"MQTT broker URL, mqtt://[user:pass@]host:port, or mqtts:// (TLS, port 8883) "
            f"(default {own_broker or DEFAULT_MQTT_URL})",
        )
        parser.add_argument(
            "--ca-file",
            metavar="FILE",
            action=_BrokerWithCA,
            help="with an mqtts:// or wss:// broker: the CA that signed its certificate "
            "(ca.pem from 'gridfleet accounts tls'; default: the system's trusted CAs)",
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
