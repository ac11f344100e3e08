"""Command-line flags every component shares: where the broker is and which topic root to use."""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Iterable
from datetime import datetime, timedelta
from typing import Any, TypeVar, overload

from gridfleet.accounts import Accounts, load_accounts
from gridfleet.config import DEFAULT_MQTT_URL, with_ca_file, with_credentials
from gridfleet.protocol.constants import DEFAULT_ROOT, MAX_COORD
from gridfleet.squares import Cell

_N = TypeVar("_N")


class GridfleetParser(argparse.ArgumentParser):
    """gridfleet's parser: `--pickup -1,3` passes a value, and --ca-file is folded into --broker.

    argparse takes a word that starts with `-` for an option unless it looks like a negative
    number, so `--pickup -1,3` would be "expected one argument": a negative square after an
    option is passed as `--pickup=-1,3`, and reaches its type, which refuses it in words.
    Folding the CA into the broker URL (`?cafile=`) once all flags are in, the command's and its
    action's, means `args.broker` is complete whichever order they came in.
    """

    @overload
    def parse_known_args(
        self, args: Iterable[str] | None = None, namespace: None = None
    ) -> tuple[argparse.Namespace, list[str]]: ...
    @overload
    def parse_known_args(
        self, args: Iterable[str] | None, namespace: _N
    ) -> tuple[_N, list[str]]: ...
    @overload
    def parse_known_args(self, *, namespace: _N) -> tuple[_N, list[str]]: ...

    def parse_known_args(
        self, args: Iterable[str] | None = None, namespace: Any = None
    ) -> tuple[Any, list[str]]:
        """argparse's, with negative squares glued to their option and the CA folded in."""
        words = list(sys.argv[1:] if args is None else args)
        for i, word in enumerate(words):
            if (
                _NEGATIVE.fullmatch(word)
                and "," in word
                and not (i and _takes_negative(words[i - 1], [word]))
            ):
                # A square given alone (`job goal u1 -1,2`): refused by the square type, in words.
                try:
                    square(word)
                except argparse.ArgumentTypeError as refused:
                    self.error(str(refused))
        glued = [
            f"{word}={words[i + 1]}" if _takes_negative(word, words[i + 1 : i + 2]) else word
            for i, word in enumerate(words)
            if not (i and _takes_negative(words[i - 1], [word]))
        ]
        parsed, rest = super().parse_known_args(glued, namespace)
        url, ca_file = getattr(parsed, "broker", None), getattr(parsed, "ca_file", None)
        if url is not None and ca_file is not None:
            parsed.broker = with_ca_file(url, ca_file)
        return parsed, rest


_NEGATIVE = re.compile(r"-\d+(,-?\d+)*|-\d*\.\d+")


def _takes_negative(word: str, following: list[str]) -> bool:
    """Whether `word` is a long option given apart from a value that is a negative number."""
    return (
        word.startswith("--")
        and "=" not in word
        and bool(following)
        and _NEGATIVE.fullmatch(following[0]) is not None
    )


def square(text: str) -> Cell:
    """`x,y` → Cell; argparse turns the ValueError into a one-line usage error."""
    try:
        x, y = (int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a square 'x,y'") from None
    if x < 0 or y < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: squares start at 0,0 (top left)")
    if x > MAX_COORD or y > MAX_COORD:
        raise argparse.ArgumentTypeError(f"{text!r} is off every map: x and y go up to {MAX_COORD}")
    return Cell(x, y)


def add_actions(parser: argparse.ArgumentParser, **kwargs: Any) -> Any:
    """`parser.add_subparsers(**kwargs)` for a command with actions (`gridfleet job submit`).

    Give each action the command's own flags again with `add_common(action, everywhere=True)`
    (argparse.SUPPRESS defaults), so they are accepted before the action and after it alike: one
    given after the action wins, one left out there keeps what came before it (or the default).
    """
    return parser.add_subparsers(parser_class=GridfleetParser, **kwargs)


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
            metavar="URL[,URL...]",
            help=f"MQTT broker URL, mqtt://[user:pass@]host:port, or mqtts:// (TLS, port 8883), "
            f"or a comma-separated list of a cluster's nodes (on one at a time, the next when it "
            f"dies) (default {own_broker or DEFAULT_MQTT_URL})",
        )
        parser.add_argument(
            "--ca-file",
            metavar="FILE",
            default=default(None),
            help="with an mqtts:// or wss:// broker (a list's TLS ones): the CA that signed its "
            "certificate (ca.pem from 'gridfleet accounts tls'; default: the system's trusted CAs)",
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


SPAN_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400}
_SPAN = re.compile(r"(\d+(?:\.\d+)?)\s*([smhd])")
MOMENT_FORMS = (
    "an ISO 8601 time or date, local unless it names its zone (2026-11-26T14:02, 2026-11-26, "
    "2026-11-26T14:02Z), now, or a span back from now (90s, 30m, 24h, 7d)"
)


def moment(text: str, now: datetime) -> datetime:
    """A point in time as a person types it (see MOMENT_FORMS); ValueError when it is none.

    A time without a zone is the local time of the machine the command runs on, as a person at
    it reads a clock: the same rule for every command that takes one.
    """
    word = text.strip()
    if word == "now":
        return now
    span = _SPAN.fullmatch(word)
    if span is not None:
        return now - timedelta(seconds=float(span.group(1)) * SPAN_UNITS[span.group(2)])
    try:
        at = datetime.fromisoformat(word)
    except ValueError:
        raise ValueError(f"{text!r} is not a time: give {MOMENT_FORMS}") from None
    return at if at.tzinfo is not None else at.astimezone()  # local, with its zone
