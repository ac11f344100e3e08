"""Which settled units move where this step: the planner around reserved squares, and following.

Pure. The planner never produces a swap, a vertex conflict or a rotation, so the only way into an
occupied square is following a unit that leaves it. That square is never released in the same
step (units keep their own clocks, so "it leaves as I enter" is a collision when it is late,
protocol.md §4.4): the follower keeps it as planned and gets it once the leader's state shows it
has gone, or is re-planned after FOLLOW_PATIENCE steps.
"""

from __future__ import annotations

from collections.abc import Callable
from collections.abc import Set as AbstractSet
from dataclasses import dataclass

from gridfleet.coordinator.planning.planner import AgentSpec, Planner
from gridfleet.coordinator.world import UnitRecord
from gridfleet.grid import Cell

FOLLOW_PATIENCE = 3  # coordinator steps a follower waits for its leader to leave before re-planning


@dataclass
class Follow:
    """A square a unit was planned into while another unit still stood on it."""

    square: Cell
    steps: int = 0  # steps it has waited for the square to empty


class Moves:
    """One planning step for the fleet; remembers who follows whom between steps."""

    def __init__(self, planner: Planner) -> None:
        self.planner = planner
        self.following: dict[str, Follow] = {}

    def plan(
        self,
        units: list[UnitRecord],
        movable: set[str],
        reserved: Callable[[UnitRecord], set[Cell]],
        targets: dict[str, Cell | None],
        urgency: dict[str, float],
        driving: AbstractSet[str] = frozenset(),
        elsewhere: AbstractSet[Cell] = frozenset(),
        keep_clear: AbstractSet[Cell] = frozenset(),
    ) -> dict[str, Cell]:
        """The next square of each unit that moves; `reserved(u)` are squares `u` may still drive.

        `driving`: units that may not move this step only because they are still driving (or
        have yet to acknowledge) what they were given; they keep their targets, and so their
        priorities. `elsewhere`: squares of units planned elsewhere (leaving a closed zone, zones.py),
        entered by nobody here; `keep_clear`: squares such a unit waits for (an idle unit on one
        makes way).
        """
        agents: dict[str, AgentSpec] = {}
        blocked: set[Cell] = set(elsewhere)
        seen: set[Cell] = set()
        waiting: dict[str, Cell] = {}
        released_to_others: set[Cell] = set()  # squares units may still drive into
        for u in units:
            assert u.state is not None
            pos = u.state.position
            if pos in seen or not self.planner.grid.is_free(pos):
                return {}  # inconsistent snapshot (states in flight): halt everyone this step
            seen.add(pos)
            held = reserved(u) - {pos}
            blocked |= held
            released_to_others |= held
            follow = self.following.get(u.id)
            if (
                follow is not None
                and u.id in movable
                and follow.steps < FOLLOW_PATIENCE
                and follow.square not in elsewhere
                and self.planner.grid.is_free(follow.square)  # not closed since (zones.py)
            ):
                # It keeps its planned square (nobody else may take it) and waits for it to empty.
                waiting[u.id] = follow.square
                blocked.add(follow.square)
                follow.steps += 1
                # Frozen for this step, but with its target, so it keeps its priority.
                agents[u.id] = AgentSpec(pos, targets[u.id], frozen=True)
                continue
            self.following.pop(u.id, None)
            still = u.id not in movable
            # Without its target an agent counts as arrived and its priority starts again at 0;
            # a unit still driving at a step would lose its priority to whoever it meets, and
            # two units meeting head-on took turns pushing each other back (bench/README.md).
            keeps = not still or u.id in driving
            agents[u.id] = AgentSpec(pos, targets[u.id] if keeps else None, frozen=still)
        # A reserved square may hold another unit (a follower waits for it to leave): that unit
        # may stay or leave, but nobody else may be released into it.
        moves = self.planner.step(agents, reserved=blocked, urgency=urgency, keep_clear=keep_clear)
        out: dict[str, Cell] = {}
        for uid, nxt in moves.items():
            if nxt == agents[uid].position:
                continue
            if nxt in seen:
                self.following[uid] = Follow(nxt)
            else:
                out[uid] = nxt
        for uid, square in waiting.items():
            if square not in seen and square not in released_to_others | elsewhere:
                out[uid] = square
                del self.following[uid]
        return out
