"""PIBT-family multi-unit planner: one collision-free, rotation-free step for every unit.

Pure: a grid, current squares, targets and priorities in; next squares out. Distance fields
(BFS, cached per target) from `gridfleet.paths` are the heuristic. Priority inheritance with
backtracking (PIBT, Okumura et al. 2019) lets a high-priority unit push lower ones out of its way.

Units run asynchronously (each enters a released square only when its own sensor sees it free),
so besides vertex conflicts and swaps the planner never produces a *rotation*: a closed cycle of
units each entering the square another vacates would wait on itself forever. Following a unit that
moves away is fine. Priorities grow every step a unit has not reached its target and reset on
arrival, so every unit eventually becomes the most urgent one and gets through.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from gridfleet.grid import Cell, GridMap
from gridfleet.paths import UNREACHABLE, DistanceFieldCache

_NONE = -1


@dataclass(frozen=True)
class AgentSpec:
    """One unit as the planner sees it: where it is, where it wants to go, whether it may move."""

    position: Cell
    target: Cell | None = None  # None: no errand; it stays unless pushed
    frozen: bool = False  # may not move this step (in motion, unacknowledged, lost, stopped)


class Planner:
    """Plans one step at a time for a fleet on one grid; keeps priorities between steps."""

    def __init__(self, grid: GridMap, seed: int = 0, cache_size: int = 4096) -> None:
        self._rng = np.random.default_rng(seed)
        self._cache_size = cache_size
        self._priority: dict[str, float] = {}
        self._tiebreak: dict[str, float] = {}
        self.set_grid(grid)

    @property
    def grid(self) -> GridMap:
        """The grid plans are made on (static map plus known obstacles)."""
        return self._grid

    def set_grid(self, grid: GridMap) -> None:
        """Re-plan on a new grid (e.g. after an obstacle was reported); drops cached fields."""
        self._grid = grid
        self.cache = DistanceFieldCache(grid, size=self._cache_size)
        w, h = grid.width, grid.height
        free = ~grid.blocked.reshape(-1)
        self._free = free
        nbrs: list[tuple[int, ...]] = []
        for idx in range(w * h):
            if not free[idx]:
                nbrs.append(())
                continue
            x, y = idx % w, idx // w
            out = []
            for nx, ny in ((x, y - 1), (x + 1, y), (x, y + 1), (x - 1, y)):
                if 0 <= nx < w and 0 <= ny < h and free[ny * w + nx]:
                    out.append(ny * w + nx)
            nbrs.append(tuple(out))
        self._nbrs = nbrs

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
    ) -> dict[str, Cell]:
        """Next square of every agent; `reserved` squares are entered by nobody this step.

        `urgency` adds to an agent's priority (e.g. job priority). Priorities are updated here:
        +1 for each agent with a target it has not reached, reset to 0 on arrival.
        """
        names = list(agents)
        w = self._grid.width
        n = len(names)
        pos = [agents[a].position.y * w + agents[a].position.x for a in names]
        for a, p in zip(names, pos, strict=True):
            if not self._free[p]:
                raise ValueError(f"agent {a} stands on a blocked square {agents[a].position}")
        fields: list[np.ndarray | None] = []
        for a in names:
            t = agents[a].target
            fields.append(None if t is None else self.cache.get(t).reshape(-1))
        # Priorities: elapsed time since last arrival plus a random tie-breaker in [0, 1).
        # The tie-breaker is fixed per agent: re-drawing it every step lets equal agents take
        # turns pushing each other back and forth forever.
        for a in names:
            if a not in self._tiebreak:
                self._tiebreak[a] = float(self._rng.random())
        jitter = [self._tiebreak[a] for a in names]
        prio = []
        for i, a in enumerate(names):
            spec = agents[a]
            base = self._priority.get(a, 0.0)
            at_goal = spec.target is None or spec.target == spec.position
            base = 0.0 if at_goal else base
            self._priority[a] = base
            extra = (urgency or {}).get(a, 0.0)
            # Units already at their target come last but can still be pushed.
            prio.append((-1.0 if at_goal else base) + extra + float(jitter[i]))
        settled = [
            agents[a].target is None or agents[a].target == agents[a].position for a in names
        ]
        occupant: dict[int, int] = {p: i for i, p in enumerate(pos)}
        goal_cell = [
            _NONE if agents[a].target is None else agents[a].target.y * w + agents[a].target.x  # type: ignore[union-attr]
            for a in names
        ]
        if len(occupant) != n:
            raise ValueError("two agents stand on one square")
        nxt = [_NONE] * n
        taken: dict[int, int] = {}
        for c in reserved:
            if self._grid.in_bounds(c):
                taken[c.y * w + c.x] = _NONE - 1
        for i, a in enumerate(names):
            if agents[a].frozen:
                nxt[i] = pos[i]
                taken[pos[i]] = i
        order = sorted(range(n), key=lambda i: -prio[i])
        rand = self._rng.random

        def dist(i: int, cell: int) -> int:
            f = fields[i]
            return 0 if f is None else int(f[cell])

        def closes_cycle(i: int, cell: int) -> bool:
            # Follow "k moves into the square of occupant(next[k])" from cell's occupant.
            k = occupant.get(cell)
            seen = 0
            while k is not None and seen <= n:
                if k == i:
                    return True
                if nxt[k] == _NONE or nxt[k] == pos[k]:
                    return False
                k = occupant.get(nxt[k])
                seen += 1
            return False

        def _crowding(i: int, cell: int) -> int:
            k = occupant.get(cell)
            if k is None or k == i:
                return 0  # its own square is not crowded: an idle unit stays unless pushed
            return 2 if settled[k] else 1

        def corridor_ahead(v_back: int, v_front: int) -> tuple[int, int, int]:
            # Step once along a corridor from v_front away from v_back; returns (open sides
            # besides v_back, the next square, v_front). Dead-end squares held by a unit that
            # sits on its own target count as closed: that unit need not move.
            n_open = 0
            nxt_cell = _NONE
            for u in self._nbrs[v_front]:
                k = occupant.get(u)
                if u == v_back or (len(self._nbrs[u]) == 1 and k is not None and goal_cell[k] == u):
                    continue
                n_open += 1
                nxt_cell = u
            return n_open, nxt_cell, v_front

        def swap_required(pusher: int, puller: int, v_pusher: int, v_puller: int) -> bool:
            # Would pushing `puller` ahead of `pusher` only drive it down a corridor with no room
            # to step aside? Then the two can pass only if the pusher backs off instead.
            guard = 0
            while dist(pusher, v_puller) < dist(pusher, v_pusher) and guard < len(self._nbrs):
                guard += 1
                n_open, nxt_cell, _ = corridor_ahead(v_pusher, v_puller)
                if n_open >= 2:
                    return False
                if n_open == 0:
                    break
                v_pusher, v_puller = v_puller, nxt_cell
            return dist(puller, v_pusher) < dist(puller, v_puller) and (
                dist(pusher, v_pusher) == 0 or dist(pusher, v_puller) < dist(pusher, v_pusher)
            )

        def swap_possible(v_pusher: int, v_puller: int) -> bool:
            # Is there a side square somewhere behind, so that backing off lets the two pass?
            start = v_pusher
            guard = 0
            while v_puller != start and guard < len(self._nbrs):
                guard += 1
                n_open, nxt_cell, _ = corridor_ahead(v_pusher, v_puller)
                if n_open >= 2:
                    return True
                if n_open == 0:
                    return False
                v_pusher, v_puller = v_puller, nxt_cell
            return False

        def swap_partner(i: int, best: int) -> int | None:
            here = pos[i]
            if best == here:
                return None
            j = occupant.get(best)
            if (
                j is not None
                and nxt[j] == _NONE
                and swap_required(i, j, here, best)
                and swap_possible(best, here)
            ):
                return j
            for u in self._nbrs[here]:
                k = occupant.get(u)
                if k is None or u == best or nxt[k] != _NONE:
                    continue
                if swap_required(k, i, here, best) and swap_possible(best, here):
                    return k
            return None

        def pibt(i: int, pusher: int | None = None) -> bool:
            here = pos[i]
            cands = [*self._nbrs[here], here]
            d_here = [dist(i, c) for c in cands]
            # Ties: a free square first, then one whose unit is still on its way, and only then
            # push a unit off its target (pushing settled units invites livelock); then staying
            # put, then the square farthest from the pusher's way (a side square, not the
            # corridor it is coming down).
            keys = [
                (d, _crowding(i, c), c != here, 0 if pusher is None else -dist(pusher, c), rand())
                for c, d in zip(cands, d_here, strict=True)
            ]
            ranked = [c for _, c in sorted(zip(keys, cands, strict=True), key=lambda kc: kc[0])]
            # Swap emulation: when two units must pass each other in a corridor, the one in
            # front backs off (worst square first, a side square off the partner's way before
            # the corridor) and pulls the other along behind it.
            partner = swap_partner(i, ranked[0])
            if partner is not None:
                back = [(-d, -dist(partner, c), rand()) for c, d in zip(cands, d_here, strict=True)]
                ranked = [c for _, c in sorted(zip(back, cands, strict=True), key=lambda kc: kc[0])]
            for rank, c in enumerate(ranked):
                if c in taken:
                    continue
                if c == here:
                    nxt[i] = here
                    taken[here] = i
                    return True
                k = occupant.get(c)
                if k is not None and nxt[k] != _NONE:
                    # Following a planned unit: only when it leaves and no cycle closes.
                    if nxt[k] == pos[k] or closes_cycle(i, c):
                        continue
                    nxt[i] = c
                    taken[c] = i
                    return True
                nxt[i] = c
                taken[c] = i
                if k is not None and not pibt(k, i):
                    continue  # the pushed unit could not move: it stays and holds its square
                if (
                    rank == 0
                    and partner is not None
                    and nxt[partner] == _NONE
                    and here not in taken
                ):
                    nxt[partner] = here  # the partner follows into the square we leave
                    taken[here] = partner
                return True
            nxt[i] = here
            taken[here] = i
            return False

        for i in order:
            if nxt[i] == _NONE:
                pibt(i)

        result: dict[str, Cell] = {}
        for i, a in enumerate(names):
            flat = nxt[i] if nxt[i] != _NONE else pos[i]
            result[a] = Cell(flat % w, flat // w)
        for a in names:
            spec = agents[a]
            if spec.target is not None and spec.target != spec.position:
                self._priority[a] = self._priority.get(a, 0.0) + 1.0
        return result

    def route(self, start: Cell, target: Cell, limit: int = 256) -> list[Cell]:
        """The shortest path after `start` to `target` (empty when unreachable), for display."""
        field = self.cache.get(target)
        d = int(field[start.y, start.x]) if self._grid.in_bounds(start) else UNREACHABLE
        out: list[Cell] = []
        here = start
        while 0 < d < UNREACHABLE and len(out) < limit:
            here = next(c for c in here.neighbours() if _at(field, c) == d - 1)
            out.append(here)
            d -= 1
        return out


def _at(field: np.ndarray, cell: Cell) -> int:
    h, w = field.shape
    return int(field[cell.y, cell.x]) if 0 <= cell.x < w and 0 <= cell.y < h else UNREACHABLE


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
