"""The scale run: thousands of units doing pick-and-deliver jobs on one large map, pure.

Jobs go from a pick face to a drop station, both drawn (seeded) from a fixed set of squares, as in
a warehouse; the coordinator's own allocator (`coordinator.allocation.allocate`) gives queued jobs
to idle units under capacity, and the coordinator's own planner moves everyone. The distance
fields of every pick face and station are computed in bulk before the first tick and shared by all
units going there (`first_tick_s` includes them). Every step is checked by the plan validator
outside the timed part.
"""

from __future__ import annotations

import random
import time
from collections import deque
from dataclasses import dataclass, field

from gridfleet.bench.runs import GUIDANCE, CheckedPlanner, Clock, Timing, largest_region
from gridfleet.coordinator.allocation import JobRequest, UnitSlot, allocate
from gridfleet.coordinator.planning.planner import AgentSpec, Planner
from gridfleet.grid import Cell, GridMap

ALLOCATE_AT_MOST = 256  # idle units given jobs in one tick (the assignment is cubic in this)
CAPACITIES_KG = (5.0, 10.0)  # every other unit is a light one
PARKING_FIELDS = 2048  # distance fields kept beside those of pick faces and stations
MASSES_KG = (1.0, 8.0)  # jobs' masses, uniform: about a third only the heavy units can carry


@dataclass(frozen=True)
class ScaleResult:
    """What a scale run achieved and what each tick cost."""

    map: str
    agents: int
    ticks: int
    pick_faces: int
    stations: int
    tasks_finished: int
    tasks_second_half: int  # finished in the second half of the run, when the fleet is busy
    travel_per_job: float  # mean shortest travel of a job given out: to its pickup, then on
    first_tick_s: float  # the distance fields of every pick face and station, and tick 0
    planner: Timing  # the planner's step, ticks after the first
    allocation: Timing  # the allocator's share of each tick after the first
    violations: int

    @property
    def tasks_per_tick(self) -> float:
        """Jobs done per tick, over the whole run."""
        return self.tasks_finished / self.ticks if self.ticks else 0.0

    @property
    def steady_tasks_per_tick(self) -> float:
        """Jobs done per tick in the second half of the run (every unit long since busy)."""
        half = self.ticks - self.ticks // 2
        return self.tasks_second_half / half if half else 0.0

    @property
    def tick(self) -> Timing:
        """Planner and allocator together, each tick after the first."""
        both = zip(self.planner.seconds, self.allocation.seconds, strict=True)
        return Timing(tuple(p + a for p, a in both))


@dataclass
class _Unit:
    position: Cell
    capacity_kg: float
    errands: deque[Cell] = field(default_factory=deque)  # pickup then dropoff, while on a job


def run_scale(
    grid: GridMap,
    agents: int,
    ticks: int,
    seed: int = 0,
    pick_faces: int = 2000,
    stations: int = 200,
    clock: Clock = time.perf_counter,
    guidance: str = "auto",
) -> ScaleResult:
    """Run `agents` units for `ticks` ticks on `grid`, a job queue always waiting for them."""
    cells = largest_region(grid)
    if agents < 1 or agents + pick_faces + stations > len(cells):
        raise ValueError(
            f"{agents} agents, {pick_faces} pick faces and {stations} stations do not fit the "
            f"{len(cells)} connected free squares"
        )
    rng = random.Random(seed)
    picked = rng.sample(cells, agents + pick_faces + stations)
    faces, drops = picked[agents : agents + pick_faces], picked[agents + pick_faces :]
    units = {
        f"u{i}": _Unit(c, CAPACITIES_KG[i % len(CAPACITIES_KG)])
        for i, c in enumerate(picked[:agents])
    }
    # Room for every pick face and station and for the squares idle units park on: a cache
    # smaller than the fields used in one tick would compute them all again every tick.
    size = pick_faces + stations + PARKING_FIELDS
    planner = Planner(grid, seed=seed, cache_size=size, **GUIDANCE[guidance])
    checked = CheckedPlanner(planner, grid, clock)
    queue: deque[JobRequest] = deque()
    made = finished = second_half = 0
    allocation: list[float] = []
    travel: list[int] = []
    started = clock()
    planner.cache.warm((*faces, *drops))  # in bulk, before the first tick
    if planner.lanes is not None:
        planner.lanes.warm((*faces, *drops))
    first_tick_s = clock() - started
    for tick in range(ticks):
        began = clock()
        idle = [UnitSlot(a, u.position, u.capacity_kg) for a, u in units.items() if not u.errands]
        idle = idle[:ALLOCATE_AT_MOST]
        while len(queue) < 2 * len(idle):
            made += 1
            mass = round(rng.uniform(*MASSES_KG), 1)
            queue.append(JobRequest(f"j{made}", rng.choice(faces), rng.choice(drops), mass))
        pairs = allocate(planner.cache, idle, list(queue)[: 2 * len(idle)])
        for job in queue:
            if job.id in pairs:
                unit = units[pairs[job.id]]
                unit.errands.extend((job.pickup, job.dropoff))
                travel.append(
                    planner.cache.distance(unit.position, job.pickup)
                    + planner.cache.distance(job.pickup, job.dropoff)
                )
        queue = deque(j for j in queue if j.id not in pairs)
        allocation.append(clock() - began)
        specs = {
            a: AgentSpec(u.position, u.errands[0] if u.errands else None) for a, u in units.items()
        }
        moved = checked.step(specs)
        for a, u in units.items():
            u.position = moved[a]
            if u.errands and u.position == u.errands[0]:
                u.errands.popleft()
                if not u.errands:
                    finished += 1
                    second_half += tick >= ticks // 2
    if ticks:
        first_tick_s += allocation[0] + checked.seconds[0]
    return ScaleResult(
        map=grid.name,
        agents=agents,
        ticks=ticks,
        pick_faces=pick_faces,
        stations=stations,
        tasks_finished=finished,
        tasks_second_half=second_half,
        travel_per_job=sum(travel) / len(travel) if travel else 0.0,
        first_tick_s=first_tick_s,
        planner=Timing(tuple(checked.seconds[1:])),
        allocation=Timing(tuple(allocation[1:])),
        violations=checked.violations,
    )
