"""The planner benchmark runs, pure: instances in, results out (the clock is injected).

Every step the planner makes is checked by the plan validator (vertex, swap, rotation, walls,
jumps) outside the timed part; a benchmark that counted an unsafe plan as throughput would lie.
"""

from __future__ import annotations

import random
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.sparse.csgraph import connected_components

from gridfleet.bench.anchors import LifelongInstance, ScenAgent
from gridfleet.coordinator.allocation import JobRequest, UnitSlot, allocate
from gridfleet.coordinator.planning.planner import AgentSpec, Planner
from gridfleet.coordinator.planning.validate import validate_step
from gridfleet.grid import Cell, GridMap
from gridfleet.paths import UNREACHABLE, DistanceFieldCache, adjacency, fields_that_fit

Clock = Callable[[], float]
ALLOCATE_AT_MOST = 256  # idle agents paired in one assignment (it is cubic in this)
OFFER_AT_MOST = 1024  # open tasks offered to one assignment as they are; more: the nearest...
OFFER_EACH = 2  # ...this many for each agent of the batch


class StepPlanner(Protocol):
    """What the runs need of a planner: one step for every agent (planning.planner.Planner)."""

    def step(self, agents: dict[str, AgentSpec]) -> dict[str, Cell]:
        """Next square of every agent."""


@dataclass(frozen=True)
class Timing:
    """Seconds the planner took for each step."""

    seconds: tuple[float, ...]

    @property
    def median_ms(self) -> float:
        """Median step time in milliseconds."""
        return 1000 * statistics.median(self.seconds) if self.seconds else 0.0

    @property
    def p95_ms(self) -> float:
        """95th-percentile step time in milliseconds."""
        return 1000 * float(np.percentile(self.seconds, 95)) if self.seconds else 0.0

    @property
    def p99_ms(self) -> float:
        """99th-percentile step time in milliseconds."""
        return 1000 * float(np.percentile(self.seconds, 99)) if self.seconds else 0.0

    @property
    def mean_ms(self) -> float:
        """Mean step time in milliseconds."""
        return 1000 * statistics.fmean(self.seconds) if self.seconds else 0.0

    @property
    def max_ms(self) -> float:
        """Slowest step in milliseconds (the first step computes most distance fields)."""
        return 1000 * max(self.seconds) if self.seconds else 0.0


@dataclass(frozen=True)
class LifelongResult:
    """What a lifelong run achieved within its horizon."""

    name: str
    agents: int
    ticks: int
    tasks_finished: int
    tasks_available: int
    exhausted_at: int | None  # tick at which the task stream ran out, if it did
    violations: int
    timing: Timing
    scheduling: Timing = Timing(())  # the scheduler's share of each tick (MR24: the allocator)
    setup_s: float = 0.0  # planner and task pool made, the first tasks given out
    finished_by_tick: tuple[int, ...] = ()  # tasks finished by the end of each tick
    fields_computed: int = 0  # distance fields computed (beyond distinct targets: thrashing)

    @property
    def tick(self) -> Timing:
        """Planner and scheduler together, every tick."""
        both = zip(self.timing.seconds, self.scheduling.seconds, strict=False)
        return Timing(tuple(p + a for p, a in both))


@dataclass(frozen=True)
class OneShotResult:
    """A one-shot MAPF run: every agent to its goal."""

    agents: int
    solved: bool
    at_goal: int  # agents on their goals when the run ended
    makespan: int | None  # first step with every agent on its goal
    sum_of_costs: int | None  # per agent: the step after which it never left its goal
    lower_bound: int  # sum of shortest-path lengths, ignoring the other agents
    violations: int
    timing: Timing


# How the planner is guided (`gridfleet bench planner --guidance`): "auto" is what the coordinator
# runs (guide paths up to guidance.MAX_SQUARES squares, one-way lanes above); "off" is plain
# shortest-path fields, the League of Robot Runners' default entry's PIBT without its guidance.
GUIDANCE: dict[str, dict[str, bool]] = {
    "auto": {},
    "off": {"guided": False, "lanes": False},
    "lanes": {"guided": False, "lanes": True},
    "paths": {"guided": True, "lanes": False},
}


@dataclass
class CheckedPlanner:
    """Steps a planner, timing each step and checking it with the plan validator (untimed)."""

    planner: StepPlanner
    grid: GridMap
    clock: Clock
    seconds: list[float] = field(default_factory=list)
    violations: int = 0

    def step(self, specs: dict[str, AgentSpec]) -> dict[str, Cell]:
        """The planner's next squares for `specs`."""
        started = self.clock()
        after = self.planner.step(specs)
        self.seconds.append(self.clock() - started)
        before = [s.position for s in specs.values()]
        moved = [after[a] for a in specs]
        self.violations += len(validate_step(self.grid, before, moved, len(self.seconds) - 1))
        return after


def run_lifelong(
    instance: LifelongInstance,
    horizon: int | None = None,
    seed: int = 0,
    clock: Clock = time.perf_counter,
    planner: StepPlanner | None = None,
    progress: Callable[[int, int], None] | None = None,
    guidance: str = "auto",
) -> LifelongResult:
    """Run `instance` for `horizon` ticks (default: its own); an idle agent is given a task.

    How is the instance's rule: MR23's stream (`_Stream`) or MR24's pool (`_Pool`). `progress`
    is told (tick, tasks finished) after every tick."""
    ticks = instance.horizon if horizon is None else horizon
    names = [str(i) for i in range(instance.agents)]
    position = dict(zip(names, instance.starts, strict=True))
    errands: dict[str, list[Cell]] = {a: [] for a in names}
    began = clock()
    if planner is None:
        # Room for every distinct target the run can meet (and a parking square an agent),
        # within the fields' memory bound: a cache smaller than the targets of one tick
        # computes them all again every tick.
        targets = len({c for task in instance.tasks for c in task})
        size = fields_that_fit(instance.grid, targets + instance.agents)
        planner = Planner(instance.grid, seed=seed, cache_size=size, **GUIDANCE[guidance])
    cache = getattr(planner, "cache", None)  # the planner's own fields: one copy, not two
    if not isinstance(cache, DistanceFieldCache):
        cache = DistanceFieldCache(instance.grid)
    tasks: _Stream | _Pool = (
        _Stream(instance.tasks)
        if instance.open_tasks is None
        else _Pool(instance.tasks, instance.open_tasks, cache)
    )
    tasks.give(names, position, errands)
    setup_s = clock() - began
    finished = 0
    finished_by_tick: list[int] = []
    scheduling: list[float] = []
    exhausted_at: int | None = None
    checked = CheckedPlanner(planner, instance.grid, clock)
    for tick in range(ticks):
        agents = {a: AgentSpec(position[a], errands[a][0] if errands[a] else None) for a in names}
        position = checked.step(agents)
        began = clock()
        idle = []
        for a in names:
            if errands[a] and position[a] == errands[a][0]:
                errands[a].pop(0)
                if not errands[a]:
                    finished += 1
                    tasks.reveal()
                    idle.append(a)
        tasks.give(idle, position, errands)
        scheduling.append(clock() - began)
        finished_by_tick.append(finished)
        if exhausted_at is None and any(not errands[a] for a in idle):
            exhausted_at = tick  # an agent done with its task found none left
        if progress is not None:
            progress(tick, finished)
    return LifelongResult(
        name=instance.name,
        agents=instance.agents,
        ticks=ticks,
        tasks_finished=finished,
        tasks_available=len(instance.tasks),
        exhausted_at=exhausted_at,
        violations=checked.violations,
        timing=Timing(tuple(checked.seconds)),
        scheduling=Timing(tuple(scheduling)),
        setup_s=setup_s,
        finished_by_tick=tuple(finished_by_tick),
        fields_computed=cache.computed + _lanes_computed(planner),
    )


def _lanes_computed(planner: StepPlanner) -> int:
    """Fields of a planner's one-way lanes computed (beside its plain ones), if it has lanes."""
    lanes = getattr(planner, "lanes", None)
    return lanes.computed if isinstance(lanes, DistanceFieldCache) else 0


class _Stream:
    """MR23's rule: agent i starts on task i; one that finishes takes the stream's next task."""

    def __init__(self, tasks: Sequence[tuple[Cell, ...]]) -> None:
        self._tasks = tasks
        self._next = 0

    def give(
        self, idle: list[str], position: dict[str, Cell], errands: dict[str, list[Cell]]
    ) -> None:
        """The next tasks to the `idle` agents, in order."""
        for a in idle:
            if self._next < len(self._tasks):
                errands[a] = list(self._tasks[self._next])
                self._next += 1

    def reveal(self) -> None:
        """Nothing: the whole stream is known."""


class _Pool:
    """MR24's rule: `open` tasks known at the start and one more each time one is finished; the
    coordinator's allocator gives known tasks to idle agents (least travel to the first errand,
    then on to the last). A task given out stays with its agent until done. As in the
    competition's simulator, the task file is gone through again when it runs out (task k is
    the file's k mod its length)."""

    def __init__(
        self, tasks: Sequence[tuple[Cell, ...]], open_tasks: int, cache: DistanceFieldCache
    ) -> None:
        self._tasks = tasks
        self._open = dict.fromkeys(range(min(open_tasks, len(tasks))))  # in reveal order
        self._next = len(self._open)
        self._cache = cache
        self._carry: dict[int, int] = {}  # the file's task -> travel from first to last errand

    def task(self, k: int) -> tuple[Cell, ...]:
        """The errands of the `k`th task revealed."""
        return self._tasks[k % len(self._tasks)]

    def give(
        self, idle: list[str], position: dict[str, Cell], errands: dict[str, list[Cell]]
    ) -> None:
        """Known tasks to the `idle` agents, as the allocator pairs them."""
        # The assignment is cubic: a fleet's worth of idle agents (every one, at the start) is
        # paired a batch at a time, each batch offered the tasks nearest its agents.
        for start in range(0, len(idle), ALLOCATE_AT_MOST):
            if not self._open:
                return
            batch = idle[start : start + ALLOCATE_AT_MOST]
            offered = list(self._open) if len(self._open) <= OFFER_AT_MOST else None
            if offered is None:
                offered = self._nearest(batch, position)
            units = [UnitSlot(a, position[a], 1.0) for a in batch]
            jobs = [JobRequest(str(k), self.task(k)[0], self.task(k)[-1], 0.0) for k in offered]
            pairs = allocate(self._cache, units, jobs)
            for job, agent in pairs.items():
                errands[agent] = list(self.task(int(job)))
                del self._open[int(job)]

    def _nearest(self, batch: list[str], position: dict[str, Cell]) -> list[int]:
        """Open tasks to offer `batch`: for each agent in turn, the OFFER_EACH not yet offered
        whose first errands are nearest it (shortest onward travel first among equals)."""
        by_first: dict[Cell, list[int]] = {}
        for k in self._open:
            by_first.setdefault(self.task(k)[0], []).append(k)
        cache, w = self._cache, self._cache.grid.width
        for ks in by_first.values():
            ks.sort(key=self._carry_of)
        firsts = list(by_first)
        at = np.array([position[a].y * w + position[a].x for a in batch], dtype=np.intp)
        # Few squares are first errands (a warehouse's pick faces), so one row per square.
        near = np.stack([cache.distances(c, at) for c in firsts]).argsort(axis=0, kind="stable")
        taken = dict.fromkeys(range(len(firsts)), 0)  # how many of each square's tasks offered
        offered: list[int] = []
        for col in range(len(batch)):
            want = OFFER_EACH
            for row in near[:, col].tolist():
                ks = by_first[firsts[row]]
                got = ks[taken[row] : taken[row] + want]
                taken[row] += len(got)
                offered.extend(got)
                want -= len(got)
                if want == 0:
                    break
        return offered

    def _carry_of(self, k: int) -> int:
        n = k % len(self._tasks)
        carry = self._carry.get(n)
        if carry is None:
            first, last = self._tasks[n][0], self._tasks[n][-1]
            carry = self._carry[n] = self._cache.distance(last, first)  # the first's field
        return carry

    def reveal(self) -> None:
        """One more task becomes known (the file again from its start once it runs out)."""
        self._open[self._next] = None
        self._next += 1


def run_one_shot(
    grid: GridMap,
    agents: Sequence[ScenAgent],
    max_steps: int,
    seed: int = 0,
    clock: Clock = time.perf_counter,
    planner: StepPlanner | None = None,
    guidance: str = "auto",
) -> OneShotResult:
    """Move every agent to its goal; stop when all are there at once or after `max_steps`."""
    names = [str(i) for i in range(len(agents))]
    goal = {a: agents[i].goal for i, a in enumerate(names)}
    position = {a: agents[i].start for i, a in enumerate(names)}
    fields = DistanceFieldCache(grid)
    shortest = [fields.distance(s.start, s.goal) for s in agents]
    if UNREACHABLE in shortest:
        raise ValueError("an agent's goal cannot be reached from its start")
    arrived = {a: 0 if position[a] == goal[a] else None for a in names}
    checked = CheckedPlanner(planner or Planner(grid, seed=seed, **GUIDANCE[guidance]), grid, clock)
    makespan: int | None = 0 if all(v == 0 for v in arrived.values()) else None
    step = 0
    while makespan is None and step < max_steps:
        after = checked.step({a: AgentSpec(position[a], goal[a]) for a in names})
        step += 1
        for a in names:
            if after[a] != goal[a]:
                arrived[a] = None
            elif arrived[a] is None:
                arrived[a] = step
        position = after
        if all(v is not None for v in arrived.values()):
            makespan = step
    costs = [v for v in arrived.values() if v is not None]
    return OneShotResult(
        agents=len(agents),
        solved=makespan is not None,
        at_goal=sum(position[a] == goal[a] for a in names),
        makespan=makespan,
        sum_of_costs=sum(costs) if makespan is not None else None,
        lower_bound=sum(shortest),
        violations=checked.violations,
        timing=Timing(tuple(checked.seconds)),
    )


def random_instance(
    grid: GridMap, agents: int, horizon: int, seed: int = 0, name: str | None = None
) -> LifelongInstance:
    """A lifelong instance with random starts and one-errand tasks in the grid's largest region."""
    cells = largest_region(grid)
    if agents < 1 or agents > len(cells):
        raise ValueError(f"{agents} agents do not fit the {len(cells)} connected free squares")
    rng = random.Random(seed)
    starts = rng.sample(cells, agents)
    # Enough tasks that the stream does not run out: even short errands take a few ticks.
    tasks = tuple((rng.choice(cells),) for _ in range(agents * (1 + horizon // 4)))
    return LifelongInstance(
        name=name or f"{grid.name}-{agents}",
        grid=grid,
        starts=tuple(starts),
        tasks=tasks,
        horizon=horizon,
    )


def largest_region(grid: GridMap) -> list[Cell]:
    """The free squares of `grid`'s largest 4-connected region."""
    labels = connected_components(adjacency(grid), directed=False)[1].reshape(grid.height, -1)
    free = ~grid.blocked
    biggest = np.bincount(labels[free]).argmax()
    ys, xs = np.nonzero(free & (labels == biggest))
    return [Cell(int(x), int(y)) for x, y in zip(xs, ys, strict=True)]
