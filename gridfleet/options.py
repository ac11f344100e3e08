"""Command-line flags every component shares: where the broker is and which topic root to use."""

from __future__ import annotations

import argparse
import re
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from gridfleet.accounts import Accounts, load_accounts
from gridfleet.config import DEFAULT_MQTT_URL, with_ca_file, with_credentials
from gridfleet.protocol.constants import DEFAULT_ROOT


class _BrokerWithCA(argparse.Action):
    """Stores --broker or --ca-file and keeps the CA folded into the broker URL (`?cafile=`).

    Folding while parsing means `args.broker` is complete whichever order the flags come in, so
    every command that reads it (not only through `broker_url`) trusts the CA. A command with
    actions folds once more after an action's flags are in (`add_actions`).
    """

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        setattr(namespace, self.dest, values)
        _fold_ca(namespace)


def _fold_ca(namespace: argparse.Namespace) -> None:
    url, ca_file = getattr(namespace, "broker", None), getattr(namespace, "ca_file", None)
    if url is not None and ca_file is not None:
        namespace.broker = with_ca_file(url, ca_file)


class ActionParser(argparse.ArgumentParser):
    """The parser of one action (`gridfleet job submit`): `-1,3` or `-2` is a value, not a flag.

    argparse takes a word that starts with `-` for an option unless it looks like a negative
    number, so `--pickup -1,3` would be "expected one argument"; here a negative square counts
    as a number too, and reaches its type, which refuses it in words.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-\d+(,-?\d+)*$|^-\d*\.\d+$")


if TYPE_CHECKING:
    _SubParsers = argparse._SubParsersAction[argparse.ArgumentParser]
else:
    _SubParsers = argparse._SubParsersAction


class _Actions(_SubParsers):
    """The actions of a command; folds --ca-file into --broker once the action's flags are in.

    argparse parses an action's flags into a namespace of its own and then copies them over the
    command's, so `--ca-file` before the action and `--broker` after it never meet in one
    `_BrokerWithCA` call: they are folded here, after the copy.
    """

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        super().__call__(parser, namespace, values, option_string)
        _fold_ca(namespace)


def add_actions(parser: argparse.ArgumentParser, **kwargs: Any) -> _SubParsers:
    """`parser.add_subparsers(**kwargs)` for a command with actions (`gridfleet job submit`).

    Give each action the command's own flags again with `add_common(action, everywhere=True)`
    (argparse.SUPPRESS defaults), so they are accepted before the action and after it alike: one
    given after the action wins, one left out there keeps what came before it (or the default).
    """
    return parser.add_subparsers(action=_Actions, parser_class=ActionParser, **kwargs)


def add_common(
    parser: argparse.ArgumentParser,
    *,
    broker: bool = True,
    own_broker: str | None = None,
    everywhere: bool = False,
) -> None:
    """Flags that most components share: --broker (with --ca-file for TLS) and --root.

    `own_broker` says what a command that starts its own broker does without --broker (the
    default is then None). `everywhere`: the parser is one action's (see `add_actions`), its
    command has the flags with their defaults already; here they default to nothing at all.
    """

    def default(value: object) -> object:
        return argparse.SUPPRESS if everywhere else value

    if broker:
        parser.add_argument(
            "--broker",
            default=default(None if own_broker else DEFAULT_MQTT_URL),
            metavar="URL",
            action=_BrokerWithCA,
            help=f"MQTT broker URL, mqtt://[user:pass@]host:port, or mqtts:// (TLS, port 8883) "
            f"(default {own_broker or DEFAULT_MQTT_URL})",
        )
        parser.add_argument(
            "--ca-file",
            metavar="FILE",
            default=default(None),
            action=_BrokerWithCA,
            help="with an mqtts:// or wss:// broker: the CA that signed its certificate "
            "(ca.pem from 'gridfleet accounts tls'; default: the system's trusted CAs)",
        )
        if own_broker is None:
            parser.add_argument(
                "--accounts",
                metavar="FILE",
                default=default(None),
                help="accounts file ('gridfleet accounts init')",
            )
            parser.add_argument(
                "--account",
                metavar="NAME",
                default=default(None),
                help="the account to log in as (default: per command)",
            )
    parser.add_argument(
        "--root",
        default=default(DEFAULT_ROOT),
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
