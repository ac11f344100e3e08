"""Traffic-flow guidance: each unit follows a guide path chosen around the others' traffic.

With plain distance fields every unit takes a shortest route, so on a busy map they crowd the
same squares and meet head on, and PIBT spends its steps pushing units back. Here a unit given a
new target gets a guide path that is short but avoids squares many other guide paths cross and,
above all, edges they take the other way (after Chen et al., "Traffic Flow Optimisation for
Lifelong Multi-Agent Path Finding", AAAI 2024, simplified). PIBT then descends the unit's own
field: for any square, the steps to the nearest square of its guide path plus the path's
remaining length there, so a unit pushed aside comes back to its path rather than cutting across
everyone else's. A guide path's traffic counts only the part still ahead of its unit, and a few
guide paths are made anew every step, so that none follows the traffic of long ago.

Pure: the neighbour table and the distance fields (as A* heuristic) in; per-unit fields out. Each
field is a list the size of the map, so guidance is for maps of up to `MAX_SQUARES` squares.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from gridfleet.coordinator.planning.pibt import Index

CONTRAFLOW = 1.0  # extra cost of an edge per guide path taking it the other way
CROSSING = 0.1  # extra cost of entering a square per guide path entering it too
RENEWED = 0.02  # share of guide paths made anew every step, round the fleet, for today's traffic
WORK_PER_STEP = 65_536  # squares a step may search for new guide paths (64 on a 32 x 32 map):
# a whole fleet given targets at once gets its guide paths over a few steps, not in one long one
MAX_SQUARES = 4096  # larger maps use the shared distance fields (a field per unit is too much)
FAR = 1 << 30  # not reachable


@dataclass
class _Guide:
    """One unit's guide path and how far along it the unit has come."""

    target: Index
    path: list[Index]
    index: dict[Index, int]  # square -> its (last) place on the path
    field: list[int]  # what PIBT descends (`Guidance._descent`)
    at: int = 0


class Guidance:
    """Guide paths and their traffic for a fleet on one grid; kept by the planner between steps."""

    def __init__(
        self, nbrs: Sequence[tuple[Index, ...]], distance_to: Callable[[Index], Sequence[int]]
    ) -> None:
        self.nbrs = nbrs
        self.distance_to = distance_to  # the plain distance field towards a square (A*'s guide)
        self._guides: dict[str, _Guide] = {}
        self._edges: dict[tuple[Index, Index], int] = {}  # guide paths taking each edge, ahead
        self._entries: dict[Index, int] = {}  # guide paths entering each square, ahead
        self._turn = 0  # where `renew` goes on from
        self._left = 0  # new guide paths still to be made this step
        self.begin_step()

    def begin_step(self) -> None:
        """A new step: new guide paths may be made again, up to this step's share."""
        self._left = max(4, WORK_PER_STEP // max(1, len(self.nbrs)))

    def field(self, unit: str, here: Index, target: Index) -> list[int] | None:
        """The field `unit` descends from `here` towards `target` (a new guide path if new), or
        None when this step's new guide paths are all made: then the plain field, this step."""
        guide = self._guides.get(unit)
        if guide is not None and guide.target == target:
            self._advance(guide, here)
            return guide.field
        self.forget(unit)
        if self._left <= 0:
            return None
        self._left -= 1
        path = self._path(here, target)
        self._count(path, 0, +1)
        guide = _Guide(target, path, {s: k for k, s in enumerate(path)}, self._descent(path))
        self._guides[unit] = guide
        return guide.field

    def renew(self, units: Sequence[str]) -> None:
        """Forget the guide paths of the next few `units` in turn: each gets a new one at its next
        step, around the traffic as it is then (the others' paths have changed since)."""
        if not units:
            return
        count = max(1, int(len(units) * RENEWED))
        for k in range(self._turn, self._turn + count):
            self.forget(units[k % len(units)])
        self._turn = (self._turn + count) % len(units)

    def forget(self, unit: str) -> None:
        """`unit` has no target now (or is gone): its path's traffic no longer counts."""
        guide = self._guides.pop(unit, None)
        if guide is not None:
            self._count(guide.path, guide.at, -1)

    def keep_only(self, units: set[str]) -> None:
        """Forget every unit not in `units`."""
        for unit in [u for u in self._guides if u not in units]:
            self.forget(unit)

    def guide(self, unit: str) -> list[Index]:
        """The rest of `unit`'s guide path after the square it last stood on (empty: none)."""
        guide = self._guides.get(unit)
        return [] if guide is None else guide.path[guide.at + 1 :]

    def ahead(self, unit: str, square: Index, target: Index) -> list[Index] | None:
        """`unit`'s guide path after `square` when it is guided to `target` through it, else None."""
        guide = self._guides.get(unit)
        if guide is None or guide.target != target or square not in guide.index:
            return None
        return guide.path[guide.index[square] + 1 :]

    def traffic(self, square: Index, onward: Index) -> int:
        """Guide paths still to take the edge `square` → `onward` (for tests and display)."""
        return self._edges.get((square, onward), 0)

    def _advance(self, guide: _Guide, here: Index) -> None:
        # The traffic behind a unit is gone: count only what is ahead of it.
        at = guide.index.get(here)
        if at is not None and at > guide.at:
            self._count(guide.path, guide.at, -1, end=at)
            guide.at = at

    def _count(self, path: list[Index], start: int, delta: int, end: int | None = None) -> None:
        edges, entries = self._edges, self._entries
        for k in range(start, (len(path) - 1) if end is None else end):
            edge = (path[k], path[k + 1])
            edges[edge] = edges.get(edge, 0) + delta
            entries[path[k + 1]] = entries.get(path[k + 1], 0) + delta

    def _path(self, start: Index, target: Index) -> list[Index]:
        """The cheapest path under the traffic costs (A* on the plain distance)."""
        h = self.distance_to(target)
        if h[start] >= FAR:
            return [start]  # cut off: no guide, the unit stays until the map changes
        edges, entries, nbrs = self._edges, self._entries, self.nbrs
        cost: dict[Index, float] = {start: 0.0}
        came: dict[Index, Index] = {}
        heap = [(float(h[start]), 0.0, start)]
        while heap:
            _, g, u = heapq.heappop(heap)
            if u == target:
                break
            if g > cost[u]:
                continue
            for v in nbrs[u]:
                step = 1.0 + CONTRAFLOW * edges.get((v, u), 0) + CROSSING * entries.get(v, 0)
                if g + step < cost.get(v, FAR):
                    cost[v] = g + step
                    came[v] = u
                    heapq.heappush(heap, (g + step + h[v], g + step, v))
        path = [target]
        while path[-1] != start:
            path.append(came[path[-1]])
        return path[::-1]

    def _descent(self, path: list[Index]) -> list[int]:
        """Per square: steps to the nearest square of `path`, plus the path's length from there.

        Of equally near path squares, the one nearest the target counts."""
        nbrs = self.nbrs
        last = len(path) - 1
        steps = [FAR] * len(nbrs)
        rest = [0] * len(nbrs)
        for k, square in enumerate(path):
            steps[square], rest[square] = 0, last - k  # a square met twice: its later place
        frontier = list(dict.fromkeys(path))
        depth = 0
        while frontier:
            depth += 1
            ahead = []
            for u in frontier:
                for v in nbrs[u]:
                    if steps[v] == FAR:
                        steps[v], rest[v] = depth, rest[u]
                        ahead.append(v)
                    elif steps[v] == depth and rest[u] < rest[v]:
                        rest[v] = rest[u]
            frontier = ahead
        return [s + r if s < FAR else FAR for s, r in zip(steps, rest, strict=True)]
