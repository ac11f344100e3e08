"""An operator client that submits a scenario's jobs and goals, and (demo) keeps jobs coming."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import random
import time
import uuid
from collections.abc import AsyncIterator, Sequence
from pathlib import Path

import aiomqtt
from pydantic import ValidationError

from gridfleet.bus import make_client
from gridfleet.errors import GridfleetError, ProtocolError
from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE, DistanceFieldCache
from gridfleet.protocol import (
    TOPICS,
    CancelJob,
    CoordinatorStatus,
    EstopSignal,
    HeaderStamper,
    JobsView,
    Reply,
    Routes,
    SetGoal,
    SubmitJob,
    Topics,
    decode,
    encode,
    encode_estop,
)
from gridfleet.protocol.codec import describe
from gridfleet.protocol.messages import FINAL_JOB_STATES, Request
from gridfleet.scenario import JobSpec, Scenario, load_scenario
from gridfleet.tasks import cancel_and_wait, stop_on_signals, until_stopped

log = logging.getLogger("gridfleet.feeder")


class Operator:
    """Sends requests to the coordinator and awaits their replies; tracks the job queue view."""

    def __init__(self, client: aiomqtt.Client, topics: Topics, client_id: str) -> None:
        self.client = client
        self.topics = topics
        self.client_id = client_id
        self.stamp = HeaderStamper(client_id)
        self.jobs: JobsView | None = None
        self.jobs_changed = asyncio.Event()
        self.coordinator_online = asyncio.Event()
        self.planned_units: set[str] = set()  # units in the coordinator's latest routes view
        self.routes_changed = asyncio.Event()
        self._pending: dict[str, asyncio.Future[Reply]] = {}
        self._count = 0

    async def start(self) -> None:
        """Subscribe to replies and the queue view."""
        await self.client.subscribe(self.topics.reply(self.client_id), qos=1)
        await self.client.subscribe(self.topics.fleet("jobs"), qos=1)
        await self.client.subscribe(self.topics.fleet("coordinator"), qos=1)
        await self.client.subscribe(self.topics.fleet("routes"), qos=0)

    async def listen(self) -> None:
        """Route inbound messages until the client disconnects."""
        async for message in self.client.messages:
            payload = (
                bytes(message.payload) if isinstance(message.payload, bytes | bytearray) else b""
            )
            try:
                kind, _ = self.topics.parse(str(message.topic))
                if kind == "reply":
                    reply = decode(Reply, payload)
                    future = self._pending.pop(reply.request_id, None)
                    if future is not None and not future.done():
                        future.set_result(reply)
                elif kind == "jobs":
                    self.jobs = decode(JobsView, payload, TOPICS["jobs"].max_bytes)
                    self.jobs_changed.set()
                elif kind == "routes":
                    routes = decode(Routes, payload, TOPICS["routes"].max_bytes)
                    self.planned_units = set(routes.routes)
                    self.routes_changed.set()
                elif kind == "coordinator":
                    status = decode(CoordinatorStatus, payload)
                    if status.state == "online":
                        self.coordinator_online.set()
                    else:
                        self.coordinator_online.clear()
            except ProtocolError as exc:
                log.warning("ignored a bad message on %s: %s", message.topic, exc)

    def _next_id(self) -> str:
        self._count += 1
        return f"{self.client_id}-{self._count}"

    async def _request(
        self, kind: str, model: type[Request], timeout: float, **fields: object
    ) -> Reply:
        """Build a request (a bad value is a ProtocolError naming its field), send, await reply."""
        try:
            request = model(
                header=self.stamp(kind),
                request_id=self._next_id(),
                reply_to=self.client_id,
                **fields,
            )
        except ValidationError as exc:
            raise ProtocolError(f"{kind}: {describe(exc)}") from None
        return await self._send(kind, request, timeout)

    async def _send(self, kind: str, request: Request, timeout: float) -> Reply:
        future: asyncio.Future[Reply] = asyncio.get_running_loop().create_future()
        self._pending[request.request_id] = future
        await self.client.publish(self.topics.request(kind), encode(request), qos=1)
        try:
            return await asyncio.wait_for(future, timeout)
        except TimeoutError:
            self._pending.pop(request.request_id, None)
            raise GridfleetError(
                f"no reply from the coordinator to {kind} within {timeout:.0f} s"
            ) from None

    async def submit_job(
        self,
        pickup: Cell,
        dropoff: Cell,
        mass_kg: float,
        job_id: str | None = None,
        priority: int = 0,
        timeout: float = 10.0,
    ) -> Reply:
        """Queue a job; returns the coordinator's reply."""
        return await self._request(
            "submit_job",
            SubmitJob,
            timeout,
            pickup=pickup,
            dropoff=dropoff,
            mass_kg=mass_kg,
            priority=priority,
            job_id=job_id,
        )

    async def set_goal(self, unit: str, target: Cell | None, timeout: float = 10.0) -> Reply:
        """Send one unit to `target` (None clears its goal)."""
        return await self._request("set_goal", SetGoal, timeout, unit=unit, target=target)

    async def cancel_job(self, job_id: str, timeout: float = 10.0) -> Reply:
        """Delete a queued job or abort an active one."""
        return await self._request("cancel_job", CancelJob, timeout, job_id=job_id)

    async def set_estop(self, engaged: bool, reason: str) -> EstopSignal:
        """Engage or release the fleet-wide emergency stop (retained: it latches); returns it."""
        signal = EstopSignal(engaged, self.client_id, reason)
        spec = TOPICS["estop"]
        await self.client.publish(
            self.topics.fleet("estop"), encode_estop(signal), qos=spec.qos, retain=spec.retained
        )
        return signal

    async def wait_for_units(self, units: Sequence[str], timeout: float = 30.0) -> None:
        """Wait until the coordinator plans for every unit in `units` (it knows their state)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while missing := sorted(set(units) - self.planned_units):
            self.routes_changed.clear()
            try:
                await asyncio.wait_for(self.routes_changed.wait(), deadline - loop.time())
            except TimeoutError:
                raise GridfleetError(
                    f"the coordinator has not heard from {', '.join(missing)} within {timeout:.0f} s"
                ) from None

    def active_jobs(self) -> int:
        """Jobs in the queue view that are not final."""
        if self.jobs is None:
            return 0
        return sum(1 for j in self.jobs.jobs if j.state not in FINAL_JOB_STATES)


@contextlib.asynccontextmanager
async def operator_session(url: str, topics: Topics, client_id: str) -> AsyncIterator[Operator]:
    """A connected Operator, subscribed and listening in the background until the block ends."""
    async with make_client(url, client_id) as client:
        operator = Operator(client, topics, client_id)
        await operator.start()
        listener = asyncio.create_task(operator.listen())
        try:
            yield operator
        finally:
            await cancel_and_wait(listener)


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
    scenario: Scenario, rng: random.Random, fields: DistanceFieldCache
) -> tuple[Cell, Cell, float]:
    """A job some unit can carry between two distinct squares reachable from the units."""
    free = scenario.grid.free_cells()
    heaviest = max(u.capacity for u in scenario.units)
    home = scenario.units[0].start
    while True:
        pickup, dropoff = rng.sample(free, 2)
        if UNREACHABLE not in (fields.distance(home, pickup), fields.distance(home, dropoff)):
            return pickup, dropoff, round(rng.uniform(0.5, heaviest), 1)


async def feed(
    url: str,
    root: str,
    scenario: Scenario,
    demo: bool,
    step: float,
    keep_active: int,
    seed: int | None = None,
) -> None:
    """Submit the scenario's work; in demo mode keep `keep_active` jobs in the queue forever."""
    client_id = f"feeder-{uuid.uuid4().hex[:6]}"
    topics = Topics(root)
    async with operator_session(url, topics, client_id) as operator:
        await operator.coordinator_online.wait()
        # The coordinator keeps jobs across runs (SQLite): a tag per run keeps this run's
        # jobs from clashing with the ids of the last one.
        await submit_scenario(operator, scenario, run_tag=time.strftime("%H%M%S"))
        if not demo:
            return
        rng = random.Random(seed)
        fields = DistanceFieldCache(scenario.grid)
        while True:
            await operator.jobs_changed.wait()
            operator.jobs_changed.clear()
            while operator.active_jobs() < keep_active:
                pickup, dropoff, mass = random_job(scenario, rng, fields)
                await operator.submit_job(pickup, dropoff, mass)
                await asyncio.sleep(step)  # pacing for the demo, not synchronisation


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m gridfleet.feeder`: run by `gridfleet up` as its operator component."""
    parser = argparse.ArgumentParser(prog="gridfleet-feeder")
    parser.add_argument("--broker", required=True)
    parser.add_argument("--root", default="gridfleet")
    parser.add_argument("--scenario", required=True, type=Path)
    parser.add_argument("--demo", action="store_true")
    parser.add_argument("--step", type=float, default=0.5)
    parser.add_argument("--keep-active", type=int, default=6)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
    try:
        scenario = load_scenario(args.scenario)
        asyncio.run(_main(args, scenario))
    except GridfleetError as exc:
        print(f"feeder: error: {exc}")
        return 2
    return 0


async def _main(args: argparse.Namespace, scenario: Scenario) -> None:
    # Stopped by `gridfleet up` with SIGTERM, perhaps mid-submission: that is a clean exit.
    work = feed(args.broker, args.root, scenario, args.demo, args.step, args.keep_active)
    await until_stopped(work, stop_on_signals())


if __name__ == "__main__":
    raise SystemExit(main())
