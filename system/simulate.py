"""`gridfleet simulate`: run a scenario on the real components, over MQTT, to the end."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import aiomqtt

from gridfleet.bus import connect_first
from gridfleet.config import broker_login, check_step, owned_client_id
from gridfleet.console.clean import clean_root
from gridfleet.console.feed import scenario_job_id, submit_scenario
from gridfleet.console.monitor import FleetMonitor
from gridfleet.console.operator import Operator
from gridfleet.coordinator.energy import POLICIES
from gridfleet.coordinator.window import DEFAULT_WINDOW, MAX_WINDOW, check_window
from gridfleet.errors import ConfigError, GridfleetError
from gridfleet.grid import Cell
from gridfleet.heap import freeze
from gridfleet.options import add_common
from gridfleet.protocol import JobView, Topics
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.protocol.messages import FINAL_JOB_STATES
from gridfleet.scenario import Scenario, load_scenario, with_units
from gridfleet.system.assembly import Assembly, SystemSpec
from gridfleet.system.threads import world_of

if TYPE_CHECKING:
    from collections.abc import Mapping

    from gridfleet.robots.battery import Battery
    from gridfleet.robots.world import WorldSim

log = logging.getLogger("gridfleet.simulate")
STALL_S = 20.0  # a run whose coordinator publishes no step for this long (plus 50 steps) ends


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet simulate`."""
    parser.add_argument(
        "scenario",
        type=Path,
        help="scenario file (TOML), or a shipped scenario by name (playfield)",
    )
    parser.add_argument(
        "--step",
        type=float,
        default=0.02,
        help="step period in seconds (default 0.02: accelerated time)",
    )
    parser.add_argument(
        "--max-steps",
        type=int,
        default=2000,
        help="give up after this many coordinator steps (default 2000)",
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="the coordinator's tie-breaking seed (default 0)"
    )
    parser.add_argument(
        "--window",
        type=int,
        default=DEFAULT_WINDOW,
        metavar="N",
        help=f"the coordinator's window: squares a unit may be released ahead, 1 to {MAX_WINDOW} "
        f"(default {DEFAULT_WINDOW})",
    )
    parser.add_argument(
        "--deterministic",
        action="store_true",
        help="the coordinator's and units' cores in lockstep, without a broker: the same run "
        "every time (steps, every job's done step), for comparing scenarios or planners",
    )
    parser.add_argument(
        "--energy-policy",
        default="gridfleet",
        metavar="|".join(POLICIES),
        help="the coordinator's energy policy (as `gridfleet coordinator --energy-policy`): "
        "gridfleet (default): the scenario's [charging] thresholds with margins; naive: to the "
        "nearest charger only at critical, no check that a job can be finished (a baseline)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object as the result")
    add_common(parser, own_broker="an embedded broker on a free port")


@dataclass
class GoalProgress:
    """A goal of the scenario and when it was first reached."""

    unit: str
    target: Cell
    step: int | None = None
    refused: str | None = None  # the coordinator's reason, when it refused the goal


@dataclass
class SimulationResult:
    """The result of one simulation run."""

    steps: int = 0
    finished: bool = False
    collisions: int = 0
    prevented: int = 0
    messages: int = 0
    wall_time_s: float = 0.0
    requests_resent: int = 0  # requests sent again for want of a reply (a loaded broker)
    units: list[dict[str, Any]] = field(default_factory=list)
    units_empty: int = 0  # units whose battery ever reached 0 %
    jobs: list[dict[str, Any]] = field(default_factory=list)
    goals: list[dict[str, Any]] = field(default_factory=list)
    monitor: FleetMonitor | None = field(default=None, repr=False)  # for tests; not in the JSON

    @property
    def ok(self) -> bool:
        """Everything finished, every goal reached, and zero collisions."""
        return self.finished and self.collisions == 0 and all(g["reached"] for g in self.goals)

    def as_json(self) -> dict[str, Any]:
        """The documented JSON shape."""
        return {
            "steps": self.steps,
            "finished": self.finished,
            "collisions": self.collisions,
            "prevented": self.prevented,
            "units": self.units,
            "units_empty": self.units_empty,
            "jobs": self.jobs,
            "goals": self.goals,
            "messages": self.messages,
            "wall_time_s": self.wall_time_s,
        }


def _all_done(monitor: FleetMonitor, accepted_jobs: int, goals: list[GoalProgress]) -> bool:
    for goal in goals:
        state = monitor.states.get(goal.unit)
        if goal.step is None and state is not None and state.position == goal.target:
            goal.step = monitor.step
    jobs = list(monitor.every_job.values())
    jobs_done = len(jobs) >= accepted_jobs and all(j.state in FINAL_JOB_STATES for j in jobs)
    return jobs_done and all(g.step is not None or g.refused for g in goals)


async def simulate(
    scenario: Scenario,
    step: float,
    max_steps: int,
    root: str,
    broker_url: str | None = None,
    record: bool = False,
    sensors_see_units: bool = True,
    seed: int = 0,
    window: int = DEFAULT_WINDOW,
    energy_policy: str = "gridfleet",
) -> SimulationResult:
    """Run coordinator and units in this process (an own broker in a child) until done."""
    started = time.monotonic()
    outcome = SimulationResult()
    goals = [GoalProgress(g.unit, g.target) for g in scenario.goals]
    refused_jobs: list[JobView] = []
    topics = Topics(root)
    spec = SystemSpec(
        scenario,
        broker=broker_url,
        root=root,
        step_s=step,
        ws_port=None,
        sensors_see_units=sensors_see_units,
        seed=seed,
        window=window,
        energy_policy=energy_policy,
        # Its own process: in this one, amqtt shares the interpreter with the coordinator and
        # every unit, and at short steps its queue grew without bound (bench/README.md).
        own_broker="processes",
    )
    async with contextlib.AsyncExitStack() as stack:
        system = await stack.enter_async_context(Assembly(spec, "threads"))
        services = list(system.threads.values())
        world = world_of(system.fleet)
        # Read once the run is over: each battery is its unit's, in the fleet's thread.
        batteries = {uid: lg.battery for uid, lg in system.fleet.service.logic.items()}
        broker_url = system.url
        client_id = owned_client_id(broker_login(broker_url), f"simulate-{uuid.uuid4().hex[:6]}")
        client = await stack.enter_async_context(connect_first(broker_url, client_id))
        monitor_client = await stack.enter_async_context(
            connect_first(broker_url, client_id + "-m")
        )
        operator = Operator(client, topics, client_id)
        monitor = FleetMonitor(monitor_client, topics, record=record)
        outcome.monitor = monitor
        await operator.start()
        await monitor.start()
        freeze()  # every part has started: no full collection pauses the run to scan them
        listeners = [asyncio.create_task(operator.listen()), asyncio.create_task(monitor.listen())]
        try:
            await asyncio.wait_for(operator.coordinator_online.wait(), 30)
            replies = await submit_scenario(operator, scenario)
            # A refused job or goal can never finish: don't wait for it (it shows in the result).
            accepted_jobs = sum(r.accepted for r in replies[: len(scenario.jobs)])
            for n, (job, reply) in enumerate(zip(scenario.jobs, replies, strict=False), start=1):
                if not reply.accepted:
                    refused_jobs.append(
                        JobView(
                            id=scenario_job_id(scenario, n, job),
                            pickup=job.pickup,
                            dropoff=job.dropoff,
                            mass_kg=job.mass,
                            state="rejected",
                            reason=reply.reason,
                        )
                    )
            for goal, reply in zip(goals, replies[len(scenario.jobs) :], strict=True):
                goal.refused = None if reply.accepted else (reply.reason or "refused")
            last_step, last_progress = monitor.step, time.monotonic()
            while monitor.step < max_steps and not _all_done(monitor, accepted_jobs, goals):
                for service in services:
                    service.check()  # a component that died ends the run with its error
                for t in listeners:
                    if t.done():
                        t.result()
                if monitor.step != last_step:
                    last_step, last_progress = monitor.step, time.monotonic()
                elif time.monotonic() - last_progress > STALL_S + 50 * step:
                    raise GridfleetError(
                        f"no coordinator step for {STALL_S + 50 * step:.0f} s (stuck at step "
                        f"{monitor.step}): the run cannot go on"
                    )
                monitor.changed.clear()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(monitor.changed.wait(), 10 * step + 1)
            outcome.finished = _all_done(monitor, accepted_jobs, goals)
            # Taken now: the coordinator may step once more while the run shuts down.
            outcome.steps = monitor.step
        finally:
            outcome.requests_resent = operator.resent
            for listener in listeners:
                listener.cancel()
    # Read once every service has stopped: the world no longer changes.
    outcome.collisions = world.collisions
    outcome.prevented = world.prevented
    outcome.messages = monitor.messages
    outcome.units = units_json(scenario, world, batteries)
    outcome.units_empty = sum(u["reached_empty"] for u in outcome.units)
    # Some refusals are also kept in the queue view (as `rejected`): list each job once. Any
    # other refusal (e.g. an id the coordinator's store already holds) is listed from its reply.
    jobs = list(monitor.every_job.values())
    in_view = {j.id for j in jobs if j.state == "rejected"}
    jobs += [j for j in refused_jobs if j.id not in in_view]
    outcome.jobs = [job_json(j) for j in jobs]
    outcome.goals = [goal_json(g) for g in goals]
    outcome.wall_time_s = round(time.monotonic() - started, 3)
    return outcome


def goal_json(g: GoalProgress) -> dict[str, Any]:
    """One goal as the result lists it."""
    return {
        "unit": g.unit,
        "target": list(g.target),
        "reached": g.step is not None,
        "step": g.step,
        **({"reason": g.refused} if g.refused else {}),
    }


def job_json(j: JobView) -> dict[str, Any]:
    """One job as the result lists it."""
    return {
        "id": j.id,
        "pickup": list(j.pickup),
        "dropoff": list(j.dropoff),
        "mass": j.mass_kg,
        "state": j.state,
        "unit": j.unit,
        "done_step": j.done_step,
        "reason": j.reason,
        # Why a job not final waits (the coordinator's code and words, protocol.md §5.3).
        "wait": j.wait,
        "wait_reason": j.wait_reason,
    }


def units_json(
    scenario: Scenario, world: WorldSim, batteries: Mapping[str, Battery | None]
) -> list[dict[str, Any]]:
    """Every unit as the result lists it: where it ended, its moves, what its battery went through."""
    listed = []
    for u in scenario.units:
        b = batteries.get(u.id)
        listed.append(
            {
                "id": u.id,
                "capacity": u.capacity,
                "position": list(world.position(u.id)),
                "moves": world.moves[u.id],
                "battery_pct": None if b is None else b.shown_pct,
                "lowest_battery_pct": None if b is None else round(b.lowest_pct, 1),
                "charges": 0 if b is None else b.charges,
                "charging_steps": 0 if b is None else b.charging_steps,
                "standing_steps": 0 if b is None else b.standing_steps,
                "reached_empty": b is not None and b.reached_empty,
            }
        )
    return listed


def summary(outcome: SimulationResult, scenario: Scenario) -> str:
    """A few human lines about the run."""
    done = sum(1 for j in outcome.jobs if j["state"] == "done")
    lines = [
        f"{scenario.name}: {'finished' if outcome.finished else 'NOT finished'} in "
        f"{outcome.steps} steps ({outcome.wall_time_s:.1f} s), {outcome.collisions} collisions,"
        f" {outcome.prevented} prevented moves, {outcome.messages} messages,"
        f" {outcome.requests_resent} requests re-sent",
        f"jobs: {done} done of {len(outcome.jobs)}",
    ]
    powered = [u for u in outcome.units if u["battery_pct"] is not None]
    if powered:
        low = min(powered, key=lambda u: u["lowest_battery_pct"])
        lines.append(
            f"batteries: lowest {low['lowest_battery_pct']:.1f} % ({low['id']}), "
            f"{sum(u['charges'] for u in powered)} charges, "
            + (f"{outcome.units_empty} ran empty" if outcome.units_empty else "none ran empty")
        )
    for job in outcome.jobs:
        if job["state"] != "done":
            lines.append(f"  {job['id']}: {job['state']}{job_words(job)}")
    for goal in outcome.goals:
        lines.append(
            f"goal {goal['unit']} -> {goal['target']}: "
            + (f"reached at step {goal['step']}" if goal["reached"] else "not reached")
        )
    return "\n".join(lines)


def job_words(job: Mapping[str, Any]) -> str:
    """What a job not done says after its state: its reason, and why it waits."""
    words = f" ({job['reason']})" if job["reason"] else ""
    wait, said = job.get("wait"), job.get("wait_reason")
    if wait:
        words += f", waiting: {said} [{wait}]" if said else f", waiting: {wait}"
    return words


def check_energy_policy(policy: str) -> None:
    """ConfigError in one line unless `policy` is one the coordinator has."""
    if policy not in POLICIES:
        raise ConfigError(f"--energy-policy {policy}: give {' or '.join(POLICIES)}")


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet simulate`."""
    check_step(args.step)
    if args.max_steps < 1:
        raise ConfigError(f"--max-steps {args.max_steps}: give at least 1")
    check_window(args.window)
    check_energy_policy(args.energy_policy)
    scenario = with_units(load_scenario(args.scenario))
    if args.json:
        # Keep stdout for the one JSON object.
        logging.getLogger().setLevel(logging.WARNING)
    if args.deterministic:
        if args.broker is not None:
            raise ConfigError("--deterministic runs without a broker: leave --broker out")
        from gridfleet.system.lockstep import (
            run_lockstep,  # it imports this module's SimulationResult
        )

        started = time.monotonic()
        outcome = run_lockstep(
            scenario, args.step, args.max_steps, args.seed, args.window, args.energy_policy
        )
        outcome.wall_time_s = round(time.monotonic() - started, 3)
    else:
        root = args.root
        own_root = args.broker is not None and root == DEFAULT_ROOT
        if own_root:
            # A shared broker keeps what earlier runs retained under a root (units of another
            # map, their `offline`): a root of this run's own, cleared when it is over.
            root = f"gridfleet-sim-{uuid.uuid4().hex[:8]}"
        try:
            outcome = asyncio.run(
                simulate(
                    scenario,
                    args.step,
                    args.max_steps,
                    root,
                    args.broker,
                    seed=args.seed,
                    window=args.window,
                    energy_policy=args.energy_policy,
                )
            )
        finally:
            if own_root:
                # Best effort: a broker that failed the run may fail this too (said above).
                with contextlib.suppress(aiomqtt.MqttError, OSError):
                    asyncio.run(clean_root(args.broker, root))
    if args.json:
        json.dump(outcome.as_json(), sys.stdout)
        sys.stdout.write("\n")
    else:
        print(summary(outcome, scenario))
    return 0 if outcome.ok else 1
