"""One-way lanes: aisles alternate, every move is cheap one way, units follow the lanes."""

from __future__ import annotations

import random

import numpy as np
import pytest

from gridfleet.coordinator.planning.flow import AGAINST_COST, WITH_COST, lane_costs, lane_directions
from gridfleet.coordinator.planning.planner import AgentSpec, Planner
from gridfleet.coordinator.planning.validate import validate_plan
from gridfleet.grid import Cell, GridMap
from gridfleet.paths import UNREACHABLE, DistanceFieldCache

# Shelves three wide, one-wide aisles between them and round them (columns 0, 4, 8; rows 0, 3, 6).
SHELF_ROWS = [
    ".........",
    ".@@@.@@@.",
    ".@@@.@@@.",
    ".........",
    ".@@@.@@@.",
    ".@@@.@@@.",
    ".........",
]
SHELVES = GridMap.from_rows(SHELF_ROWS)


def cost(grid: GridMap, here: Cell, there: Cell) -> int:
    """What the lanes charge for the move `here` → `there`."""
    w = grid.width
    return int(lane_costs(grid)[here.y * w + here.x, there.y * w + there.x])


def test_aisles_alternate_in_map_order_and_other_lanes_by_their_index() -> None:
    walled = np.zeros((6, 3), dtype=bool)
    walled[[1, 2, 4], 1] = True  # lanes 1, 2 and 4 are aisles
    assert lane_directions(walled).tolist() == [1, 1, -1, -1, 1, -1]


def test_the_aisles_of_a_shelf_block_run_in_turn_one_way_and_the_other() -> None:
    # Column aisles 0, 4, 8 run south, north, south; row aisles 0, 3, 6 east, west, east.
    assert cost(SHELVES, Cell(0, 1), Cell(0, 2)) == WITH_COST
    assert cost(SHELVES, Cell(4, 1), Cell(4, 2)) == AGAINST_COST
    assert cost(SHELVES, Cell(4, 2), Cell(4, 1)) == WITH_COST
    assert cost(SHELVES, Cell(8, 4), Cell(8, 5)) == WITH_COST
    assert cost(SHELVES, Cell(1, 3), Cell(2, 3)) == AGAINST_COST
    assert cost(SHELVES, Cell(2, 0), Cell(1, 0)) == AGAINST_COST
    assert cost(SHELVES, Cell(1, 6), Cell(2, 6)) == WITH_COST


def test_every_move_is_along_its_lane_one_way_and_against_it_the_other() -> None:
    rng = random.Random(3)
    grid = GridMap.from_rows(
        "".join("@" if rng.random() < 0.25 else "." for _ in range(17)) for _ in range(11)
    )
    costs = lane_costs(grid).tocoo()
    pairs = zip(costs.row.tolist(), costs.col.tolist(), strict=True)
    seen = dict(zip(pairs, costs.data.tolist(), strict=True))
    assert len(seen) > 100
    for (a, b), c in seen.items():
        assert {c, seen[(b, a)]} == {WITH_COST, AGAINST_COST}


def test_a_field_with_lanes_is_the_cheapest_way_and_keeps_every_square_reachable() -> None:
    plain = DistanceFieldCache(SHELVES).get(Cell(4, 3))
    lanes = DistanceFieldCache(SHELVES, costs=lane_costs(SHELVES)).get(Cell(4, 3))
    assert ((plain == UNREACHABLE) == (lanes == UNREACHABLE)).all()
    reachable = plain != UNREACHABLE
    assert (lanes[reachable] >= WITH_COST * plain[reachable]).all()
    assert (lanes[reachable] <= AGAINST_COST * plain[reachable]).all()
    # From (4, 2), one step up aisle 4 against its lane; from (4, 4), one along it.
    assert lanes[2, 4] == AGAINST_COST
    assert lanes[4, 4] == WITH_COST


def test_routes_follow_the_lanes_where_the_way_along_them_is_cheaper() -> None:
    planner = Planner(SHELVES, lanes=True)
    # Down aisle 0, which runs south: the shortest way is along it.
    assert planner.route(Cell(0, 0), Cell(0, 3)) == [Cell(0, 1), Cell(0, 2), Cell(0, 3)]
    # (4, 0) to (8, 3), 7 steps either way: east along row 0 and down aisle 8 (both along) rather
    # than down aisle 4 and east along row 3 (both against).
    way = planner.route(Cell(4, 0), Cell(8, 3))
    assert way == [
        Cell(5, 0),
        Cell(6, 0),
        Cell(7, 0),
        Cell(8, 0),
        Cell(8, 1),
        Cell(8, 2),
        Cell(8, 3),
    ]
    # Down aisle 4 (it runs north) when the way round is longer than the cost against it.
    assert planner.route(Cell(4, 3), Cell(4, 6)) == [Cell(4, 4), Cell(4, 5), Cell(4, 6)]


def test_a_unit_takes_the_other_row_when_its_own_runs_the_wrong_way() -> None:
    # Two rows: row 0 runs east, row 1 west. From (8, 0) to (0, 0) a unit goes down, along row 1
    # and up: 10 steps at a cost of 11, where 8 steps along row 0 against it cost 16.
    hall = GridMap.from_rows(["." * 9] * 2)
    way = Planner(hall, lanes=True).route(Cell(8, 0), Cell(0, 0))
    assert way[:8] == [Cell(x, 1) for x in range(8, 0, -1)]
    assert way[-1] == Cell(0, 0) and len(way) == 10
    assert len(Planner(hall, lanes=False).route(Cell(8, 0), Cell(0, 0))) == 8


def test_a_route_on_lanes_gets_cheaper_square_by_square_and_arrives() -> None:
    grid = GridMap.from_rows(["." * 90 if y % 4 else "." + "@" * 88 + "." for y in range(60)])
    planner = Planner(grid)  # above 4096 squares: lanes by default
    assert planner.lanes is not None
    free = [c for y in range(60) for x in range(90) if grid.is_free(c := Cell(x, y))]
    for start, target in zip(free[::97], free[::-89], strict=False):
        lane = planner.lanes.get(target)
        way = planner.route(start, target, 1000)
        assert way[-1:] == ([target] if start != target else [])
        for here, there in zip([start, *way], way, strict=False):
            assert here.manhattan(there) == 1 and grid.is_free(there)
            assert lane[there.y, there.x] < lane[here.y, here.x]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_busy_fleet_on_lanes_plans_cleanly_and_every_unit_arrives(seed: int) -> None:
    # The validator is the oracle: targets across three shelf blocks, every step clean.
    grid = GridMap.from_rows([row + row[1:] + row[1:] for row in SHELF_ROWS])
    cells = (Cell(x, y) for y in range(grid.height) for x in range(grid.width))
    free = [c for c in cells if grid.is_free(c)]
    rng = random.Random(seed)
    starts, goals = rng.sample(free, 14), rng.sample(free, 14)
    planner = Planner(grid, seed=seed, lanes=True)
    here = {str(i): s for i, s in enumerate(starts)}
    plan = [list(here.values())]
    for _ in range(400):
        pending = {a: goals[int(a)] for a in here if here[a] != goals[int(a)]}
        if not pending:
            break
        here = planner.step({a: AgentSpec(here[a], pending.get(a)) for a in here})
        plan.append(list(here.values()))
    assert validate_plan(grid, plan) == []
    assert all(here[a] == goals[int(a)] for a in here)


def test_lanes_are_on_for_large_maps_only_unless_asked() -> None:
    large = GridMap.from_rows(["." * 100] * 50)
    assert Planner(large).lanes is not None
    assert Planner(SHELVES).lanes is None
    assert Planner(SHELVES, lanes=True).lanes is not None
    assert Planner(large, lanes=False).lanes is None
