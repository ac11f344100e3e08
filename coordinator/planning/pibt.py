"""One step of PIBT: priority inheritance with backtracking (Okumura et al. 2019; cf. pypibt).

Every agent, most urgent first, takes its best square not yet taken and pushes along whoever
stands there (priority inheritance); a pushed agent that cannot move sends its pusher on to its
next choice (backtracking). Two rules on top of plain PIBT: an agent may follow one that leaves
its square but never closes a cycle of such moves (a *rotation*: asynchronous units would each
wait for the next), and two agents that must pass in a corridor swap places
(`coordinator.planning.pibt_swap`).

Squares are flat indices (y * width + x); agents are indices into the step's lists.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from operator import itemgetter

from gridfleet.coordinator.planning.pibt_swap import swap_partner
from gridfleet.grid import GridMap

Index = int  # a square as a flat index: y * width + x
NONE = -1  # no square: an agent not planned yet, an agent without a target
RESERVED = NONE - 1  # the holder of a reserved square: nobody may enter it
_KEY = itemgetter(0)  # sort (key, square) pairs by key alone: equal keys keep their order


def neighbour_table(grid: GridMap) -> list[tuple[Index, ...]]:
    """The free neighbours of every square (N, E, S, W; none for a blocked square)."""
    w, h = grid.width, grid.height
    free = ~grid.blocked.reshape(-1)
    table: list[tuple[Index, ...]] = []
    for idx in range(w * h):
        if not free[idx]:
            table.append(())
            continue
        x, y = idx % w, idx // w
        out = []
        for nx, ny in ((x, y - 1), (x + 1, y), (x, y + 1), (x - 1, y)):
            if 0 <= nx < w and 0 <= ny < h and free[ny * w + nx]:
                out.append(ny * w + nx)
        table.append(tuple(out))
    return table


class PIBT:
    """The search of one step: where every agent stands and, so far, where it goes."""

    def __init__(
        self,
        nbrs: Sequence[tuple[Index, ...]],
        pos: list[Index],
        goal: list[Index],
        fields: Sequence[Sequence[int] | None],
        settled: list[bool],
        rand: Callable[[], float],
    ) -> None:
        self.nbrs = nbrs
        self.pos = pos
        self.goal = goal  # target square, or NONE
        self.fields = fields  # flat distance field towards the target (plain ints), or None
        self.settled = settled  # no target, or already on it
        self.rand = rand  # the last tie-breaker: the planner's seeded stream
        self.occupant: dict[Index, int] = {p: i for i, p in enumerate(pos)}
        if len(self.occupant) != len(pos):
            raise ValueError("two agents stand on one square")
        self.nxt = [NONE] * len(pos)
        self.taken: dict[Index, int] = {}  # square -> the agent entering it (or RESERVED)

    def reserve(self, square: Index) -> None:
        """Nobody enters `square` this step."""
        self.taken[square] = RESERVED

    def freeze(self, i: int) -> None:
        """Agent `i` stays where it is this step."""
        self.nxt[i] = self.pos[i]
        self.taken[self.pos[i]] = i

    def run(self, order: Sequence[int]) -> list[Index]:
        """Next square of every agent, planning them in `order` (most urgent first)."""
        nxt = self.nxt
        for i in order:
            if nxt[i] == NONE:
                self.push(i)
        return [n if n != NONE else p for n, p in zip(nxt, self.pos, strict=True)]

    def planned(self, i: int) -> bool:
        """Has agent `i` got its square for this step?"""
        return self.nxt[i] != NONE

    def dist(self, i: int, square: Index) -> int:
        """Steps from `square` to agent `i`'s target (0 for an agent without one)."""
        f = self.fields[i]
        return 0 if f is None else f[square]

    def push(self, i: int, pusher: int | None = None) -> bool:
        """Move `i` to its best square still open, pushing its occupant along; False: it stays."""
        here = self.pos[i]
        ranked, partner = self._choices(i, pusher)
        pos, nxt, taken, occupant = self.pos, self.nxt, self.taken, self.occupant
        for rank, c in enumerate(ranked):
            if c in taken:
                continue
            if c == here:
                nxt[i] = here
                taken[here] = i
                return True
            k = occupant.get(c)
            if k is not None and nxt[k] != NONE:
                # Following a planned unit: only when it leaves and no cycle closes.
                if nxt[k] == pos[k] or self.closes_cycle(i, c):
                    continue
                nxt[i] = c
                taken[c] = i
                return True
            nxt[i] = c
            taken[c] = i
            if k is not None and not self.push(k, i):
                continue  # the pushed unit could not move: it stays and holds its square
            if rank == 0 and partner is not None and nxt[partner] == NONE and here not in taken:
                nxt[partner] = here  # the partner follows into the square we leave
                taken[here] = partner
            return True
        nxt[i] = here
        taken[here] = i
        return False

    def _choices(self, i: int, pusher: int | None) -> tuple[list[Index], int | None]:
        """`i`'s squares, best first, and the agent it swaps places with (if any)."""
        here = self.pos[i]
        dist, crowding, rand = self.dist, self.crowding, self.rand  # bound once: a hot loop
        cands = [*self.nbrs[here], here]
        d = [dist(i, c) for c in cands]
        # Ties: a free square first, then one whose unit is still on its way, and only then
        # push a unit off its target (pushing settled units invites livelock); then staying
        # put, then the square farthest from the pusher's way (a side square, not the
        # corridor it is coming down).
        keys = [
            (dc, crowding(i, c), c != here, 0 if pusher is None else -dist(pusher, c), rand())
            for c, dc in zip(cands, d, strict=True)
        ]
        ranked = [c for _, c in sorted(zip(keys, cands, strict=True), key=_KEY)]
        # Swap emulation: when two units must pass each other in a corridor, the one in
        # front backs off (worst square first, a side square off the partner's way before
        # the corridor) and pulls the other along behind it.
        partner = swap_partner(self, i, ranked[0])
        if partner is not None:
            back = [(-dc, -dist(partner, c), rand()) for c, dc in zip(cands, d, strict=True)]
            ranked = [c for _, c in sorted(zip(back, cands, strict=True), key=_KEY)]
        return ranked, partner

    def crowding(self, i: int, square: Index) -> int:
        """0: free (or `i`'s own), 1: a unit on its way stands there, 2: a unit on its target."""
        k = self.occupant.get(square)
        if k is None or k == i:
            return 0  # its own square is not crowded: an idle unit stays unless pushed
        return 2 if self.settled[k] else 1

    def closes_cycle(self, i: int, square: Index) -> bool:
        """Would `i` entering `square` close a chain of units entering each other's squares?"""
        nxt, pos, occupant = self.nxt, self.pos, self.occupant
        k = occupant.get(square)
        seen = 0
        while k is not None and seen <= len(pos):
            if k == i:
                return True
            if nxt[k] == NONE or nxt[k] == pos[k]:
                return False
            k = occupant.get(nxt[k])
            seen += 1
        return False
