"""PIBT-family multi-unit planner: one collision-free, rotation-free step for every unit.

Pure: a grid, current squares, targets and priorities in; next squares out. Distance fields
(cached per target) from `gridfleet.paths` are the heuristic: on maps of up to 4096 squares a
unit's field follows its guide path (`coordinator.planning.guidance`), on larger ones the
cheapest cost under one-way lanes (`coordinator.planning.flow`). Priority inheritance with
backtracking (PIBT, Okumura et al. 2019) lets a high-priority unit push lower ones out of its way.

Units run asynchronously (each enters a released square only when its own sensor sees it free),
so besides vertex conflicts and swaps the planner never produces a *rotation*: a closed cycle of
units each entering the square another vacates would wait on itself forever. Following a unit that
moves away is fine. Priorities grow every step a unit has not reached its target and reset on
arrival, so every unit eventually becomes the most urgent one and gets through.

This module keeps what lasts between steps (grid, distance fields, priorities, the seeded random
stream) and orders the agents; the search of one step is `coordinator.planning.pibt`, the
corridor swap `coordinator.planning.pibt_swap`.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from gridfleet.coordinator.planning.flow import lane_costs
from gridfleet.coordinator.planning.guidance import MAX_SQUARES, Guidance
from gridfleet.coordinator.planning.parking import parking_square
from gridfleet.coordinator.planning.pibt import NONE, PIBT, neighbour_table
from gridfleet.coordinator.planning.unjam import Unjam
from gridfleet.grid import Cell, GridMap
from gridfleet.paths import UNREACHABLE, DistanceFieldCache


@dataclass(frozen=True)
class AgentSpec:
    """One unit as the planner sees it: where it is, where it wants to go, whether it may move."""

    position: Cell
    target: Cell | None = None  # None: no errand; it stays unless pushed
    frozen: bool = False  # may not move this step (in motion, unacknowledged, lost, stopped)

    @property
    def settled(self) -> bool:
        """No errand, or already on its target."""
        return self.target is None or self.target == self.position


class Planner:
    """Plans one step at a time for a fleet on one grid; keeps priorities between steps."""

    def __init__(
        self,
        grid: GridMap,
        seed: int = 0,
        cache_size: int = 4096,
        guided: bool | None = None,
        lanes: bool | None = None,
    ) -> None:
        """`guided`: traffic-flow guidance (`planning.guidance`); None: on for maps of up to
        `guidance.MAX_SQUARES` squares. `lanes`: one-way lanes (`planning.flow`); None: on
        where guidance is off (a guide path per unit is too much on a large map)."""
        self._rng = np.random.default_rng(seed)
        self._seed = seed
        self._guided = guided
        self._lanes_wanted = lanes
        self._cache_size = cache_size
        self._priority: dict[str, float] = {}
        self._tiebreak: dict[str, float] = {}
        self._parking: dict[str, Cell] = {}  # idle units making way: where each goes to wait
        self.set_grid(grid)

    @property
    def grid(self) -> GridMap:
        """The grid plans are made on (static map plus known obstacles)."""
        return self._grid

    def set_grid(self, grid: GridMap) -> None:
        """Re-plan on a new grid (e.g. after an obstacle was reported); drops cached fields."""
        self._grid = grid
        self._free = ~grid.blocked.reshape(-1)
        self._nbrs = neighbour_table(grid)
        guided = self._guided
        if guided is None:
            guided = grid.width * grid.height <= MAX_SQUARES
        lanes = not guided if self._lanes_wanted is None else self._lanes_wanted
        # One-way lanes: the fields units descend cost more against a lane (`flow`); plain
        # fields stay for the allocator, the display and getting units unstuck.
        self.lanes = (
            DistanceFieldCache(grid, size=self._cache_size, costs=lane_costs(grid))
            if lanes
            else None
        )
        self.cache = DistanceFieldCache(grid, size=self._cache_size)
        self.unjam = Unjam(self._nbrs, self._field_to, self._seed)
        # Guide paths follow the traffic of the grid they were made on: a new grid, new ones.
        self.guidance = Guidance(self._nbrs, self._field_to) if guided else None

    def _field_to(self, square: int) -> Sequence[int]:
        """The plain distance field towards a flat square."""
        w = self._grid.width
        return self.cache.flat(Cell(square % w, square // w))

    def add_obstacles(self, cells: Iterable[Cell]) -> None:
        """Block newly discovered squares and re-plan around them."""
        self.set_grid(self._grid.with_blocked(cells))

    def priority(self, agent: str) -> float:
        """The current priority of `agent` (grows while it has not reached its target)."""
        return self._priority.get(agent, 0.0)

    def step(
        self,
        agents: dict[str, AgentSpec],
        reserved: Iterable[Cell] = (),
        urgency: dict[str, float] | None = None,
        keep_clear: Iterable[Cell] = (),
    ) -> dict[str, Cell]:
        """Next square of every agent; `reserved` squares are entered by nobody this step.

        `urgency` adds to an agent's priority (e.g. job priority). Priorities are updated here:
        +1 for each agent with a target it has not reached, reset to 0 on arrival. An idle agent
        on another's target, or on a square in `keep_clear` (one a unit not planned here waits
        for: its way out of a closed zone), is given a parking square to go to (`parking`).
        """
        agents = self._making_way(agents, frozenset(keep_clear))
        w = self._grid.width
        names = list(agents)
        specs = list(agents.values())
        pos = [s.position.y * w + s.position.x for s in specs]
        for a, p in zip(names, pos, strict=True):
            if not self._free[p]:
                raise ValueError(f"agent {a} stands on a blocked square {agents[a].position}")
        settled = [s.settled for s in specs]
        order = self._urgent_first(names, settled, urgency or {})
        goal = [NONE if s.target is None else s.target.y * w + s.target.x for s in specs]
        held = {c.y * w + c.x for c in reserved if self._grid.in_bounds(c)}
        frozen = [s.frozen for s in specs]
        moves = self.unjam.moves(names, pos, goal, frozen, held)
        if moves is None:
            if self.guidance is not None:
                self.guidance.keep_only({a for a, s in agents.items() if s.target is not None})
                self.guidance.begin_step()
                # Renewed here, not after the moves: between steps every unit shows its guide.
                self.guidance.renew(names)
            fields = [self._field(a, s) for a, s in zip(names, specs, strict=True)]
            search = PIBT(self._nbrs, pos, goal, fields, settled, self._rng.random)
            for square in held:
                search.reserve(square)
            for i, still in enumerate(frozen):
                if still:
                    search.freeze(i)
            moves = search.run(order)
        for a, done in zip(names, settled, strict=True):
            if not done:
                self._priority[a] += 1.0
        return {a: Cell(m % w, m // w) for a, m in zip(names, moves, strict=True)}

    def _field(self, agent: str, spec: AgentSpec) -> Sequence[int] | None:
        """The distance field `agent` descends this step (flat), or None without a target."""
        if spec.target is None:
            return None
        if self.guidance is None:
            return (self.cache if self.lanes is None else self.lanes).flat(spec.target)
        w = self._grid.width
        here, target = spec.position, spec.target
        guided = self.guidance.field(agent, here.y * w + here.x, target.y * w + target.x)
        return self.cache.flat(target) if guided is None else guided

    def forget(self, agent: str) -> None:
        """A unit removed for good: its priority and parking square go (back, it starts anew)."""
        self._priority.pop(agent, None)
        self._parking.pop(agent, None)

    def parking(self, agent: str) -> Cell | None:
        """Where idle `agent` is going to make way for another unit, if it is."""
        return self._parking.get(agent)

    def _making_way(
        self, agents: dict[str, AgentSpec], keep_clear: frozenset[Cell] = frozenset()
    ) -> dict[str, AgentSpec]:
        """The agents, each idle one on another's target (or `keep_clear`) sent to park."""
        wanted = {s.target for s in agents.values() if s.target is not None} | keep_clear
        out = agents
        for a, s in agents.items():
            if s.target is not None:
                self._parking.pop(a, None)
                continue
            park = self._parking.get(a)
            if park is not None and (
                park == s.position or park in wanted or not self._grid.is_free(park)
            ):
                del self._parking[a]
                park = None
            if park is None and s.position in wanted and not s.frozen:
                park = self._park(s.position, wanted, agents)
            if park is not None:
                self._parking[a] = park
                if out is agents:
                    out = dict(agents)
                out[a] = AgentSpec(s.position, park, s.frozen)
        return out

    def _park(self, here: Cell, wanted: set[Cell], agents: dict[str, AgentSpec]) -> Cell | None:
        # Off every target and off the way of those coming for `here`: parking on their way
        # would only swap the two back and forth.
        avoid = set(wanted)
        for s in agents.values():
            if s.target == here:
                avoid.add(s.position)
                avoid.update(self.route(s.position, here))
        w = self._grid.width
        flat = parking_square(
            self._nbrs,
            here.y * w + here.x,
            {c.y * w + c.x for c in avoid},
            {s.position.y * w + s.position.x for s in agents.values()},
        )
        return None if flat is None else Cell(flat % w, flat // w)

    def _urgent_first(
        self, names: list[str], settled: list[bool], urgency: dict[str, float]
    ) -> list[int]:
        """Agents by priority, highest first; resets the priority of those that arrived."""
        # Priority: elapsed time since last arrival plus a random tie-breaker in [0, 1). The
        # tie-breaker is fixed per agent: re-drawing it every step lets equal agents take turns
        # pushing each other back and forth forever.
        for a in names:
            if a not in self._tiebreak:
                self._tiebreak[a] = float(self._rng.random())
        prio = []
        for a, done in zip(names, settled, strict=True):
            base = 0.0 if done else self._priority.get(a, 0.0)
            self._priority[a] = base
            # Units already at their target come last but can still be pushed.
            prio.append((-1.0 if done else base) + urgency.get(a, 0.0) + self._tiebreak[a])
        return sorted(range(len(names)), key=lambda i: -prio[i])

    def route(
        self, start: Cell, target: Cell, limit: int = 256, unit: str | None = None
    ) -> list[Cell]:
        """The way after `start` to `target` (empty when unreachable), for display: `unit`'s guide
        path when it is guided there through `start`, else a shortest path."""
        w = self._grid.width
        if unit is not None and self.guidance is not None:
            ahead = self.guidance.ahead(unit, start.y * w + start.x, target.y * w + target.x)
            if ahead is not None:
                return [Cell(s % w, s // w) for s in ahead[:limit]]
        # By flat index over the kept field and the neighbour table (N, E, S, W, as
        # Cell.neighbours): a route shown for every unit in every order cost the coordinator
        # about a seventh of its time at 500 units built from Cells (and a field copied per call
        # on the large maps).
        out: list[Cell] = []
        here = start.y * w + start.x
        if self.cache.distance(start, target) >= UNREACHABLE:
            return out
        if self.lanes is not None:
            # As PIBT ranks squares: down the lanes' field, each square cheaper than the last.
            lane = self.lanes.flat(target)
            while lane[here] > 0 and len(out) < limit:
                here = min(self._nbrs[here], key=lane.__getitem__)
                out.append(Cell(here % w, here // w))
            return out
        field = self.cache.flat(target)
        d = field[here]
        while d > 0 and len(out) < limit:
            here = next(n for n in self._nbrs[here] if field[n] == d - 1)
            out.append(Cell(here % w, here // w))
            d -= 1
        return out


def plan_step(
    grid: GridMap,
    positions: Sequence[Cell],
    targets: Sequence[Cell | None],
    seed: int = 0,
) -> list[Cell]:
    """One step for units given as lists (a fresh planner: no priority memory)."""
    planner = Planner(grid, seed=seed)
    agents = {
        str(i): AgentSpec(p, t) for i, (p, t) in enumerate(zip(positions, targets, strict=True))
    }
    out = planner.step(agents)
    return [out[str(i)] for i in range(len(positions))]
