"""Feeding the fleet work: a scenario's jobs and goals, and (demo) a stream of random feasible jobs.

`gridfleet feed` is the operator component that `gridfleet up` runs beside the others.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import random
import signal
import time
import uuid
from collections.abc import Collection, Coroutine
from pathlib import Path
from typing import Any

import aiomqtt

from gridfleet.config import broker_urls, check_step
from gridfleet.console.operator import Operator, operator_session
from gridfleet.errors import ConfigError
from gridfleet.options import add_common, broker_url
from gridfleet.paths import UNREACHABLE, DistanceFieldCache
from gridfleet.protocol import Reply, Topics
from gridfleet.scenario import JobSpec, Scenario, load_scenario
from gridfleet.squares import Cell
from gridfleet.tasks import cancel_and_wait, stop_on_signals, until_stopped

DEMO_KEEP_MIN = 6  # jobs the demo keeps queued at least (by default one per unit)
# After its session ends, the feed tries the next broker of its list at once, then waits this
# long before each round of the list, doubling up to the most.
RETRY_FIRST_S = 0.1
RETRY_MOST_S = 5.0

log = logging.getLogger("gridfleet.feed")


def scenario_job_id(scenario: Scenario, n: int, job: JobSpec, run_tag: str | None = None) -> str:
    """The id the scenario's `n`-th job (from 1) is submitted under."""
    return job.id or f"{scenario.name}{f'-{run_tag}' if run_tag else ''}-job-{n}"


async def submit_scenario(
    operator: Operator, scenario: Scenario, run_tag: str | None = None
) -> list[Reply]:
    """Submit every job and goal of `scenario`; job ids default to `<scenario>[-<tag>]-job-<n>`."""
    # A goal for a unit the coordinator has not heard from yet would be refused as unknown.
    await operator.wait_for_units([u.id for u in scenario.units])
    replies = []
    for n, job in enumerate(scenario.jobs, start=1):
        job_id = scenario_job_id(scenario, n, job, run_tag)
        reply = await operator.submit_job(job.pickup, job.dropoff, job.mass, job_id, job.priority)
        log.info("job %s: %s", job_id, "queued" if reply.accepted else f"refused: {reply.reason}")
        replies.append(reply)
    for goal in scenario.goals:
        reply = await operator.set_goal(goal.unit, goal.target)
        log.info(
            "goal %s -> %s: %s",
            goal.unit,
            list(goal.target),
            "set" if reply.accepted else f"refused: {reply.reason}",
        )
        replies.append(reply)
    return replies


def random_job(
    scenario: Scenario,
    rng: random.Random,
    fields: DistanceFieldCache,
    avoid: Collection[Cell] = frozenset(),
) -> tuple[Cell, Cell, float]:
    """A job some unit can carry between two distinct squares reachable from the units.

    Its mass is drawn for a unit picked at random, so the work fits the fleet's mix: a fleet of
    small units and one big one gets mostly small jobs (masses up to the biggest capacity left
    half the small units idle in the hour-long warehouse demo while heavy jobs queued).
    """
    free = [c for c in scenario.grid.free_cells() if c not in avoid]  # e.g. obstacles found
    home = scenario.units[0].start
    carrier = rng.choice(scenario.units).capacity
    mass = min(carrier, max(0.1, round(rng.uniform(min(0.5, carrier), carrier), 1)))
    while True:
        pickup, dropoff = rng.sample(free, 2)
        if UNREACHABLE not in (fields.distance(home, pickup), fields.distance(home, dropoff)):
            return pickup, dropoff, mass


async def feed(
    url: str,
    root: str,
    scenario: Scenario,
    demo: bool,
    step: float,
    keep_active: int | None = None,
    seed: int | None = None,
) -> None:
    """Submit the scenario's work; in demo mode keep `keep_active` jobs in the queue forever.

    By default a job per unit, and at least 6: 6 jobs kept 144 of 150 units idle.
    """
    keep, pace = demo_queue(len(scenario.units), step, keep_active)
    client_id = f"feeder-{uuid.uuid4().hex[:6]}"
    topics = Topics(root)
    # The coordinator keeps jobs across runs (SQLite): a tag per run keeps this run's jobs from
    # clashing with the ids of the last one.
    tag = time.strftime("%H%M%S")
    rng = random.Random(seed)
    fields = DistanceFieldCache(scenario.grid)
    brokers = broker_urls(url)
    submitted = False
    tried, delay = 0, RETRY_FIRST_S
    # A session lost (its broker died, a link cut) is begun again on the next broker of the
    # list, as every component's: a demo feed that stayed on a dead session fed nothing more.
    while True:
        try:
            async with operator_session(",".join(brokers), topics, client_id) as operator:
                await _in_session(operator, operator.coordinator_online.wait())
                tried, delay = 0, RETRY_FIRST_S
                if not submitted:
                    await _in_session(operator, submit_scenario(operator, scenario, tag))
                    submitted = True
                if not demo:
                    return
                while True:
                    await _in_session(operator, operator.jobs_changed.wait())
                    operator.jobs_changed.clear()
                    while operator.active_jobs() < keep:
                        # Not onto obstacles the units have found (the coordinator would refuse).
                        pickup, dropoff, mass = random_job(
                            scenario, rng, fields, operator.obstacles
                        )
                        await operator.submit_job(pickup, dropoff, mass)
                        await asyncio.sleep(pace)  # pacing for the demo, not synchronisation
        except aiomqtt.MqttError as exc:
            log.warning("feed: session lost (%s); trying %s", exc, brokers[1 % len(brokers)])
        brokers = brokers[1:] + brokers[:1]
        tried += 1
        if tried >= len(brokers):  # each was tried: wait before the next round
            tried = 0
            await asyncio.sleep(delay)  # back-off between rounds of the list
            delay = min(2 * delay, RETRY_MOST_S)


async def _in_session(operator: Operator, work: Coroutine[Any, Any, object]) -> None:
    """Await `work`, or raise MqttError if the operator's session ends first."""
    task = asyncio.create_task(work)
    ended = asyncio.create_task(operator.ended.wait())
    try:
        await asyncio.wait({task, ended}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        await cancel_and_wait(ended)
        lost = not task.done()
        if lost:
            await cancel_and_wait(task)
    if lost:
        raise aiomqtt.MqttError("the session ended")
    task.result()


def demo_queue(units: int, step: float, keep_active: int | None = None) -> tuple[int, float]:
    """How many jobs the demo keeps queued, and the pause between two of its submissions (s)."""
    keep = keep_active or max(DEMO_KEEP_MIN, units)
    return keep, step / max(1, keep // DEMO_KEEP_MIN)  # a big fleet's queue refilled as fast


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet feed`."""
    add_common(parser)
    parser.add_argument("--scenario", required=True, type=Path, help="scenario file")
    parser.add_argument(
        "--demo", action="store_true", help="keep a stream of random feasible jobs coming"
    )
    parser.add_argument("--step", type=float, default=0.5, help="pace of demo submissions (s)")
    parser.add_argument(
        "--keep-active",
        type=int,
        help=f"jobs the demo keeps in the queue (default one per unit, at least {DEMO_KEEP_MIN})",
    )


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet feed`; stopped by SIGTERM, perhaps mid-submission, cleanly."""
    check_step(args.step)
    if args.keep_active is not None and args.keep_active < 1:
        raise ConfigError(f"--keep-active {args.keep_active}: give at least 1")
    scenario = load_scenario(args.scenario)
    url = broker_url(args, "operator")
    work = feed(url, args.root, scenario, args.demo, args.step, args.keep_active)

    async def main() -> None:
        await until_stopped(work, stop_on_signals())

    asyncio.run(main())
    # Done on its own (no --demo): a stop that comes while the interpreter winds down is no
    # reason to die of it (`gridfleet up` stopping at that moment saw the feed killed, -15).
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    return 0
