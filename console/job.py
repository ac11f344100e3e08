"""`gridfleet job`: an operator's command line: submit, cancel and list jobs, goals, units'
controls (pause, out of service, charge) and removal, closed zones, the stop."""

from __future__ import annotations

import argparse
import asyncio
import csv
import math
import sys
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, TextIO, get_args

from gridfleet.console.operator import Operator, operator_session
from gridfleet.errors import ConfigError, GridfleetError, ProtocolError
from gridfleet.options import add_actions, add_common, broker_url, moment, square
from gridfleet.protocol import (
    EstopSignal,
    JobHistoryEntry,
    JobsView,
    Reply,
    ZonesView,
    validate_id,
)
from gridfleet.protocol.constants import MAX_ESTOP_REASON, MAX_TEXT
from gridfleet.protocol.messages import (
    FINAL_JOB_STATES,
    ChargeEntry,
    FleetMap,
    JobState,
    PlaceKind,
)
from gridfleet.protocol.topics import Topics
from gridfleet.squares import Cell

WAIT_S = 10.0


def kilograms(text: str) -> float:
    """A mass in kg, more than 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of kg") from None
    if value == math.inf:
        raise argparse.ArgumentTypeError(f"{text!r} is too large a number of kg")
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: a mass must be more than 0 kg")
    return value


def priority(text: str) -> int:
    """A job's priority: a whole number from 0 to 100."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 100:
        raise argparse.ArgumentTypeError(
            f"{text!r}: a priority is a whole number from 0 to 100 (higher goes first)"
        )
    return value


def identifier(what: str) -> Callable[[str], str]:
    """An argparse type for an id (a job's, a unit's): the protocol's rule, in words."""

    def check(text: str) -> str:
        try:
            return validate_id(text, what)
        except ProtocolError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    check.__name__ = what  # argparse names the type in some messages
    return check


def place_or_square(text: str) -> Cell | str:
    """A job's pickup or dropoff: `X,Y` is a square, anything else a place's name (an id)."""
    if "," in text:
        return square(text)
    try:
        return validate_id(text, "place name")
    except ProtocolError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a square X,Y nor a place's name (an id: 1-64 letters, digits, "
            "'_', '.', '-', starting with a letter or digit)"
        ) from None


def reason(text: str) -> str:
    """An emergency stop's reason: one line of at most MAX_ESTOP_REASON characters."""
    if any(c in text for c in "\r\n\x00"):
        raise argparse.ArgumentTypeError(f"{text[:40]!r}: a reason is one line")
    if len(text) > MAX_ESTOP_REASON:
        raise argparse.ArgumentTypeError(
            f"{text[:20]!r}... has {len(text)} characters: a reason is one line of at most "
            f"{MAX_ESTOP_REASON}"
        )
    return text


def zone_reason(text: str) -> str:
    """Why a zone is closed: one line of 1 to MAX_TEXT characters."""
    if not text.strip():
        raise argparse.ArgumentTypeError("give a reason: why the zone is closed")
    if any(c in text for c in "\r\n\x00"):
        raise argparse.ArgumentTypeError(f"{text[:40]!r}: a reason is one line")
    if len(text) > MAX_TEXT:
        raise argparse.ArgumentTypeError(
            f"{text[:20]!r}... has {len(text)} characters: a zone's reason has at most {MAX_TEXT}"
        )
    return text


def _add_flags(parser: argparse.ArgumentParser, *, everywhere: bool = False) -> None:
    """The flags every action takes, before the action or after it."""
    add_common(parser, everywhere=everywhere)
    parser.add_argument(
        "--timeout",
        type=float,
        default=argparse.SUPPRESS if everywhere else WAIT_S,
        metavar="S",
        help=f"seconds to wait for the coordinator (default {WAIT_S:g})",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Subcommands of `gridfleet job`; the common flags go before the action or after it."""
    _add_flags(parser)
    sub = add_actions(parser, dest="action", required=True, metavar="ACTION")
    submit = sub.add_parser("submit", help="queue a pick-and-deliver job")
    submit.add_argument(
        "--pickup",
        type=place_or_square,
        required=True,
        metavar="PLACE|X,Y",
        help="place (by name: `gridfleet job places`) or square to fetch from",
    )
    submit.add_argument(
        "--dropoff",
        type=place_or_square,
        required=True,
        metavar="PLACE|X,Y",
        help="place or square to deliver to",
    )
    submit.add_argument(
        "--mass", type=kilograms, required=True, metavar="KG", help="the item's mass in kg"
    )
    submit.add_argument(
        "--priority", type=priority, default=0, metavar="0-100", help="higher goes first"
    )
    submit.add_argument(
        "--id",
        dest="job_id",
        type=identifier("job id"),
        help="job id (default: the coordinator picks one)",
    )
    cancel = sub.add_parser("cancel", help="delete a queued job or abort an active one")
    cancel.add_argument("job_id", type=identifier("job id"))
    goal = sub.add_parser("goal", help="send one unit to a square (or --clear its goal)")
    goal.add_argument("unit", type=identifier("unit id"))
    where = goal.add_mutually_exclusive_group()  # neither: a worded refusal in `run`
    where.add_argument("target", nargs="?", type=square, metavar="X,Y")
    where.add_argument("--clear", action="store_true", help="clear the unit's goal")
    for name, command in UNIT_ACTIONS.items():
        control = sub.add_parser(name, help=UNIT_HELP[command])
        control.add_argument("unit", type=identifier("unit id"))
    remove = sub.add_parser(
        "remove",
        help="forget a lost unit that is off the floor for good: its squares freed, its job "
        "re-queued (failed if it carried the item)",
        description="Remove a unit that is gone for good (protocol.md §6.11). Only a lost unit "
        "(offline, broken or silent) can be removed: confirm first that it is physically off "
        "the floor. Its squares are freed at once, its job goes back to the queue (or fails, "
        "when the item left with it), its retained topics are cleared and the act is audited. "
        "Should it come back, it joins as a new unit: with a new 'online' on its connection, "
        "its square checked as any unit's, none of its old job or squares.",
    )
    remove.add_argument("unit", type=identifier("unit id"))
    remove.add_argument(
        "--reason", type=reason, default=None, help="one line, for the audit and the events"
    )
    clear = sub.add_parser(
        "clear-obstacles", help="forget discovered obstacles that are gone (X,Y ... or --all)"
    )
    which = clear.add_mutually_exclusive_group()  # neither: a worded refusal in `run`
    which.add_argument("squares", nargs="*", type=square, default=[], metavar="X,Y")
    which.add_argument("--all", action="store_true", help="every discovered obstacle")
    sub.add_parser("list", help="print the job queue")
    close_zone = sub.add_parser(
        "close-zone",
        help="close a rectangle of squares: no unit is sent in, units inside leave",
        description="Close the rectangle between two corners (protocol.md §6.12): planning "
        "treats its squares as walls, a unit inside leaves by the shortest way (or holds, when "
        "it cannot), and jobs with a pickup or dropoff inside wait until it opens. The stop is "
        "not affected. Closing a zone again as it is changes nothing.",
    )
    close_zone.add_argument("name", type=identifier("zone name"))
    close_zone.add_argument("first", type=square, metavar="X1,Y1", help="one corner")
    close_zone.add_argument("last", type=square, metavar="X2,Y2", help="the opposite corner")
    close_zone.add_argument(
        "--reason", type=zone_reason, required=True, help="why, one line: everybody sees it"
    )
    open_zone = sub.add_parser("open-zone", help="open a closed zone again")
    open_zone.add_argument("name", type=identifier("zone name"))
    sub.add_parser("zones", help="print the closed zones")
    places = sub.add_parser("places", help="print the map's named places (name, square, kinds)")
    places.add_argument("--kind", choices=get_args(PlaceKind), help="only the places of this kind")
    history = sub.add_parser(
        "history", help="print every change of every job in a time range (table, CSV or JSON)"
    )
    history.add_argument(
        "--since",
        type=timepoint,
        default=timepoint("24h"),
        metavar="WHEN",
        help="from: an ISO 8601 time or date (local time unless it says its zone), or an age: "
        "30m, 24h, 7d (default 24h ago)",
    )
    history.add_argument(
        "--until", type=timepoint, default=None, metavar="WHEN", help="until (default now)"
    )
    history.add_argument("--unit", type=identifier("unit id"), help="only this unit's")
    history.add_argument("--job", dest="job_id", type=identifier("job id"), help="only this job's")
    history.add_argument(
        "--state", choices=get_args(JobState), help="only the changes into this state"
    )
    history.add_argument(
        "--charges",
        action="store_true",
        help="the charges' starts and ends instead of the jobs' changes (--unit applies; --job "
        "and --state do not)",
    )
    form = history.add_mutually_exclusive_group()
    form.add_argument("--csv", action="store_true", help="comma-separated values, with a header")
    form.add_argument("--json", action="store_true", help="a JSON array of entries")
    stop = sub.add_parser("stop", help="engage the fleet-wide emergency stop (latched)")
    stop.add_argument("--reason", type=reason, default="operator", help="one line, for everybody")
    release = sub.add_parser("release", help="release the emergency stop")
    release.add_argument(
        "--reason", type=reason, default="operator", help="one line, for everybody"
    )
    for action in sub.choices.values():
        _add_flags(action, everywhere=True)


# `gridfleet job ACTION UNIT` -> the control_unit command it sends (protocol.md §6.4).
UNIT_ACTIONS = {
    "pause": "pause",
    "resume": "resume",
    "out-of-service": "out_of_service",
    "in-service": "in_service",
    "charge": "charge",
}
UNIT_HELP = {
    "pause": "hold one unit where it is; its job waits",
    "resume": "let a paused unit go on",
    "out_of_service": "take one unit out of service: no jobs, its unstarted job re-queued",
    "in_service": "bring a unit back into service",
    "charge": "send one unit to charge (once it carries nothing), to full, then back to work",
}


def timepoint(text: str) -> datetime:
    """A point in time for `--since`/`--until` (gridfleet.options.moment's rule)."""
    try:
        return moment(text, datetime.now(UTC))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


HISTORY_COLUMNS = (
    "at", "job", "state", "unit", "wait", "reason", "since_submitted_s", "pickup_x",
    "pickup_y", "dropoff_x", "dropoff_y", "mass_kg", "priority", "submitted_by",
)  # fmt: skip


def history_row(entry: JobHistoryEntry) -> list[str]:
    """One entry as the CSV's cells, in HISTORY_COLUMNS' order."""
    cells: list[object] = [
        entry.at.astimezone(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z"),
        entry.job,
        entry.state,
        entry.unit,
        entry.wait,
        entry.reason,
        entry.since_submitted_s,
        *entry.pickup,
        *entry.dropoff,
        entry.mass_kg,
        entry.priority,
        entry.submitted_by,
    ]
    return ["" if c is None else str(c) for c in cells]


CHARGE_COLUMNS = ("at", "unit", "charger", "event", "battery_pct", "reason")


def charge_row(entry: ChargeEntry) -> list[str]:
    """One charge entry as the CSV's cells, in CHARGE_COLUMNS' order."""
    at = entry.at.astimezone(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")
    cells = [at, entry.unit, entry.charger, entry.event, entry.battery_pct, entry.reason]
    return ["" if c is None else str(c) for c in cells]


def history_line(entry: JobHistoryEntry) -> str:
    """One job change as the table's line."""
    at, after = history_row(entry)[0], f"{entry.since_submitted_s:.1f}s"
    line = f"{at:<24} {entry.job:<24} {entry.state:<11} {entry.unit or '-':<10}"
    return f"{line} {after:>9}  {entry.reason or ''}".rstrip()


def charge_line(entry: ChargeEntry) -> str:
    """One charge entry as the table's line."""
    at, pct = charge_row(entry)[0], f"{entry.battery_pct:.1f} %"
    line = f"{at:<24} {entry.unit:<10} {entry.charger:<10} {entry.event:<8} {pct:>8}"
    return f"{line}  {entry.reason or ''}".rstrip()


@dataclass(frozen=True)
class HistoryShape:
    """How one kind of history entry is printed: its CSV columns and row, its table's head and
    line, and what the count at the end calls them (singular, plural)."""

    columns: tuple[str, ...]
    row: Callable[[Any], list[str]]
    head: str
    line: Callable[[Any], str]
    nouns: tuple[str, str]


JOB_CHANGES = HistoryShape(
    HISTORY_COLUMNS,
    history_row,
    f"{'at (UTC)':<24} {'job':<24} {'state':<11} {'unit':<10} {'after':>9}  why",
    history_line,
    ("change", "changes"),
)
CHARGES = HistoryShape(
    CHARGE_COLUMNS,
    charge_row,
    f"{'at (UTC)':<24} {'unit':<10} {'charger':<10} {'event':<8} {'battery':>8}  why",
    charge_line,
    ("charge entry", "charge entries"),
)


async def print_history(operator: Operator, args: argparse.Namespace, out: TextIO) -> int:
    """`job history` (or its `--charges`): every page of the query, printed as it arrives; 1
    when it is refused."""
    query: dict[str, object] = {"since": args.since, "until": args.until, "unit": args.unit}
    if args.charges:
        if args.job_id is not None or args.state is not None:
            print("refused: --job and --state select jobs, not charges", file=sys.stderr)
            return 2
        query["kind"], shape = "charges", CHARGES
    else:
        query |= {"job_id": args.job_id, "state": args.state}
        shape = JOB_CHANGES
    writer = csv.writer(out, lineterminator="\n") if args.csv else None
    if writer is not None:
        writer.writerow(shape.columns)
    elif args.json:
        print("[", file=out)
    else:
        print(shape.head, file=out)
    cursor: str | None = None
    count = 0
    while True:
        page = await operator.job_history(args.timeout, **query, cursor=cursor)
        if isinstance(page, Reply) or not page.accepted:
            print(f"refused: {page.reason}", file=sys.stderr)
            return 1
        entries: list[JobHistoryEntry] | list[ChargeEntry] = (
            page.charges if args.charges else page.entries
        )
        for entry in entries:
            if writer is not None:
                writer.writerow(shape.row(entry))
            elif args.json:
                comma = "," if count else " "
                print(f"{comma}{entry.model_dump_json(exclude_none=True)}", file=out)
            else:
                print(shape.line(entry), file=out)
            count += 1
        cursor = page.next_cursor
        if cursor is None:
            break
    if args.json:
        print("]", file=out)
    elif writer is None:
        print(f"{count} {shape.nouns[count != 1]}", file=out)
    return 0


def print_jobs(view: JobsView, out: TextIO) -> None:
    """The queue as a table: jobs not finished, then the latest finished, newest first."""
    print(f"{'job':<24} {'state':<11} {'unit':<10} {'mass':>6}  pickup -> dropoff", file=out)
    for job in view.listed():
        route = (
            f"{_named(job.pickup_place, job.pickup)} -> {_named(job.dropoff_place, job.dropoff)}"
        )
        line = f"{job.id:<24} {job.state:<11} {job.unit or '-':<10} {job.mass_kg:>6.2f}  {route}"
        if job.reason:
            line += f"  ({job.reason})"
        elif job.wait_reason:  # why a job not final is not moving (protocol.md §5.3)
            line += f"  waits: {job.wait_reason}"
        print(line, file=out)
    ended = sum(n for s, n in view.counts.items() if s in FINAL_JOB_STATES)
    if ended > len(view.finished):
        counts = ", ".join(f"{n} {s}" for s, n in view.counts.items() if s in FINAL_JOB_STATES)
        print(f"... the latest {len(view.finished)} finished of {ended} ({counts})", file=out)


def _named(place: str | None, at: Cell) -> str:
    """A job's square, with the place it was named by: `A3 [3, 4]`."""
    return str(list(at)) if place is None else f"{place} {list(at)}"


def print_places(fleet_map: FleetMap, kind: str | None, out: TextIO) -> None:
    """The map's places as a table (name, square, kinds), in name order; only `kind`'s if given."""
    places = sorted(
        (p for p in fleet_map.places if kind is None or kind in p.kinds), key=lambda p: p.name
    )
    if not places:
        which = f" of kind {kind}" if kind else ""
        print(
            f"the map {fleet_map.name!r} has no places{which} (a scenario names them: [[places]])",
            file=out,
        )
        return
    print(f"{'place':<24} {'square':<12} kinds", file=out)
    for p in places:
        print(f"{p.name:<24} {list(p.square)!s:<12} {', '.join(p.kinds)}", file=out)
    print(f"{len(places)} place{'s' if len(places) != 1 else ''}", file=out)


def print_zones(view: ZonesView, out: TextIO) -> None:
    """The closed zones as a table, in the order they were closed."""
    if not view.zones:
        print("no zone is closed", file=out)
        return
    print(
        f"{'zone':<20} {'from':<12} {'to':<12} {'squares':>7}  {'closed by':<14} "
        f"{'closed at (UTC)':<20} why",
        file=out,
    )
    for z in view.zones:
        squares = (z.last.x - z.first.x + 1) * (z.last.y - z.first.y + 1)
        at = z.closed_at.astimezone(UTC).strftime("%Y-%m-%d %H:%M:%S")
        line = f"{z.name:<20} {list(z.first)!s:<12} {list(z.last)!s:<12} {squares:>7}  "
        print(f"{line}{z.closed_by or '-':<14} {at:<20} {z.reason}", file=out)
    print(f"{len(view.zones)} zone{'s' if len(view.zones) != 1 else ''} closed", file=out)


def _who(signal: EstopSignal) -> str:
    return f"{signal.by}" + (f": {signal.reason}" if signal.reason else "")


def _presses(operator: Operator) -> str:
    """The held presses in words: "the press of unit2 (bumper hit)"."""
    held = sorted(operator.stop.presses.values(), key=lambda p: p.by)
    words = [f"{p.by}" + (f" ({p.reason})" if p.reason else "") for p in held]
    return f"the press{'es' if len(words) > 1 else ''} of {', '.join(words)}"


def _holds(presses: dict[str, EstopSignal]) -> str:
    return "hold" if len(presses) > 1 else "holds"


def _them(presses: dict[str, EstopSignal]) -> str:
    return "them" if len(presses) > 1 else "it"


async def engage(operator: Operator, why: str, out: TextIO) -> int:
    """`job stop`: latch the stop, unless the latch already holds it (its cause stays)."""
    view = await operator.stop_as_kept()
    if view.latch is not None and view.latch.engaged:
        print(
            f"the emergency stop was already engaged (latched by {_who(view.latch)}); "
            "left as it was",
            file=out,
        )
        return 0
    await operator.set_estop(True, why)
    if view.presses:
        print(
            f"emergency stop ENGAGED: it was already engaged by {_presses(operator)}; "
            "now it is latched too",
            file=out,
        )
    else:
        print("emergency stop ENGAGED", file=out)
    return 0


async def release(operator: Operator, why: str, timeout: float, out: TextIO) -> int:
    """`job release`: release the latch when something holds the fleet; 1 if it stays stopped.

    A press is cleared by the coordinator when the latch goes from engaged to released, so a
    press the latch does not hold yet is waited for (the coordinator latches it at once).
    """
    view = await operator.stop_as_kept()
    if not view.engaged and not operator.coordinator_stopped:
        print("nothing to release: the emergency stop was not engaged", file=out)
        return 0
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while view.presses and not view.latch_engaged and operator.coordinator_online.is_set():
        operator.stop_changed.clear()
        try:
            await asyncio.wait_for(operator.stop_changed.wait(), deadline - loop.time())
        except TimeoutError:
            break
    if view.presses and not view.latch_engaged:
        held = f"not released: {_presses(operator)} {_holds(view.presses)} the fleet"
        them = _them(view.presses)
        if operator.coordinator_online.is_set():
            print(
                f"{held}, and the coordinator has not latched {them} within {timeout:g} s (only "
                "a latched stop is released; the coordinator then clears the presses)",
                file=out,
            )
        else:
            print(
                f"{held}, and no coordinator is online to clear {them} (it clears the presses "
                "when an operator releases the latch): release once one runs",
                file=out,
            )
        return 1
    cause = view.cause
    await operator.set_estop(False, why)
    print(
        "emergency stop released" + (f" (it was engaged by {_who(cause)})" if cause else ""),
        file=out,
    )
    if not view.presses:
        return 0
    them = _them(view.presses)
    if operator.coordinator_online.is_set():
        print(f"{_presses(operator)} held it too: releasing the latch clears {them}", file=out)
        return 0
    print(
        f"{_presses(operator)} still {_holds(view.presses)} the fleet: no coordinator is online "
        f"to clear {them}, and once one runs it latches {them} again: release then",
        file=out,
    )
    return 1


async def _first_view(
    operator: Operator, changed: asyncio.Event, what: str, args: argparse.Namespace, hint: str = ""
) -> None:
    """Wait for a view's first message (`changed`); none within the timeout: an error naming it."""
    try:
        await asyncio.wait_for(changed.wait(), args.timeout)
    except TimeoutError:
        raise GridfleetError(
            f"no {what} on {operator.broker} under root {args.root!r} within "
            f"{args.timeout:.0f} s: is the coordinator running{hint}?"
        ) from None


async def act(args: argparse.Namespace, out: TextIO) -> int:
    """Do what the action says and print the outcome; 1 when the coordinator refused it."""
    client_id = f"cli-{uuid.uuid4().hex[:6]}"
    url = broker_url(args, "operator")
    async with operator_session(url, Topics(args.root), client_id) as operator:
        if args.action == "stop":
            return await engage(operator, args.reason, out)
        if args.action == "release":
            return await release(operator, args.reason, args.timeout, out)
        if args.action == "list":
            await _first_view(operator, operator.jobs_changed, "job queue", args)
            assert operator.jobs is not None
            print_jobs(operator.jobs, out)
            return 0
        if args.action == "history":
            return await print_history(operator, args, out)
        if args.action == "zones":
            await _first_view(
                operator, operator.zones_changed, "zones view", args, " (1.6 or later)"
            )
            assert operator.zones is not None
            print_zones(operator.zones, out)
            return 0
        if args.action == "places":
            await _first_view(operator, operator.map_changed, "map", args)
            assert operator.map is not None
            print_places(operator.map, args.kind, out)
            return 0
        try:
            await asyncio.wait_for(operator.coordinator_online.wait(), args.timeout)
        except TimeoutError:
            raise GridfleetError(
                f"the coordinator is not online on {operator.broker} under root {args.root!r}"
            ) from None
        reply: Reply
        if args.action == "submit":
            reply = await operator.submit_job(
                args.pickup, args.dropoff, args.mass, args.job_id, args.priority, args.timeout
            )
        elif args.action == "cancel":
            reply = await operator.cancel_job(args.job_id, args.timeout)
        elif args.action in ("close-zone", "open-zone"):
            if args.action == "close-zone":
                reply = await operator.close_zone(
                    args.name, args.first, args.last, args.reason, args.timeout
                )
            else:
                reply = await operator.open_zone(args.name, args.timeout)
            if reply.accepted:  # its reason says what was closed or opened
                print(f"accepted: {reply.reason or args.name}", file=out)
                return 0
        elif args.action == "clear-obstacles":
            squares = None if args.all else args.squares
            reply = await operator.clear_obstacles(squares, args.timeout)
        elif args.action == "remove":
            reply = await operator.remove_unit(args.unit, args.reason, args.timeout)
            if reply.accepted:  # its reason says what became of the unit's job
                print(f"accepted: {reply.reason or f'unit {args.unit} removed'}", file=out)
                return 0
        elif args.action in UNIT_ACTIONS:
            command = UNIT_ACTIONS[args.action]
            reply = await operator.control_unit(args.unit, command, args.timeout)
        else:
            reply = await operator.set_goal(
                args.unit, None if args.clear else args.target, args.timeout
            )
    if not reply.accepted:
        print(f"refused: {reply.reason}", file=out)
        return 1
    print(f"accepted{f': job {reply.job_id}' if reply.job_id else ''}", file=out)
    return 0


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet job`."""
    if not 0 < args.timeout < math.inf:
        raise ConfigError(f"--timeout {args.timeout:g}: give a positive number of seconds")
    if args.action == "goal" and args.target is None and not args.clear:
        raise ConfigError(
            f"goal {args.unit}: give the square to send it to, X,Y, or --clear to clear its goal"
        )
    if args.action == "clear-obstacles" and not args.squares and not args.all:
        raise ConfigError(
            "clear-obstacles: name the squares, X,Y ..., or give --all to clear every one"
        )
    return asyncio.run(act(args, sys.stdout))
