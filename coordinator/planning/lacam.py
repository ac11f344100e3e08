"""Completeness for a fixed set of goals: LaCAM (Okumura, AAAI 2023) over the coordinator's PIBT.

PIBT alone can livelock: a few units short of their goals push each other back and forth while
everyone else waits on theirs. LaCAM searches the space of whole configurations depth first. The
successors of a configuration come from PIBT run under a constraint (these agents go to these
squares), taken from a tree of constraints grown one agent at a time as it is needed. So a
configuration PIBT keeps returning to is left another way next time, and the search is complete:
given time, it finds a way to the goals when there is one and says when there is none.

Pure: the neighbour table, starts, goals and distance fields in; configurations out. Every
configuration it returns follows the planner's rules (no two agents on a square, no swap, no
rotation: asynchronous units could not carry out a cycle of moves).
"""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from gridfleet.coordinator.planning.pibt import PIBT, Index

Config = tuple[Index, ...]  # one square per agent
Field = Sequence[int]  # flat distance field towards one agent's goal


@dataclass(frozen=True)
class _Constraint:
    """Agents `who[k]` must go to squares `where[k]` (a node of the low-level tree)."""

    who: tuple[int, ...] = ()
    where: tuple[Index, ...] = ()

    def child(self, i: int, square: Index) -> _Constraint:
        """This constraint and one more: agent `i` goes to `square`."""
        return _Constraint((*self.who, i), (*self.where, square))


@dataclass(eq=False)
class _Node:
    """A configuration reached, how it was reached, and the constraints still to try from it."""

    config: Config
    parent: _Node | None
    priority: list[float]
    order: list[int]  # agents, most urgent first: the order constraints are added in
    tree: deque[_Constraint] = field(default_factory=lambda: deque([_Constraint()]))


class NoSolution(Exception):
    """The goals cannot all be reached together (the whole search space was explored)."""


class LaCAM:
    """A search from `starts` to `goals` on the grid given by its neighbour table."""

    def __init__(
        self,
        nbrs: Sequence[tuple[Index, ...]],
        starts: Sequence[Index],
        goals: Sequence[Index],
        fields: Sequence[Field],
        seed: int = 0,
    ) -> None:
        if not len(starts) == len(goals) == len(fields):
            raise ValueError("starts, goals and fields must have one entry per agent")
        self.nbrs = nbrs
        self.starts: Config = tuple(starts)
        self.goals: Config = tuple(goals)
        self.fields = fields
        self._rng = random.Random(seed)
        self.nodes = 0  # configurations generated
        self.tries = 0  # successors asked of PIBT (the search's cost)
        # Farther agents first at the start; afterwards PIBT's rule: +1 while short of the goal.
        spread = max(1, max((fields[i][s] for i, s in enumerate(starts)), default=1))
        root = self._node(self.starts, None, [fields[i][s] / spread for i, s in enumerate(starts)])
        self._explored: dict[Config, _Node] = {root.config: root}
        self._stack = [root]

    def solve(self, expired: Callable[[], bool] = lambda: False) -> list[Config] | None:
        """Configurations from the starts to the goals, or None when `expired` said stop first;
        called again, the search goes on where it stopped.

        Raises NoSolution when the goals cannot be reached together."""
        n = len(self.starts)
        explored, stack = self._explored, self._stack
        while stack:
            if expired():
                return None
            node = stack[-1]
            if node.config == self.goals:
                return _backtrack(node)
            if not node.tree:
                stack.pop()
                continue
            constraint = node.tree.popleft()
            if len(constraint.who) < n:
                i = node.order[len(constraint.who)]
                here = node.config[i]
                squares = [here, *self.nbrs[here]]
                self._rng.shuffle(squares)
                node.tree.extend(constraint.child(i, s) for s in squares)
            self.tries += 1
            nxt = self._successor(node, constraint)
            if nxt is None:
                continue
            known = explored.get(nxt)
            if known is not None:
                stack.append(known)  # go on from there again: it usually leads somewhere new
                continue
            self.nodes += 1
            priority = [
                p + 1.0 if nxt[i] != self.goals[i] else p - int(p)
                for i, p in enumerate(node.priority)
            ]
            new = self._node(nxt, node, priority)
            explored[nxt] = new
            stack.append(new)
        raise NoSolution(f"no way for {n} agents to reach their goals together")

    def _node(self, config: Config, parent: _Node | None, priority: list[float]) -> _Node:
        order = sorted(range(len(config)), key=lambda i: -priority[i])
        return _Node(config, parent, priority, order)

    def _successor(self, node: _Node, constraint: _Constraint) -> Config | None:
        """PIBT's next configuration from `node` under `constraint`; None when there is none."""
        here = node.config
        settled = [h == g for h, g in zip(here, self.goals, strict=True)]
        search = PIBT(
            self.nbrs, list(here), list(self.goals), list(self.fields), settled, self._rng.random
        )
        for i, square in zip(constraint.who, constraint.where, strict=True):
            if square in search.taken or (square != here[i] and square not in self.nbrs[here[i]]):
                return None
            k = search.occupant.get(square)
            if k is not None and search.nxt[k] == here[i]:
                return None  # a swap
            search.nxt[i] = square
            search.taken[square] = i
        nxt = tuple(search.run(node.order))
        return nxt if is_valid_move(here, nxt) else None


def is_valid_move(before: Config, after: Config) -> bool:
    """No two agents on one square after, and no closed cycle of agents entering each other's
    squares (a swap is a cycle of two); adjacency is the caller's to keep."""
    if len(set(after)) != len(after):
        return False
    at = {square: i for i, square in enumerate(before)}
    state = [0] * len(before)  # 0 not seen, 1 on the chain being followed, 2 done
    for start in range(len(before)):
        chain = []
        i: int | None = start
        while i is not None and state[i] == 0:
            state[i] = 1
            chain.append(i)
            i = None if after[i] == before[i] else at.get(after[i])
        if i is not None and state[i] == 1:
            return False  # the chain came back to itself
        for j in chain:
            state[j] = 2
    return True


def _backtrack(node: _Node) -> list[Config]:
    out = []
    at: _Node | None = node
    while at is not None:
        out.append(at.config)
        at = at.parent
    return out[::-1]
