"""Who may clear an obstacle from the coordinator's map: a unit only its own word, never a wall."""

from __future__ import annotations

from gridfleet.coordinator.world import World
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import HeaderStamper, Leds, Sensors, UnitState

ROWS = ["....", ".@..", "...."]  # [1, 1] is a fixed obstacle of the map


def state(unit: str, position: Cell, step: int = 1, **sensors: str) -> UnitState:
    return UnitState(
        header=HeaderStamper(unit)("state"),
        step=step,
        position=position,
        direction="-",
        status="idle",
        leds=Leds(),
        sensors=Sensors(**{"N": "free", "E": "free", "S": "free", "W": "free", **sensors}),  # type: ignore[arg-type]
        obstacles=[],
    )


def test_another_units_free_reading_does_not_erase_an_obstacle_a_unit_sees() -> None:
    # As found: unit b's sensor reading `free` towards [2, 1], which unit a sees, erased it.
    world = World(GridMap.from_rows(ROWS))
    assert world.on_state("a", state("a", Cell(2, 0), S="obstacle"), 0.0) == [Cell(2, 1)]
    assert world.on_state("b", state("b", Cell(2, 2), N="free"), 0.0) == []
    assert Cell(2, 1) in world.obstacles and not world.grid.is_free(Cell(2, 1))
    # b sees it too, then a no longer does: b's word still holds it.
    assert world.on_state("b", state("b", Cell(2, 2), step=2, N="obstacle"), 1.0) == []
    assert world.on_state("a", state("a", Cell(2, 0), step=2, S="free"), 1.0) == []
    assert Cell(2, 1) in world.obstacles
    # Once no unit that saw it still does, it is gone: each took back its own word.
    assert world.on_state("b", state("b", Cell(2, 2), step=3, N="free"), 2.0) == [Cell(2, 1)]
    assert world.obstacles == set() and world.grid.is_free(Cell(2, 1))


def test_a_unit_takes_back_its_own_word_and_an_operator_clears_anyones() -> None:
    world = World(GridMap.from_rows(ROWS))
    world.on_state("a", state("a", Cell(2, 0), S="obstacle"), 0.0)
    assert world.on_state("a", state("a", Cell(2, 0), step=2, S="free"), 1.0) == [Cell(2, 1)]
    world.on_state("a", state("a", Cell(2, 0), step=3, S="obstacle"), 2.0)
    assert world.clear_obstacles([Cell(2, 1)]) == [Cell(2, 1)]  # protocol.md §6.6
    assert world.grid.is_free(Cell(2, 1))
    # Cleared by an operator, what a unit saw before counts no more: b's `free` was never needed.
    world.on_state("b", state("b", Cell(2, 2), S="wall"), 3.0)
    assert world.obstacles == set()


def test_no_free_reading_unblocks_a_fixed_obstacle_of_the_map() -> None:
    world = World(GridMap.from_rows(ROWS))
    world.on_state("a", state("a", Cell(1, 0), S="free"), 0.0)  # [1, 1] is `@` on the map
    world.on_state("b", state("b", Cell(1, 2), N="free"), 0.0)
    assert not world.grid.is_free(Cell(1, 1)) and world.obstacles == set()
