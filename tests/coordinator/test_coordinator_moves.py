"""Moves (coordinator/moves.py): a unit still driving at a step keeps its priority, so two units
meeting head-on in a corridor do not take turns pushing each other back (issue 32: with units
that settle at different steps, they did, for ever)."""

from __future__ import annotations

from gridfleet.coordinator.moves import Moves
from gridfleet.coordinator.planning.planner import Planner
from gridfleet.coordinator.world import UnitRecord
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import HeaderStamper
from gridfleet.robots.unit import UnitLogic

CORRIDOR = GridMap.from_rows(["......."])
TARGETS: dict[str, Cell | None] = {"east": Cell(6, 0), "west": Cell(0, 0)}


def record(unit: str, at: Cell) -> UnitRecord:
    """A unit heard standing on `at`, with nothing left to drive."""
    state = UnitLogic(unit, CORRIDOR, at, 10.0, 1.0).report(HeaderStamper(unit)("state"))
    return UnitRecord(unit, connection="online", state=state)


def step(moves: Moves, at: dict[str, Cell], driving: set[str]) -> dict[str, Cell]:
    """One planning step; the units in `driving` may not move (they still drive their squares)."""
    units = [record(u, c) for u, c in at.items()]
    movable = set(at) - driving
    return moves.plan(units, movable, lambda u: set(), TARGETS, {}, driving=driving)


def toward_target(unit: str, before: Cell, after: Cell) -> bool:
    target = TARGETS[unit]
    assert target is not None
    return after.manhattan(target) < before.manhattan(target)


def test_the_unit_that_won_a_head_on_meeting_keeps_winning_while_it_drives_between_steps() -> None:
    for seed in range(8):  # the tie-breakers decide who wins first: either way, it keeps winning
        moves = Moves(Planner(CORRIDOR, seed=seed))
        at = {"east": Cell(2, 0), "west": Cell(4, 0)}
        first = step(moves, at, driving=set())
        winner = next(u for u, c in first.items() if toward_target(u, at[u], c))
        loser = "west" if winner == "east" else "east"
        at = {**at, **first}
        # The winner drives the square it was given; at the next step only the other is settled,
        # and it is not let back into the square it was pushed out of.
        second = step(moves, at, driving={winner})
        assert not toward_target(loser, at[loser], second.get(loser, at[loser])), (seed, second)
        at = {**at, **second}
        # Both settled again: the winner still has the priority and pushes the other back (and
        # follows it); before, its priority had started again at 0 while it drove, and the other
        # pushed it back instead.
        third = step(moves, at, driving=set())
        assert loser in third and not toward_target(loser, at[loser], third[loser]), (seed, third)
        assert winner not in third or toward_target(winner, at[winner], third[winner])
