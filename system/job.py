"""`gridfleet job`: an operator's command line: submit, cancel and list jobs, goals, the stop."""

from __future__ import annotations

import argparse
import asyncio
import sys
import uuid
from typing import TextIO

from gridfleet.config import redacted
from gridfleet.errors import ConfigError, GridfleetError
from gridfleet.grid import Cell
from gridfleet.options import add_common, broker_url
from gridfleet.protocol import JobsView, Reply
from gridfleet.protocol.topics import Topics
from system.operator import operator_session

WAIT_S = 10.0


def square(text: str) -> Cell:
    """`x,y` → Cell; argparse turns the ValueError into a one-line usage error."""
    try:
        x, y = (int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a square 'x,y'") from None
    if x < 0 or y < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: squares start at 0,0 (top left)")
    return Cell(x, y)


def kilograms(text: str) -> float:
    """A mass in kg, more than 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of kg") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r}: a mass must be more than 0 kg")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Subcommands of `gridfleet job`."""
    add_common(parser)
    parser.add_argument(
        "--timeout", type=float, default=WAIT_S, help="seconds to wait for the coordinator"
    )
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    submit = sub.add_parser("submit", help="queue a pick-and-deliver job")
    submit.add_argument(
        "--pickup", type=square, required=True, metavar="X,Y", help="square to fetch from"
    )
    submit.add_argument(
        "--dropoff", type=square, required=True, metavar="X,Y", help="square to deliver to"
    )
    submit.add_argument(
        "--mass", type=kilograms, required=True, metavar="KG", help="the item's mass in kg"
    )
    submit.add_argument("--priority", type=int, default=0, help="0-100, higher goes first")
    submit.add_argument("--id", dest="job_id", help="job id (default: the coordinator picks one)")
    cancel = sub.add_parser("cancel", help="delete a queued job or abort an active one")
    cancel.add_argument("job_id")
    goal = sub.add_parser("goal", help="send one unit to a square (or --clear its goal)")
    goal.add_argument("unit")
    where = goal.add_mutually_exclusive_group(required=True)
    where.add_argument("target", nargs="?", type=square, metavar="X,Y")
    where.add_argument("--clear", action="store_true", help="clear the unit's goal")
    sub.add_parser("list", help="print the job queue")
    stop = sub.add_parser("stop", help="engage the fleet-wide emergency stop (latched)")
    stop.add_argument("--reason", default="operator", help="one line, shown to everybody")
    release = sub.add_parser("release", help="release the emergency stop")
    release.add_argument("--reason", default="operator", help="one line, shown to everybody")


def print_jobs(view: JobsView, out: TextIO) -> None:
    """The queue as a table, active jobs first."""
    print(f"{'job':<24} {'state':<11} {'unit':<10} {'mass':>6}  pickup -> dropoff", file=out)
    for job in sorted(view.jobs, key=lambda j: (j.state in ("done", "cancelled"), j.id)):
        route = f"{list(job.pickup)} -> {list(job.dropoff)}"
        line = f"{job.id:<24} {job.state:<11} {job.unit or '-':<10} {job.mass_kg:>6.2f}  {route}"
        print(line + (f"  ({job.reason})" if job.reason else ""), file=out)


async def act(args: argparse.Namespace, out: TextIO) -> int:
    """Do what the action says and print the outcome; 1 when the coordinator refused it."""
    client_id = f"cli-{uuid.uuid4().hex[:6]}"
    url = broker_url(args, "operator")
    async with operator_session(url, Topics(args.root), client_id) as operator:
        if args.action in ("stop", "release"):
            signal = await operator.set_estop(args.action == "stop", args.reason)
            print(f"emergency stop {'ENGAGED' if signal.engaged else 'released'}", file=out)
            return 0
        if args.action == "list":
            try:
                await asyncio.wait_for(operator.jobs_changed.wait(), args.timeout)
            except TimeoutError:
                raise GridfleetError(
                    f"no job queue on {redacted(args.broker)} under root {args.root!r} within "
                    f"{args.timeout:.0f} s: is the coordinator running?"
                ) from None
            assert operator.jobs is not None
            print_jobs(operator.jobs, out)
            return 0
        try:
            await asyncio.wait_for(operator.coordinator_online.wait(), args.timeout)
        except TimeoutError:
            raise GridfleetError(
                f"the coordinator is not online on {redacted(args.broker)} under root {args.root!r}"
            ) from None
        reply: Reply
        if args.action == "submit":
            reply = await operator.submit_job(
                args.pickup, args.dropoff, args.mass, args.job_id, args.priority, args.timeout
            )
        elif args.action == "cancel":
            reply = await operator.cancel_job(args.job_id, args.timeout)
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
    if args.timeout <= 0:
        raise ConfigError(f"--timeout {args.timeout}: give a positive number of seconds")
    return asyncio.run(act(args, sys.stdout))
