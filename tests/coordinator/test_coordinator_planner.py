"""Planner on ASCII grids: every plan validator-clean, every unit reaches its target in time."""

from __future__ import annotations

import pytest

from gridfleet.coordinator.planning.pibt import PIBT, neighbour_table
from gridfleet.coordinator.planning.pibt_swap import swap_partner
from gridfleet.coordinator.planning.planner import AgentSpec, Planner, plan_step
from gridfleet.coordinator.planning.validate import validate_plan, validate_step
from gridfleet.grid import Cell, GridMap
from gridfleet.paths import DistanceFieldCache


def parse(text: str) -> tuple[GridMap, dict[str, Cell], dict[str, Cell]]:
    """'#' wall, '.' free, 'A'-'Z' a unit's start, 'a'-'z' its target (on a free square)."""
    rows = [r for r in (line.strip() for line in text.strip().splitlines()) if r]
    starts: dict[str, Cell] = {}
    goals: dict[str, Cell] = {}
    for y, row in enumerate(rows):
        for x, ch in enumerate(row):
            if ch.isupper():
                starts[ch] = Cell(x, y)
            elif ch.islower():
                goals[ch.upper()] = Cell(x, y)
    grid = GridMap.from_rows("".join("@" if ch == "#" else "." for ch in row) for row in rows)
    return grid, starts, goals


def run(
    grid: GridMap, starts: dict[str, Cell], goals: dict[str, Cell], bound: int, seed: int = 0
) -> tuple[list[list[Cell]], int]:
    """Plan until every unit has reached its target; returns the plan and the steps taken.

    As in the coordinator, a unit's errand ends when it stands on its target (a pick, a drop, a
    reached goal); from then on it has no target and may be pushed aside by the others.
    """
    planner = Planner(grid, seed=seed)
    names = sorted(starts)
    here = dict(starts)
    pending = {a: goals[a] for a in names if a in goals and goals[a] != here[a]}
    plan = [[here[a] for a in names]]
    for t in range(bound):
        if not pending:
            return plan, t
        nxt = planner.step({a: AgentSpec(here[a], pending.get(a)) for a in names})
        here = nxt
        plan.append([here[a] for a in names])
        pending = {a: g for a, g in pending.items() if here[a] != g}
    raise AssertionError(f"units {sorted(pending)} did not reach their targets in {bound} steps")


def assert_clean(grid: GridMap, plan: list[list[Cell]]) -> None:
    bad = validate_plan(grid, plan)
    assert bad == [], bad[:5]


def test_corridor_with_one_passing_bay() -> None:
    # A and B cross a corridor with one side bay; one must step into the bay to let the other by.
    text = """
    ###########
    #####.#####
    #A.......B#
    ###########
    """
    grid, starts, _ = parse(text)
    goals = {"A": starts["B"], "B": starts["A"]}
    plan, steps = run(grid, starts, goals, bound=60)
    assert_clean(grid, plan)
    assert steps >= 8


def test_dead_end() -> None:
    # A sits deep in a dead end and must get out; B wants to go to the end of it.
    text = """
    ########
    #A....##
    ####.###
    #b...a.#
    ########
    """
    grid, _, _ = parse(text)
    starts = {"A": Cell(1, 1), "B": Cell(4, 3)}
    goals = {"A": Cell(5, 3), "B": Cell(1, 1)}
    plan, _ = run(grid, starts, goals, bound=80)
    assert_clean(grid, plan)


def test_four_way_crossing() -> None:
    text = """
    ###.###
    ###.###
    ###.###
    .......
    ###.###
    ###.###
    ###.###
    """
    grid, _, _ = parse(text)
    starts = {"N": Cell(3, 0), "S": Cell(3, 6), "W": Cell(0, 3), "E": Cell(6, 3)}
    goals = {"N": Cell(3, 6), "S": Cell(3, 0), "W": Cell(6, 3), "E": Cell(0, 3)}
    plan, _ = run(grid, starts, goals, bound=120)
    assert_clean(grid, plan)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dense_room(seed: int) -> None:
    import numpy as np

    grid = GridMap.from_rows(["......"] * 6)
    rng = np.random.default_rng(seed)
    cells = [Cell(x, y) for y in range(6) for x in range(6)]
    picks = rng.permutation(len(cells))
    n = 24  # two thirds of the room is full
    starts = {f"u{i}": cells[int(picks[i])] for i in range(n)}
    goal_picks = rng.permutation(len(cells))
    goals = {f"u{i}": cells[int(goal_picks[i])] for i in range(n)}
    plan, _ = run(grid, starts, goals, bound=400, seed=seed)
    assert_clean(grid, plan)


def test_new_obstacle_causes_reroute() -> None:
    text = """
    #######
    #A...a#
    #.###.#
    #.....#
    #######
    """
    grid, starts, goals = parse(text)
    planner = Planner(grid)
    first = planner.step({"A": AgentSpec(starts["A"], goals["A"])})
    assert first["A"] == Cell(2, 1)  # straight along the top
    planner.add_obstacles([Cell(3, 1)])
    here = starts["A"]
    trail = [here]
    for _ in range(30):
        if here == goals["A"]:
            break
        here = planner.step({"A": AgentSpec(here, goals["A"])})["A"]
        trail.append(here)
    assert here == goals["A"]
    assert Cell(3, 1) not in trail
    assert Cell(1, 2) in trail  # went round by the bottom
    assert validate_plan(planner.grid, [[c] for c in trail]) == []


def test_never_rotates_even_when_a_rotation_would_be_fastest() -> None:
    # Four units on a 2x2 block each want the next square clockwise: a rotation is optimal
    # for a synchronous planner but would deadlock asynchronous units.
    grid = GridMap.from_rows(["....", "....", "....", "...."])
    starts = [Cell(1, 1), Cell(2, 1), Cell(2, 2), Cell(1, 2)]
    targets = [starts[1], starts[2], starts[3], starts[0]]
    for seed in range(20):
        nxt = plan_step(grid, starts, targets, seed=seed)
        assert validate_step(grid, starts, nxt) == []


def test_frozen_units_and_reserved_squares_are_respected() -> None:
    grid = GridMap.from_rows(["....."])
    planner = Planner(grid)
    out = planner.step(
        {"A": AgentSpec(Cell(0, 0), Cell(4, 0)), "B": AgentSpec(Cell(2, 0), None, frozen=True)},
        reserved=[Cell(1, 0)],
    )
    assert out == {"A": Cell(0, 0), "B": Cell(2, 0)}


def test_follows_a_unit_that_moves_away() -> None:
    grid = GridMap.from_rows(["....."])
    planner = Planner(grid)
    out = planner.step(
        {"A": AgentSpec(Cell(0, 0), Cell(4, 0)), "B": AgentSpec(Cell(1, 0), Cell(4, 0))}
    )
    assert out["B"] == Cell(2, 0)
    assert out["A"] == Cell(1, 0)


@pytest.mark.parametrize("seed", range(6))
def test_corridor_pass_takes_the_bay_without_dithering(seed: int) -> None:
    # The unit at the bay steps into it, the other passes: a few steps over the straight run,
    # not rounds of backing off and pushing back.
    text = """
    ###########
    #####.#####
    #A.......B#
    ###########
    """
    grid, starts, _ = parse(text)
    goals = {"A": starts["B"], "B": starts["A"]}
    plan, steps = run(grid, starts, goals, bound=60, seed=seed)
    assert_clean(grid, plan)
    assert steps <= 8 + 4, steps


def test_a_unit_without_errand_stays_put() -> None:
    grid, starts, _ = parse(
        """
        .....
        ..A..
        .....
        """
    )
    planner = Planner(grid, seed=3)
    for _ in range(20):
        assert planner.step({"A": AgentSpec(starts["A"])}) == {"A": starts["A"]}


def test_an_idle_unit_pushed_aside_settles_again() -> None:
    # Found on the live dashboard: idle units walked about at random (every square is at
    # distance 0 from "no target"). An idle unit stays; it steps aside only for a unit that
    # needs its square, and then stays again.
    grid, starts, _ = parse(
        """
        #######
        #A...B#
        #.....#
        #######
        """
    )
    planner = Planner(grid, seed=3)
    here = dict(starts)
    for _ in range(30):
        here = planner.step({a: AgentSpec(here[a]) for a in here})
        assert here == starts
    grid, starts, goals = parse(
        """
        #######
        #b.A.B#
        ###.###
        #######
        """
    )
    planner = Planner(grid, seed=3)
    here = dict(starts)
    plan = [[here[a] for a in sorted(here)]]
    for _ in range(20):
        here = planner.step({"A": AgentSpec(here["A"]), "B": AgentSpec(here["B"], goals["B"])})
        plan.append([here[a] for a in sorted(here)])
        if here["B"] == goals["B"]:
            break
    assert here["B"] == goals["B"]
    assert_clean(grid, plan)
    settled = dict(here)
    for _ in range(20):
        here = planner.step({a: AgentSpec(here[a]) for a in here})
        assert here == settled


def test_the_same_seed_gives_the_same_moves() -> None:
    # The benchmark's task counts and the coordinator's replays rely on it.
    grid = GridMap.from_rows(["......"] * 6)
    cells = [Cell(x, y) for y in range(6) for x in range(6)]
    starts = {f"u{i}": cells[i] for i in range(0, 36, 2)}
    goals = {f"u{i}": cells[35 - i] for i in range(0, 36, 2)}
    first, _ = run(grid, starts, goals, bound=400, seed=5)
    again, _ = run(grid, starts, goals, bound=400, seed=5)
    assert first == again


def search_on(rows: list[str], agents: dict[Cell, Cell]) -> PIBT:
    """A one-step search on `rows` ('@' blocked) with agents given as {start: target}."""
    grid = GridMap.from_rows(rows)
    cache = DistanceFieldCache(grid)
    w = grid.width
    return PIBT(
        neighbour_table(grid),
        [s.y * w + s.x for s in agents],
        [t.y * w + t.x for t in agents.values()],
        [cache.get(t).reshape(-1) for t in agents.values()],
        [s == t for s, t in agents.items()],
        lambda: 0.5,
    )


def test_neighbour_table_lists_free_neighbours_north_east_south_west() -> None:
    # 0 1
    # 2 @
    assert neighbour_table(GridMap.from_rows(["..", ".@"])) == [(1, 2), (0,), (0,), ()]


def test_a_move_that_closes_a_cycle_is_recognised() -> None:
    # Squares 0 1 / 2 3; agent 0 on 0, 1 on 1, 2 on 3, 3 on 2; all want the next square clockwise.
    s = search_on(
        ["..", ".."],
        {
            Cell(0, 0): Cell(1, 0),
            Cell(1, 0): Cell(1, 1),
            Cell(1, 1): Cell(0, 1),
            Cell(0, 1): Cell(0, 0),
        },
    )
    s.nxt[1], s.nxt[2] = 3, 2  # 1 -> square 3, 2 -> square 2
    s.nxt[3] = 2  # 3 stays: agent 0 may follow 1 around
    assert not s.closes_cycle(0, 1)
    s.nxt[3] = 0  # 3 enters agent 0's square: 0 following 1 would close the ring
    assert s.closes_cycle(0, 1)


def test_a_unit_facing_a_dead_end_backs_off_to_let_the_other_pass() -> None:
    # ......   A on (2,0) wants the dead end (5,0); B on (3,0) wants (0,0). Pushing B ahead
    # #.####   would only drive it into the dead end; behind A, (1,0) has a side square.
    s = search_on(["......", "#.####"], {Cell(2, 0): Cell(5, 0), Cell(3, 0): Cell(0, 0)})
    assert swap_partner(s, 0, 3) == 1
    assert s.run([0, 1]) == [1, 2]  # A backs off towards the side square, B follows
    # Without a side square behind, backing off does not help: no swap.
    s = search_on(["......", "######"], {Cell(2, 0): Cell(5, 0), Cell(3, 0): Cell(0, 0)})
    assert swap_partner(s, 0, 3) is None


def test_a_shown_route_is_a_shortest_way_square_by_square_and_stops_at_its_limit() -> None:
    # A maze-like map, larger than the compact-field threshold on one side of the test and small
    # on the other: the way is checked against the distance field, square by square.
    for rows in (["....@....", ".@@.@.@@.", ".@.....@.", ".@@@@@.@.", "........."],
                 ["." * 90 if y % 4 else "." + "@" * 88 + "." for y in range(60)]):  # fmt: skip
        grid = GridMap.from_rows(rows)
        # Plain fields: with one-way lanes (on by default above 4096 squares) a route may be
        # longer by design (tests/coordinator/test_coordinator_flow.py).
        planner, cache = Planner(grid, lanes=False), DistanceFieldCache(grid)
        free = [
            c
            for y in range(grid.height)
            for x in range(grid.width)
            if grid.is_free(c := Cell(x, y))
        ]
        for start, target in zip(free[::7], free[::-5], strict=False):
            d = cache.distance(start, target)
            way = planner.route(start, target, 256)
            assert len(way) == d
            for here, there in zip([start, *way], way, strict=False):
                assert here.manhattan(there) == 1 and grid.is_free(there)
                assert cache.distance(there, target) == cache.distance(here, target) - 1
            assert planner.route(start, target, 3) == way[:3]
    walled = GridMap.from_rows(["..@..", "..@.."])
    assert Planner(walled).route(Cell(0, 0), Cell(4, 0)) == []  # unreachable: no way shown
