"""`gridfleet simulate --deterministic`: the coordinator's and the units' pure cores in lockstep.

The same cores that run over MQTT (coordinator.core, robots.core), the same messages, but passed
through an in-process bus in a fixed order and stepped on a simulated clock: each step the
coordinator steps, then every unit in id order. Nothing depends on the machine's speed or on
thread scheduling, so a scenario and a seed give the same run, step for step, every time: what
comparing two scenarios or two planner versions needs. Timing effects of a real broker (late and
lost messages) are what the default mode is for.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from functools import partial

from paho.mqtt.client import topic_matches_sub

from gridfleet.console.feed import scenario_job_id
from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.energy import EnergySettings
from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.window import DEFAULT_WINDOW
from gridfleet.coordinator.world import World
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    Charger,
    HeaderStamper,
    Reply,
    SetGoal,
    SubmitJob,
    Topics,
    decode,
    encode,
)
from gridfleet.robots.battery import Battery
from gridfleet.robots.core import UnitCore
from gridfleet.robots.unit import UnitLogic
from gridfleet.robots.world import WorldSim
from gridfleet.scenario import Scenario
from gridfleet.system.simulate import (
    GoalProgress,
    SimulationResult,
    goal_json,
    job_json,
    units_json,
)

Handler = Callable[[str, bytes], list[Outbound]]
OPERATOR = "lockstep"


class LockstepBus:
    """Topics, retained messages and subscriptions in one process; delivery in publish order."""

    def __init__(self) -> None:
        self.subscribers: list[tuple[str, Handler]] = []
        self.retained: dict[str, bytes] = {}
        self.messages = 0
        self._queue: deque[Outbound] = deque()

    def subscribe(self, pattern: str, handler: Handler) -> None:
        """Follow `pattern` (MQTT wildcards); retained messages that match arrive at once."""
        self.subscribers.append((pattern, handler))
        for topic, payload in list(self.retained.items()):
            if topic_matches_sub(pattern, topic):
                self.publish(handler(topic, payload))

    def publish(self, messages: list[Outbound]) -> None:
        """Deliver `messages` and everything they cause, breadth first."""
        self._queue.extend(messages)
        while self._queue:
            out = self._queue.popleft()
            self.messages += 1
            if out.retain:
                if out.payload:
                    self.retained[out.topic] = out.payload
                else:
                    self.retained.pop(out.topic, None)  # an empty retained message clears
            for pattern, handler in list(self.subscribers):
                if topic_matches_sub(pattern, out.topic):
                    self._queue.extend(handler(out.topic, out.payload))


class Lockstep:
    """A scenario's coordinator and units on a LockstepBus, stepped on a simulated clock."""

    def __init__(
        self,
        scenario: Scenario,
        step_s: float,
        seed: int = 0,
        root: str = "sim",
        window: int = DEFAULT_WINDOW,
        policy: str = "gridfleet",  # the coordinator's energy policy (coordinator/energy.py)
    ) -> None:
        self.scenario = scenario
        self.step_s = step_s
        self.topics = Topics(root)
        self.bus = LockstepBus()
        grid = scenario.grid
        starts = {u.id: u.start for u in scenario.units}
        self.world = WorldSim(grid, scenario.hidden_obstacles, starts)
        self.core = CoordinatorCore(
            # Every unit is here before the first step: none can be heard late.
            World(
                grid,
                step_period_s=step_s,
                fleet_known_after_s=0.0,
                chargers=tuple(Charger(name=c.name, square=c.square) for c in scenario.chargers),
            ),
            JobBook(),
            nonce=f"seed{seed}",
            seed=seed,
            topics=self.topics,
            stamp=HeaderStamper("coordinator"),
            window=window,
            energy=EnergySettings.of(scenario.charging, policy),
        )
        chargers = frozenset(c.square for c in scenario.chargers)
        self.units = [
            UnitCore(
                UnitLogic(
                    u.id,
                    grid,
                    u.start,
                    u.capacity,
                    step_s,
                    battery=None if u.battery is None else Battery.from_spec(u.battery, step_s),
                    chargers=chargers,
                ),
                self.topics,
                color=u.color,
            )
            for u in sorted(scenario.units, key=lambda u: u.id)
        ]
        self.replies: dict[str, Reply] = {}
        self.now = 0.0

    def start(self) -> None:
        """Everybody subscribes and connects, in a fixed order: coordinator, units, operator."""
        core = self.core
        for pattern, _ in core.subscriptions():
            self.bus.subscribe(pattern, lambda t, p: list(core.on_message(t, p, self.now).publish))
        self.bus.publish(list(core.on_connect(self.now).publish))
        for unit in self.units:
            unit.start(self.now)
            for pattern, _ in unit.subscriptions():
                self.bus.subscribe(pattern, self._unit_handler(unit))
            self.bus.publish(unit.on_connect(self.now))
        self.bus.subscribe(self.topics.reply(OPERATOR), self._on_reply)

    def _unit_handler(self, unit: UnitCore) -> Handler:
        return lambda topic, payload: unit.on_message(topic, payload, self.now)

    def _on_reply(self, topic: str, payload: bytes) -> list[Outbound]:
        reply = decode(Reply, payload)
        self.replies[reply.request_id] = reply
        return []

    def submit_scenario(self) -> list[Reply]:
        """Every job, then every goal, of the scenario: their replies, in that order."""
        stamp = HeaderStamper(OPERATOR)
        sent: list[str] = []
        for n, job in enumerate(self.scenario.jobs, start=1):
            rid = f"job-{n}"
            req = SubmitJob(
                header=stamp("submit_job"),
                request_id=rid,
                reply_to=OPERATOR,
                pickup=job.pickup,
                dropoff=job.dropoff,
                mass_kg=job.mass,
                priority=job.priority,
                job_id=scenario_job_id(self.scenario, n, job),
            )
            self._request("submit_job", req)
            sent.append(rid)
        for n, goal in enumerate(self.scenario.goals, start=1):
            rid = f"goal-{n}"
            req_goal = SetGoal(
                header=stamp("set_goal"),
                request_id=rid,
                reply_to=OPERATOR,
                unit=goal.unit,
                target=goal.target,
            )
            self._request("set_goal", req_goal)
            sent.append(rid)
        return [self.replies[rid] for rid in sent]

    def _request(self, kind: str, req: SubmitJob | SetGoal) -> None:
        self.bus.publish([Outbound.of(kind, self.topics.request(kind), encode(req))])

    def step(self) -> None:
        """One step: the coordinator's (orders), then each unit's move and state, in id order."""
        self.now += self.step_s
        core = self.core
        self.bus.publish(list(core.step(self.now).publish))
        self.bus.publish(list(core.views_due(self.now).publish))
        for unit in self.units:
            self.bus.publish(
                unit.tick(
                    partial(self.world.sense, unit.id), partial(self.world.move, unit.id), self.now
                )
            )

    def finished(self) -> bool:
        """Every job final and every goal reached (or cleared)."""
        jobs_done = all(j.final for j in self.core.jobs.jobs.values())
        return jobs_done and not self.core.directives.goals


def run_lockstep(
    scenario: Scenario,
    step_s: float,
    max_steps: int,
    seed: int,
    window: int = DEFAULT_WINDOW,
    policy: str = "gridfleet",
) -> SimulationResult:
    """The scenario to the end (or `max_steps`), deterministically, under the coordinator's
    energy `policy`; the same result as ever."""
    sim = Lockstep(scenario, step_s, seed, window=window, policy=policy)
    sim.start()
    replies = sim.submit_scenario()
    goals = [
        GoalProgress(g.unit, g.target, refused=None if r.accepted else (r.reason or "refused"))
        for g, r in zip(scenario.goals, replies[len(scenario.jobs) :], strict=True)
    ]
    while sim.core.step_no < max_steps and not sim.finished():
        sim.step()
        for goal in goals:
            here = sim.world.position(goal.unit) == goal.target
            if goal.refused is None and here and goal.step is None:
                goal.step = sim.core.step_no
    outcome = SimulationResult(
        steps=sim.core.step_no,
        finished=sim.finished(),
        collisions=sim.world.collisions,
        prevented=sim.world.prevented,
        messages=sim.bus.messages,
    )
    outcome.units = units_json(scenario, sim.world, {u.id: u.logic.battery for u in sim.units})
    outcome.units_empty = sum(u["reached_empty"] for u in outcome.units)
    outcome.jobs = [job_json(j.view()) for j in sim.core.jobs.jobs.values()]
    outcome.goals = [goal_json(g) for g in goals]
    return outcome
