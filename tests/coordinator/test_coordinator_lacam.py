"""LaCAM and the planner's livelock fallback: complete where PIBT is not, validator-clean."""

from __future__ import annotations

import random

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from gridfleet.bench.anchors import ScenAgent
from gridfleet.bench.runs import run_one_shot
from gridfleet.coordinator.planning import unjam as unjam_module
from gridfleet.coordinator.planning.lacam import LaCAM, NoSolution, is_valid_move
from gridfleet.coordinator.planning.pibt import neighbour_table
from gridfleet.coordinator.planning.planner import Planner
from gridfleet.coordinator.planning.unjam import PATIENCE, Unjam
from gridfleet.coordinator.planning.validate import validate_plan
from gridfleet.grid import Cell, GridMap
from gridfleet.maps import load_map
from gridfleet.paths import DistanceFieldCache, adjacency

from support.paths import MAPS


def random_problem(
    seed: int, size: int, density: float, share: float
) -> tuple[GridMap, list[ScenAgent]]:
    """A seeded random map and `share` of its largest region's squares as agents' starts/goals."""
    rng = np.random.default_rng(seed)
    grid = GridMap(rng.random((size, size)) < density)
    labels = connected_components(adjacency(grid), directed=False)[1].reshape(size, size)
    free = ~grid.blocked
    ys, xs = np.nonzero(free & (labels == np.bincount(labels[free]).argmax()))
    cells = [Cell(int(x), int(y)) for x, y in zip(xs, ys, strict=True)]
    pick = random.Random(seed)
    n = int(len(cells) * share)
    starts, goals = pick.sample(cells, n), pick.sample(cells, n)
    return grid, [ScenAgent(s, g) for s, g in zip(starts, goals, strict=True)]


def lacam(grid: GridMap, starts: list[Cell], goals: list[Cell]) -> LaCAM:
    w = grid.width
    cache = DistanceFieldCache(grid)
    return LaCAM(
        neighbour_table(grid),
        [c.y * w + c.x for c in starts],
        [c.y * w + c.x for c in goals],
        [cache.flat(g) for g in goals],
    )


def cells(grid: GridMap, plan: list[tuple[int, ...]]) -> list[list[Cell]]:
    return [[Cell(s % grid.width, s // grid.width) for s in config] for config in plan]


def test_a_valid_move_may_stay_and_follow_a_unit_that_leaves() -> None:
    assert is_valid_move((0, 1, 5), (1, 2, 5))  # 0 follows 1 along; 5 stays


@pytest.mark.parametrize(
    ("before", "after", "what"),
    [
        ((0, 2), (1, 1), "two on one square"),
        ((0, 1), (1, 0), "a swap"),
        ((0, 1, 3), (1, 3, 0), "a rotation of three"),
        ((0, 1, 2, 5), (1, 2, 5, 0), "a rotation of four"),
    ],
)
def test_an_invalid_move_is_refused(
    before: tuple[int, ...], after: tuple[int, ...], what: str
) -> None:
    assert not is_valid_move(before, after), what


@pytest.mark.parametrize("seed", range(6))
def test_lacam_plans_from_the_starts_to_the_goals_and_breaks_no_rule(seed: int) -> None:
    grid, agents = random_problem(seed, size=10, density=0.1, share=0.4)
    search = lacam(grid, [a.start for a in agents], [a.goal for a in agents])
    plan = search.solve()
    assert plan is not None
    assert plan[0] == search.starts and plan[-1] == search.goals
    assert validate_plan(grid, cells(grid, plan)) == []


def test_three_units_on_a_ring_of_four_get_round_by_the_free_square() -> None:
    grid = GridMap.from_rows(["..", ".."])
    ring = [Cell(0, 0), Cell(1, 0), Cell(1, 1), Cell(0, 1)]
    plan = lacam(grid, ring[:3], ring[1:]).solve()  # each to the next square round
    assert plan is not None and plan[-1] == (1, 3, 2)
    assert validate_plan(grid, cells(grid, plan)) == []


def test_four_units_on_a_ring_of_four_cannot_rotate() -> None:
    # A rotation would do it in one step, but asynchronous units would each wait for the next.
    grid = GridMap.from_rows(["..", ".."])
    ring = [Cell(0, 0), Cell(1, 0), Cell(1, 1), Cell(0, 1)]
    with pytest.raises(NoSolution, match="4 agents"):
        lacam(grid, ring, ring[1:] + ring[:1]).solve()


def test_two_units_that_must_swap_in_a_corridor_have_no_solution() -> None:
    grid = GridMap.from_rows(["..."])
    with pytest.raises(NoSolution, match="2 agents"):
        lacam(grid, [Cell(0, 0), Cell(1, 0)], [Cell(1, 0), Cell(0, 0)]).solve()


def test_a_search_told_to_stop_returns_none() -> None:
    grid, agents = random_problem(1, size=10, density=0.1, share=0.4)
    assert (
        lacam(grid, [a.start for a in agents], [a.goal for a in agents]).solve(lambda: True) is None
    )


# PIBT alone (unguided) leaves 2 of these 30 agents short of their goals, pushing each other
# back and forth.
LIVELOCK = (2, 8, 0.1, 0.5)


def test_pibt_alone_livelocks_on_this_problem() -> None:
    grid, agents = random_problem(*LIVELOCK)
    planner = Planner(grid, guided=False)
    planner.unjam.search_nodes = 0  # the search gives up at once: plain PIBT
    result = run_one_shot(grid, agents, max_steps=300, planner=planner)
    assert not result.solved and result.at_goal < len(agents)


def test_the_planner_notices_the_livelock_and_searches_its_way_out() -> None:
    grid, agents = random_problem(*LIVELOCK)
    planner = Planner(grid, guided=False)
    result = run_one_shot(grid, agents, max_steps=300, planner=planner)
    assert result.solved and result.at_goal == len(agents)
    assert result.violations == 0
    assert planner.unjam.searches >= 1


def test_400_agents_on_a_32_by_32_map_all_reach_their_goals() -> None:
    grid, agents = random_problem(0, size=32, density=0.1, share=0.43)
    assert len(agents) >= 390
    result = run_one_shot(grid, agents, max_steps=1000, planner=Planner(grid))
    assert result.solved and result.violations == 0


def line_unjam() -> tuple[Unjam, list[str], list[int]]:
    """An Unjam on a line of 6 squares, for two agents going from 0 and 1 to 2 and 3."""
    grid = GridMap.from_rows(["......"])
    cache = DistanceFieldCache(grid)
    return Unjam(neighbour_table(grid), lambda s: cache.flat(Cell(s, 0))), ["a", "b"], [2, 3]


def trip(unjam: Unjam, names: list[str], goal: list[int]) -> list[int] | None:
    """Enter (0, 1) three times, as a fleet going round in circles would: a search follows."""
    for pos in ([0, 1], [1, 2], [0, 1], [1, 2]):
        assert unjam.moves(names, pos, goal, [False, False], set()) is None
    return unjam.moves(names, [0, 1], goal, [False, False], set())


def test_a_configuration_entered_a_third_time_starts_a_search_and_its_plan_is_followed() -> None:
    unjam, names, goal = line_unjam()
    assert trip(unjam, names, goal) == [1, 2]
    assert unjam.following and unjam.searches == 1
    assert unjam.moves(names, [1, 2], goal, [False, False], set()) == [2, 3]
    assert unjam.moves(names, [2, 3], goal, [False, False], set()) is None  # arrived: PIBT again
    assert not unjam.following


def test_a_livelock_seen_while_a_unit_still_drives_waits_busy_and_searches_once_all_stop() -> None:
    # With released windows some unit of a fleet going round in circles was nearly always still
    # driving, so the search (from a still fleet only) never began. Busy, the coordinator gives no
    # window beyond the next square, those driving stop, and the search begins.
    unjam, names, goal = line_unjam()
    assert not unjam.busy
    for pos in ([0, 1], [1, 2], [0, 1], [1, 2]):
        assert unjam.moves(names, pos, goal, [False, True], set()) is None
    assert unjam.moves(names, [0, 1], goal, [False, True], set()) is None  # due, b still driving
    assert unjam.busy and unjam.searches == 0
    assert unjam.moves(names, [0, 1], goal, [False, True], set()) is None
    assert unjam.busy  # stays so until the fleet is still...
    assert unjam.moves(names, [0, 1], goal, [False, False], set()) == [1, 2]  # ...then searches
    assert unjam.busy and unjam.following and unjam.searches == 1
    assert unjam.moves(names, [1, 2], goal, [False, False], set()) == [2, 3]
    assert unjam.moves(names, [2, 3], goal, [False, False], set()) is None
    assert not unjam.busy


def test_a_livelock_due_is_called_off_by_new_targets_or_by_getting_nearer_them() -> None:
    unjam, names, goal = line_unjam()
    for pos in ([0, 1], [1, 2], [0, 1], [1, 2], [0, 1]):
        unjam.moves(names, pos, goal, [False, True], set())
    assert unjam.busy
    assert unjam.moves(names, [0, 1], [2, 5], [False, True], set()) is None
    assert not unjam.busy  # new targets: whatever went round in circles is over
    unjam, names, goal = line_unjam()
    for pos in ([0, 1], [1, 2], [0, 1], [1, 2], [0, 1]):
        unjam.moves(names, pos, goal, [False, True], set())
    assert unjam.busy
    assert unjam.moves(names, [1, 3], goal, [False, True], set()) is None
    assert not unjam.busy  # nearer the targets than ever: no livelock after all


def test_a_unit_that_cannot_move_holds_the_one_behind_it_and_a_held_plan_is_dropped() -> None:
    unjam, names, goal = line_unjam()
    trip(unjam, names, goal)
    for _ in range(PATIENCE):
        # b is frozen (still moving, or stopped): a may not enter the square b holds.
        assert unjam.moves(names, [0, 1], goal, [False, True], set()) == [0, 1]
    assert unjam.moves(names, [0, 1], goal, [False, True], set()) is None
    assert not unjam.following


def test_a_reserved_square_is_not_entered_on_the_plan() -> None:
    unjam, names, goal = line_unjam()
    trip(unjam, names, goal)
    assert unjam.moves(names, [0, 1], goal, [False, False], {2}) == [0, 1]


def test_a_fleet_that_leaves_the_plan_or_new_targets_drop_it() -> None:
    unjam, names, goal = line_unjam()
    trip(unjam, names, goal)
    assert unjam.moves(names, [0, 4], goal, [False, False], set()) is None  # b was moved by hand
    assert not unjam.following
    unjam, names, goal = line_unjam()
    trip(unjam, names, goal)
    assert unjam.moves(names, [0, 1], [2, 5], [False, False], set()) is None
    assert not unjam.following


def test_a_search_longer_than_a_step_holds_everyone_still_until_it_has_a_way(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(unjam_module, "STEP_WORK", 1)  # one successor tried a step
    unjam, names, goal = line_unjam()
    assert trip(unjam, names, goal) == [0, 1]  # searching: nobody moves meanwhile
    assert unjam.moves(names, [0, 1], goal, [False, False], set()) == [0, 1]
    assert unjam.moves(names, [0, 1], goal, [False, False], set()) == [1, 2]  # found: off
    assert unjam.following and unjam.searches == 1


def test_a_fleet_that_moves_while_the_search_goes_on_drops_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(unjam_module, "STEP_WORK", 1)
    unjam, names, goal = line_unjam()
    trip(unjam, names, goal)
    assert unjam.moves(names, [0, 2], goal, [False, False], set()) is None  # b was moved
    assert not unjam.following


def test_two_agents_sent_to_one_square_do_not_hold_the_fleet_still_searching() -> None:
    # Two jobs picked up at one place send two units to one square: no configuration has both
    # there. A search for one held the whole fleet still, budget after budget (a warehouse run
    # stood still from step 90 on); the nearer keeps the square, the other waits where it is.
    grid = GridMap.from_rows([".....", ".....", "....."])
    w = grid.width
    cache = DistanceFieldCache(grid)
    unjam = Unjam(neighbour_table(grid), lambda g: cache.flat(Cell(g % w, g // w)))
    flat = [1 * w + 0, 1 * w + 4, 1 * w + 2]  # a and b both want [2, 1], where c stands
    goal = [1 * w + 2, 1 * w + 2, 0 * w + 2]  # ...and c wants [2, 0]
    names = ["a", "b", "c"]
    held_still = 0
    for _ in range(200):
        out = unjam.moves(names, flat, goal, [False] * 3, set())
        if out is not None and out != flat:
            break
        held_still += out is not None
    else:
        raise AssertionError(f"no move in 200 steps, {held_still} of them held still searching")
    assert unjam.searches >= 1
    assert len(set(out)) == 3 and all(
        a == b or grid.is_free(Cell(b % w, b // w)) for a, b in zip(flat, out, strict=True)
    )


def test_units_left_standing_on_a_square_someone_keeps_make_way_and_the_search_goes_on() -> None:
    # Seen in a dense warehouse run over MQTT: three units bringing jobs to [4, 0], two going to
    # [8, 0], where one of the three stood, and one to [6, 0]. Only one unit can end on each; the
    # others were left where they stood, one of them on [8, 0], so no search was possible, and two
    # units went back and forth between [5, 0] and [6, 1] for 1,000 steps.
    grid = load_map(MAPS / "warehouse.map")
    w = grid.width
    cache = DistanceFieldCache(grid)
    unjam = Unjam(neighbour_table(grid), lambda g: cache.flat(Cell(g % w, g // w)))
    at = {"u06": (6, 0), "u07": (7, 0), "u12": (8, 0), "x0": (5, 0), "x2": (9, 1), "x6": (9, 0)}
    to = {"u06": (4, 0), "u07": (4, 0), "u12": (4, 0), "x0": (8, 0), "x2": (8, 0), "x6": (6, 0)}
    names = list(at)
    goal = [to[n][1] * w + to[n][0] for n in names]
    here = [at[n][1] * w + at[n][0] for n in names]
    there = list(here)
    there[0] = 1 * w + 6  # u06 steps down to [6, 1] and back, as it did
    out = None
    for pos in (here, there, here, there, here):
        out = unjam.moves(names, pos, goal, [False] * len(names), set())
    assert unjam.searches == 1 and out is not None
    pos = out
    for _ in range(100):  # follow the plan to its end
        out = unjam.moves(names, pos, goal, [False] * len(names), set())
        if out is None:
            break
        pos = out
    else:
        raise AssertionError("the plan never ended")
    ends = {n: (p % w, p // w) for n, p in zip(names, pos, strict=True)}
    assert len(set(ends.values())) == len(names)
    assert ends["x6"] == (6, 0) and (4, 0) in ends.values() and (8, 0) in ends.values()
    assert [n for n in ("u06", "u07", "u12") if ends[n] == (4, 0)] != []
