"""The system bench: the real coordinator and simulated units over a real broker, measured.

Deployed as in a hall (the default): the broker, the coordinator and the units in processes of
their own, the units sharded over several processes sharing one simulated world; the bench's own
listener and operator in this one. `deploy="threads"` runs the coordinator and units in threads of
this process instead (the broker still in its own), as `gridfleet simulate` does.

Work: a stream of random feasible jobs, topped up so that as many are active (not final) as
there are units; every unit stays busy and allocation, planning and the job store all work.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import random
import statistics
import tempfile
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from gridfleet.bench.figures import percentile
from gridfleet.bench.system.broker import check_broker
from gridfleet.bench.system.monitor import BenchMonitor
from gridfleet.bench.system.procs import ProcessWatch
from gridfleet.bench.system.result import SystemResult
from gridfleet.bench.system.scenario import make_scenario
from gridfleet.bus import connect_first
from gridfleet.config import check_step
from gridfleet.console.feed import random_job
from gridfleet.console.operator import Operator, operator_session
from gridfleet.coordinator.window import DEFAULT_WINDOW
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.heap import freeze_after_start
from gridfleet.paths import DistanceFieldCache
from gridfleet.protocol import Reply, Topics
from gridfleet.robots.shards import workers_for
from gridfleet.scenario import Scenario
from gridfleet.system.assembly import Assembly, SystemSpec
from gridfleet.system.supervisor import Supervisor
from gridfleet.system.threads import ServiceThread, world_of
from gridfleet.tasks import cancel_and_wait

if TYPE_CHECKING:
    from gridfleet.robots.fleet import Fleet

Deploy = Literal["processes", "threads"]
TRUTH_TAIL = 1 << 20  # bytes read from the truth file's end: its last lines, whatever the fleet

STOP_WAIT_S = 20.0  # an engagement not shown by every unit within this is reported as None


async def _keep_jobs(
    operator: Operator, scenario: Scenario, seed: int, submitted: list[int]
) -> None:
    """Keep as many jobs active as there are units: submit the deficit whenever the view changes."""
    rng = random.Random(seed)
    fields = DistanceFieldCache(scenario.grid)
    target = len(scenario.units)
    limit = asyncio.Semaphore(8)  # requests in flight: aiomqtt warns above 10 pending publishes

    async def submit(job: tuple[Cell, Cell, float]) -> Reply:
        async with limit:
            reply = await operator.submit_job(*job)
        # Counted as it is answered, not when the whole batch is: at 200 units and more the
        # batch outlasted the run, which then reported no job submitted.
        submitted[0] += reply.accepted
        return reply

    while True:
        deficit = target - operator.active_jobs() if operator.jobs is not None else target
        if deficit > 0:
            jobs = [random_job(scenario, rng, fields) for _ in range(deficit)]
            # A reply that timed out (an overloaded broker) is a job less, not the end of the run.
            await asyncio.gather(*(submit(job) for job in jobs), return_exceptions=True)
        operator.jobs_changed.clear()
        await operator.jobs_changed.wait()


Counts = Callable[[], "WorldCounts"]


@dataclass(frozen=True)
class WorldCounts:
    """The world simulation's ground truth at one moment."""

    moves: int
    collisions: int
    prevented: int
    at: float  # wall time (time.time()) the counts are of


def _thread_counts(fleet: ServiceThread[Fleet]) -> Counts:
    """Read from the units' thread (the bench in one process)."""
    world = world_of(fleet)
    return lambda: fleet.call(
        lambda: WorldCounts(
            sum(world.moves.values()), world.collisions, world.prevented, time.time()
        )
    )


def _truth_counts(path: Path) -> Counts:
    """Read from the last line the units' processes wrote to their truth file."""

    def read() -> WorldCounts:
        with path.open("rb") as f:
            f.seek(max(0, path.stat().st_size - TRUTH_TAIL))
            lines = f.read().splitlines()
        for line in reversed(lines):
            with contextlib.suppress(ValueError):
                d = json.loads(line)
                return WorldCounts(d["moves"], d["collisions"], d["prevented"], d["t"])
        raise RuntimeError(f"{path}: no ground truth written yet")

    return read


async def _counts_since(counts: Counts, since: float, step_s: float) -> WorldCounts:
    """The first counts of `since` or later (waiting for the truth to catch up, STOP_WAIT_S at
    most: then the latest)."""
    deadline = time.monotonic() + STOP_WAIT_S
    while (now := counts()).at < since and time.monotonic() < deadline:
        await asyncio.sleep(step_s / 2)  # polling the truth file, with a deadline
    return now


async def _stop_trials(
    operator: Operator, monitor: BenchMonitor, counts: Counts, trials: int, step_s: float
) -> tuple[list[float | None], list[float | None], int]:
    """Engage and release the fleet stop `trials` times; latencies and moves made while stopped."""
    seen_ms: list[float | None] = []
    applied_ms: list[float | None] = []
    moved = 0
    for _ in range(trials):
        monitor.expect(True)
        wall, t0 = datetime.now(UTC), time.monotonic()
        await operator.set_estop(True, "system bench")
        try:
            await asyncio.wait_for(monitor.all_shown.wait(), STOP_WAIT_S)
        except TimeoutError:
            # An overloaded broker: further trials would only take as long; none of them count.
            seen_ms += [None] * (trials - len(seen_ms))
            applied_ms += [None] * (trials - len(applied_ms))
            await operator.set_estop(False, "system bench")
            break
        shown = list(monitor.shown.values())
        seen_ms.append(round((max(s.seen for s in shown) - t0) * 1000, 2))
        last = max(s.stamped for s in shown)
        applied_ms.append(round((last - wall).total_seconds() * 1000, 2))
        # Counts of after every unit showed the stop: a truth file is written once a step by a
        # process the machine may keep waiting (a CI run counted moves made before the stop,
        # read from a line written late).
        before = await _counts_since(counts, time.time(), step_s)
        await asyncio.sleep(3 * step_s)  # pacing: give a stopped unit three steps to misbehave
        after = await _counts_since(counts, time.time(), step_s)
        moved += after.moves - before.moves
        monitor.expect(False)
        await operator.set_estop(False, "system bench")
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(monitor.all_shown.wait(), STOP_WAIT_S)
        await asyncio.sleep(max(0.3, 5 * step_s))  # pacing: let the fleet get moving again
    return seen_ms, applied_ms, moved


async def run_system(
    units: int,
    step_s: float,
    duration_s: float,
    seed: int = 0,
    broker_url: str | None = None,
    estops: int = 3,
    warmup_s: float | None = None,
    deploy: Deploy = "processes",
    workers: int | None = None,
    window: int = DEFAULT_WINDOW,
) -> SystemResult:
    """Run the whole system with `units` simulated units and measure it (see the module doc)."""
    if units < 1:
        raise ConfigError(f"{units} units: give at least 1")
    check_step(step_s)
    if duration_s <= 0:
        raise ConfigError(f"duration {duration_s} s: give a positive number of seconds")
    if estops < 1:
        raise ConfigError(f"{estops} emergency-stop trials: give at least 1")
    if workers is not None and workers < 1:
        raise ConfigError(f"{workers} unit workers: give at least 1")
    if deploy == "threads" and workers not in (None, 1):
        raise ConfigError("unit workers are processes: not with the bench in threads")
    warmup = warmup_s if warmup_s is not None else max(1.0, 10 * step_s)
    root = f"bench-{uuid.uuid4().hex[:8]}"
    with tempfile.TemporaryDirectory(prefix="gridfleet-bench-") as tmp:
        scenario = make_scenario(units, seed, Path(tmp))
        if broker_url is not None:
            await check_broker(broker_url)
        spec = SystemSpec(
            scenario,
            broker=broker_url,
            root=root,
            step_s=step_s,
            window=window,
            db_path=Path(tmp) / "jobs.db",
            ws_port=None,
        )
        truth = Path(tmp) / "truth.jsonl"
        if deploy == "processes":
            shards = workers if workers is not None else workers_for(units)
            spec = replace(spec, unit_workers=shards, truth=truth)
        else:
            shards = 1
            spec = replace(
                spec, seed=seed, coordinator_id=f"{root}-coordinator", own_broker="processes"
            )
        with open(os.devnull, "w") as quiet:  # the components' logs: the figures say it all
            supervisor = Supervisor(out=quiet, stop_timeout=20.0)
            async with Assembly(spec, deploy, supervisor) as system:
                if deploy == "processes":
                    counts = _truth_counts(truth)
                    roots = {"bench": os.getpid()}
                else:
                    counts = _thread_counts(system.fleet)
                    roots = {"bench+coordinator+units": os.getpid()}
                running = system.supervisor.children if system.supervisor else []

                def components(own: dict[str, int] = roots) -> dict[str, int]:
                    return own | {c.spec.name: c.process.pid for c in running if c.process}

                figures = await _measure(
                    system.url,
                    root,
                    scenario,
                    counts,
                    ProcessWatch(components),
                    seed,
                    warmup,
                    duration_s,
                    estops,
                    step_s,
                )
        if broker_url is not None:  # once every service has stopped and said goodbye
            await _clear_retained(broker_url, figures.retained)
    return SystemResult(
        units=units,
        step_s=step_s,
        broker=broker_url or "embedded amqtt",
        deploy=deploy,
        window=window,
        unit_workers=shards,
        map_size=(scenario.grid.width, scenario.grid.height),
        free_squares=len(scenario.grid.free_cells()),
        **figures.result,
    )


@dataclass
class _Figures:
    result: dict[str, Any]
    retained: set[str]


async def _measure(
    url: str,
    root: str,
    scenario: Scenario,
    counts: Counts,
    watch: ProcessWatch,
    seed: int,
    warmup: float,
    duration_s: float,
    estops: int,
    step_s: float,
) -> _Figures:
    """The measured window and the stop trials, on a running system."""
    units = len(scenario.units)
    topics = Topics(root)
    freeze_after_start()  # the listener is an instrument: no pauses of its own
    async with contextlib.AsyncExitStack() as stack:
        monitor_client = await stack.enter_async_context(connect_first(url, f"{root}-monitor"))
        monitor = BenchMonitor(monitor_client, topics, units)
        await monitor.start()
        listener = asyncio.create_task(monitor.listen())
        stack.push_async_callback(cancel_and_wait, listener)
        operator = await stack.enter_async_context(
            operator_session(url, topics, f"{root}-operator")
        )
        await operator.wait_for_units([u.id for u in scenario.units], timeout=60)
        submitted = [0]
        feeder = asyncio.create_task(_keep_jobs(operator, scenario, seed, submitted))
        stack.push_async_callback(cancel_and_wait, feeder)
        await asyncio.sleep(warmup)  # pacing: the warm-up, not synchronisation
        moves0 = counts().moves
        kinds0, step0, sub0 = dict(monitor.by_kind), monitor.step, submitted[0]
        done0 = operator.jobs.counts.get("done", 0) if operator.jobs else 0
        t0 = time.monotonic()
        watch.start()
        monitor.measuring = True
        await asyncio.sleep(duration_s)  # pacing: the measured window
        monitor.measuring = False
        processes = watch.finish()
        elapsed = time.monotonic() - t0
        moves = counts().moves - moves0
        kinds = {k: v - kinds0.get(k, 0) for k, v in monitor.by_kind.items()}
        steps = monitor.step - step0
        done = (operator.jobs.counts.get("done", 0) if operator.jobs else 0) - done0
        jobs_submitted = submitted[0] - sub0
        await cancel_and_wait(feeder)
        seen, applied, moved = await _stop_trials(operator, monitor, counts, estops, step_s)
        end = counts()
    total = sum(kinds.values())
    latencies = [v * 1000 for v in monitor.latencies]
    done_ms = [v for v in seen if v is not None]
    result = {
        "duration_s": round(elapsed, 3),
        "messages": total,
        "messages_per_s": round(total / elapsed, 1),
        "per_kind_per_s": {k: round(v / elapsed, 1) for k, v in sorted(kinds.items()) if v},
        "steps": steps,
        "step_rate": round(steps / elapsed, 2),
        "nominal_step_rate": round(1 / step_s, 2),
        "moves_per_unit_s": round(moves / units / elapsed, 3),
        "jobs_done": done,
        "jobs_submitted": jobs_submitted,
        "state_latency_ms_p50": _round(statistics.median(latencies) if latencies else None),
        "state_latency_ms_p99": _round(percentile(latencies, 0.99)),
        "estop_ms": tuple(seen),
        "estop_ms_p99": _round(percentile(done_ms, 0.99) if len(done_ms) == len(seen) else None),
        "estop_applied_ms": tuple(applied),
        "moved_while_stopped": moved,
        "collisions": end.collisions,
        "prevented": end.prevented,
        "processes": tuple(processes),
    }
    return _Figures(result, set(monitor.retained_topics))


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 2)


async def _clear_retained(url: str, topics: set[str]) -> None:
    """Leave an external broker as it was: an empty retained message deletes each one."""
    async with connect_first(url, f"bench-clean-{uuid.uuid4().hex[:6]}") as client:
        for topic in sorted(topics):
            await client.publish(topic, b"", qos=1, retain=True)
