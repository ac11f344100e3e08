"""The plan validator catches one hand-made bad plan of every kind, and passes a good one."""

from __future__ import annotations

import pytest

from gridfleet.coordinator.planning.validate import validate_plan, validate_step, validate_windows
from gridfleet.grid import Cell, GridMap

GRID = GridMap.from_rows(["....", ".@..", "....", "...."])


def C(x: int, y: int) -> Cell:
    return Cell(x, y)


def kinds(plan: list[list[Cell]]) -> set[str]:
    return {v.kind for v in validate_plan(GRID, plan)}


def test_a_good_plan_is_clean() -> None:
    # B follows A along the top row: following a unit that moves away is fine.
    plan = [[C(1, 0), C(0, 0)], [C(2, 0), C(1, 0)], [C(3, 0), C(2, 0)]]
    assert validate_plan(GRID, plan) == []


@pytest.mark.parametrize(
    ("plan", "kind"),
    [
        ([[C(0, 0)], [C(2, 0)]], "continuity"),  # jumps two squares
        ([[C(0, 0)], [C(1, 1)]], "continuity"),  # diagonal
        ([[C(0, 1)], [C(1, 1)]], "wall"),  # into the wall
        ([[C(4, 0)]], "wall"),  # off the map
        ([[C(0, 0), C(2, 0)], [C(1, 0), C(1, 0)]], "vertex"),  # two on one square
        ([[C(0, 0), C(1, 0)], [C(1, 0), C(0, 0)]], "swap"),  # head-on swap
        # a rotation of four units round the 2 x 2 block at the bottom left
        (
            [[C(0, 2), C(1, 2), C(1, 3), C(0, 3)], [C(1, 2), C(1, 3), C(0, 3), C(0, 2)]],
            "rotation",
        ),
    ],
)
def test_each_failure_type_is_caught(plan: list[list[Cell]], kind: str) -> None:
    assert kind in kinds(plan)


def test_rotation_of_three_on_a_ring() -> None:
    ring = GridMap.from_rows(["...", ".@.", "..."])
    before = [C(0, 0), C(1, 0), C(2, 0), C(2, 1), C(2, 2), C(1, 2), C(0, 2), C(0, 1)]
    after = before[1:] + before[:1]  # everyone one square clockwise: an 8-cycle
    found = validate_step(ring, before, after)
    assert [v.kind for v in found] == ["rotation"]
    assert found[0].agents == tuple(range(8))


def test_agent_count_change_is_reported() -> None:
    assert validate_step(GRID, [C(0, 0)], [C(0, 0), C(1, 0)])[0].kind == "continuity"


def test_good_windows_are_clean() -> None:
    # A drives the top row, B follows one square behind its window, C waits with none.
    positions = [C(1, 0), C(0, 0), C(0, 3)]
    windows = [[C(2, 0), C(3, 0), C(3, 1)], [], []]
    assert validate_windows(GRID, positions, windows, bound=4) == []


@pytest.mark.parametrize(
    ("positions", "windows", "kind"),
    [
        ([C(0, 0)], [[C(2, 0)]], "continuity"),  # does not start next to its unit
        ([C(0, 0)], [[C(1, 0), C(2, 1)]], "continuity"),  # a gap inside the window
        ([C(0, 1)], [[C(1, 1)]], "wall"),  # onto the wall
        ([C(3, 0)], [[C(4, 0)]], "wall"),  # off the map
        ([C(0, 0), C(2, 0)], [[C(1, 0), C(2, 0)], []], "occupied"),  # onto a unit standing still
        ([C(0, 0), C(3, 0)], [[C(1, 0), C(2, 0)], [C(2, 0)]], "overlap"),  # both hold [2, 0]
        ([C(0, 0), C(1, 0)], [[C(1, 0)], [C(0, 0)]], "occupied"),  # a swap, as windows
        ([C(0, 3)], [[C(1, 3), C(2, 3), C(3, 3), C(3, 2), C(3, 1)]], "length"),
    ],
)
def test_each_window_failure_is_caught(
    positions: list[Cell], windows: list[list[Cell]], kind: str
) -> None:
    assert kind in {v.kind for v in validate_windows(GRID, positions, windows, bound=4)}
