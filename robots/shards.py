"""A scenario's units sharded over worker processes sharing one world (`gridfleet robots --workers`).

Each worker runs a `Fleet` of its share of the units, one MQTT client each, as `gridfleet robots
--units` would on another machine; the world they step in is one `SharedWorld`, so sensors see
every unit, moves are checked against every unit and the counts are the fleet's. The parent owns
the shared world, writes the ground truth (`--truth`) and stops every worker when it stops, or
when one of them dies (its supervisor then restarts the whole fleet, resuming with `--state`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing
import os
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.process import BaseProcess
from pathlib import Path

from gridfleet.errors import ConfigError, GridfleetError
from gridfleet.heap import freeze_after_start
from gridfleet.lifeline import PARENT_ENV, die_with_parent
from gridfleet.robots.shared_world import SharedHandle, SharedWorld
from gridfleet.robots.truth import write_truth
from gridfleet.scenario import load_scenario, with_units
from gridfleet.tasks import stop_on_signals

log = logging.getLogger("robots")
STOP_S = 15.0  # a worker still running this long after SIGTERM is killed


def shares(unit_ids: Sequence[str], workers: int) -> list[list[str]]:
    """`unit_ids` dealt over `workers` processes, as evenly as can be (none left empty)."""
    if workers < 1:
        raise ConfigError(f"--workers {workers}: give at least 1")
    count = min(workers, len(unit_ids))
    return [list(unit_ids[i::count]) for i in range(count)]


def workers_for(units: int, cpus: int | None = None) -> int:
    """How many unit processes `gridfleet up` runs: one per 50 units, at most one per core."""
    cores = cpus if cpus is not None else (os.cpu_count() or 1)
    return max(1, min(cores, -(-units // 50)))


@dataclass(frozen=True)
class WorkerSpec:
    """What one worker process runs (pickled into it at start)."""

    scenario: Path
    broker: str
    root: str
    units: tuple[str, ...]
    step_s: float
    mode: str
    accounts: Path | None
    state: Path | None
    world: SharedHandle


def _worker(spec: WorkerSpec) -> None:
    """A worker process: its share of the units until SIGTERM or SIGINT."""
    die_with_parent()
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    from gridfleet.accounts import load_accounts
    from gridfleet.robots.fleet import Fleet

    scenario = load_scenario(spec.scenario)
    world = SharedWorld.attach(scenario, spec.world)
    try:
        fleet = Fleet(
            scenario,
            spec.broker,
            root=spec.root,
            units=spec.units,
            step=spec.step_s,
            mode=spec.mode,  # type: ignore[arg-type]
            accounts=None if spec.accounts is None else load_accounts(spec.accounts),
            state_path=spec.state,
            world=world,
        )

        async def main() -> None:
            stop = stop_on_signals()
            freeze_after_start()
            log.info(
                "worker %d running %d units on %s",
                os.getpid(),
                len(spec.units),
                next(iter(fleet.shells.values())).endpoint.brokers,
            )
            await fleet.run(stop)

        asyncio.run(main())
    finally:
        world.close()


def run_sharded(
    scenario_path: Path,
    broker: str,
    *,
    root: str,
    workers: int,
    step_s: float,
    mode: str = "coordinated",
    accounts: Path | None = None,
    state: Path | None = None,
    truth: Path | None = None,
) -> int:
    """Run every unit of the scenario over `workers` processes; 0 after a clean stop."""
    scenario = load_scenario(scenario_path)
    ids = [u.id for u in with_units(scenario).units]
    groups = shares(ids, workers)  # a bad count is refused before anything is made
    context = multiprocessing.get_context("spawn")
    world = SharedWorld.create(scenario, context.Lock())
    specs = [
        WorkerSpec(
            scenario_path, broker, root, tuple(share), step_s, mode, accounts, state, world.handle
        )
        for share in groups
    ]
    procs = [
        context.Process(target=_worker, args=(s,), name=f"units-{i}") for i, s in enumerate(specs)
    ]
    try:
        os.environ[PARENT_ENV] = str(os.getpid())  # each worker ends with this process
        try:
            for proc in procs:
                proc.start()
        finally:
            os.environ.pop(PARENT_ENV, None)
        log.info(
            "%d units over %d worker processes (pids %s)",
            len(ids),
            len(procs),
            ", ".join(str(p.pid) for p in procs),
        )
        failed = asyncio.run(_watch(procs, world, truth, step_s))
    finally:
        _stop(procs)
        log.info("stopped: %d moves, %d prevented", sum(world.moves.values()), world.prevented)
        world.close(unlink=True)
    if failed:
        raise GridfleetError(f"unit worker {failed} died; every worker was stopped")
    return 0


async def _watch(
    procs: Sequence[BaseProcess], world: SharedWorld, truth: Path | None, step_s: float
) -> str | None:
    """Until a stop signal (None) or a worker's death (its name); writes the truth meanwhile."""
    stop = stop_on_signals()
    writer = None
    if truth is not None:
        writer = asyncio.create_task(write_truth(world, truth, step_s, stop))
    dead = None
    while not stop.is_set():
        dead = next((p.name for p in procs if not p.is_alive()), None)
        if dead is not None:
            stop.set()
            break
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 0.2)  # polling the workers' liveness
    if writer is not None:
        await writer
    return dead


def _stop(procs: Sequence[BaseProcess]) -> None:
    """SIGTERM every worker (each unit says offline), then kill what is left after STOP_S."""
    for proc in procs:
        if proc.is_alive():
            proc.terminate()
    for proc in procs:
        proc.join(STOP_S)
        if proc.is_alive():
            log.error("unit worker %s did not stop within %.0f s: killed", proc.name, STOP_S)
            proc.kill()
            proc.join()
