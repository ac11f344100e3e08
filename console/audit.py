"""`gridfleet audit`: who did what and when, from the coordinator's audit trail, page by page.

Times are ISO 8601, local unless they name their zone (`2026-11-26T14:02`, a date alone is its
midnight, `Z` or `+01:00` honoured), or a span back from now: `90s`, `30m`, `2h`, `7d`. A range that cannot
be read, or whose start is after its end, is refused in one line before anything is sent.
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import json
import math
import secrets
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from typing import TextIO

from gridfleet.config import redacted
from gridfleet.console.operator import operator_session
from gridfleet.errors import ConfigError, GridfleetError, ProtocolError
from gridfleet.options import add_common, broker_url, moment
from gridfleet.protocol import Topics, validate_id
from gridfleet.protocol.messages import MAX_AUDIT_PAGE, AuditEntry

WAIT_S = 10.0  # for each page's reply, re-sent meanwhile
RETRY_S = 2.0
PAGE = 200  # entries asked for at a time
FIELDS = ("at", "actor", "verified", "via", "act", "target", "detail", "outcome", "reason")


def parse_time(text: str, now: datetime, flag: str) -> datetime:
    """`text` read by gridfleet.options.moment's rule; ConfigError naming `flag` otherwise."""
    try:
        return moment(text, now)
    except ValueError as exc:
        raise ConfigError(f"{flag} {exc}") from None


def time_range(since: str, until: str | None, now: datetime) -> tuple[datetime, datetime | None]:
    """(since, until) read from the flags; ConfigError in one line when the range is wrong."""
    start = parse_time(since, now, "--since")
    end = None if until is None else parse_time(until, now, "--until")
    if start > (end or now):
        what = f"--until {end.isoformat()}" if end is not None else f"now ({now.isoformat()})"
        raise ConfigError(f"--since {start.isoformat()} is after {what}: nothing can lie between")
    return start, end


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet audit`."""
    add_common(parser)
    parser.add_argument(
        "--since",
        required=True,
        metavar="TIME",
        help="from this time (local unless it names its zone), or 2h, 7d ago",
    )
    parser.add_argument("--until", metavar="TIME", help="up to this time (default: now)")
    parser.add_argument("--actor", metavar="ACCOUNT", help="only this account's acts")
    shape = parser.add_mutually_exclusive_group()
    shape.add_argument("--json", action="store_true", help="one JSON array of the entries")
    shape.add_argument("--csv", action="store_true", help="CSV with a header row")
    parser.add_argument(
        "--timeout",
        type=float,
        default=WAIT_S,
        metavar="S",
        help=f"seconds to wait for each page from the coordinator (default {WAIT_S:g})",
    )


async def read_trail(
    url: str,
    topics: Topics,
    since: datetime,
    until: datetime | None,
    actor: str | None,
    timeout: float,
) -> list[AuditEntry]:
    """Every entry of the range, oldest first, page by page; GridfleetError when refused."""
    out: list[AuditEntry] = []
    async with operator_session(url, topics, f"audit-{secrets.token_hex(3)}", RETRY_S) as operator:
        limit = min(PAGE, MAX_AUDIT_PAGE)
        cursor: str | None = None
        while True:
            page = await operator.audit(
                timeout, since=since, until=until, actor=actor, limit=limit, cursor=cursor
            )
            if not page.accepted:
                raise GridfleetError(f"refused: {page.reason}")
            out += page.entries
            cursor = page.next_cursor
            if cursor is None:
                return out


def print_table(entries: list[AuditEntry], out: TextIO) -> None:
    """The entries as a table, one line each, oldest first."""
    print(f"{'at (UTC)':<24} {'actor':<16} {'act':<15} {'target':<16} outcome", file=out)
    for e in entries:
        actor = e.actor or "-"
        if not e.verified:
            actor += "?"  # what the client claimed: the broker did not vouch for it
        line = f"{_when(e.at):<24} {actor:<16} {e.act:<15} {e.target or '-':<16} {e.outcome}"
        if e.reason:
            line += f": {e.reason}"
        if e.detail:
            line += f"  ({e.detail})"
        print(line, file=out)
    if any(not e.verified for e in entries):
        print(
            "? not vouched for: what the client claimed, or the name typed at a failed login",
            file=out,
        )


def _when(at: datetime) -> str:
    return at.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def rows(entries: list[AuditEntry]) -> list[dict[str, object]]:
    """The entries as plain rows (JSON's and CSV's), times in UTC ISO 8601."""
    out = []
    for e in entries:
        row: dict[str, object] = json.loads(e.model_dump_json())
        row["at"] = _when(e.at)
        out.append(row)
    return out


def print_csv(entries: list[AuditEntry], out: TextIO) -> None:
    """CSV with a header row; every field, empty for null."""
    writer = csv.DictWriter(out, fieldnames=FIELDS, lineterminator="\n")
    writer.writeheader()
    for row in rows(entries):
        writer.writerow({k: "" if row.get(k) is None else row[k] for k in FIELDS})


def run(args: argparse.Namespace, now: Callable[[], datetime] = lambda: datetime.now(UTC)) -> int:
    """Entry point of `gridfleet audit`."""
    if not 0 < args.timeout < math.inf:
        raise ConfigError(f"--timeout {args.timeout:g}: give a positive number of seconds")
    since, until = time_range(args.since, args.until, now())
    actor = None
    if args.actor is not None:
        try:
            actor = validate_id(args.actor, "--actor")
        except ProtocolError as exc:
            raise ConfigError(str(exc)) from None
    url = broker_url(args, "operator")
    try:
        entries = asyncio.run(read_trail(url, Topics(args.root), since, until, actor, args.timeout))
    except GridfleetError as exc:
        if str(exc).startswith("refused: "):
            print(exc, file=sys.stdout)
            return 1
        raise GridfleetError(f"{exc} (broker {redacted(args.broker)})") from None
    if args.json:
        json.dump(rows(entries), sys.stdout, indent=None)
        print()
    elif args.csv:
        print_csv(entries, sys.stdout)
    else:
        print_table(entries, sys.stdout)
    return 0
