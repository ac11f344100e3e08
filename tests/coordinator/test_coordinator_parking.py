"""Idle units make way: one standing on another unit's target leaves for a parking square."""

from __future__ import annotations

import pytest
from test_coordinator_planner import assert_clean, parse, run

from gridfleet.coordinator.planning.parking import parking_square
from gridfleet.coordinator.planning.pibt import neighbour_table
from gridfleet.coordinator.planning.planner import AgentSpec, Planner
from gridfleet.grid import Cell

# Found in an hour of `up --demo`: an idle unit at the end of a dead end held another unit's
# dropoff; PIBT could not push it out (its only way was the pusher's square) and the job waited
# 21 minutes. Each shape: A idle on the square B is heading for.
POCKETS = {
    "end of a row": """
        #######
        #A....#
        ###.###
        ###B###
        #######
        """,
    "one-wide pocket beside a corridor": """
        ########
        #A...B.#
        ####.###
        ########
        """,
    "deep dead end": """
        #####
        #A###
        #.###
        #...#
        #B..#
        #####
        """,
}


@pytest.mark.parametrize("shape", POCKETS)
def test_an_idle_unit_in_a_dead_end_makes_way_for_the_unit_heading_there(shape: str) -> None:
    grid, starts, _ = parse(POCKETS[shape])
    plan, _ = run(grid, starts, {"B": starts["A"]}, bound=40)
    assert_clean(grid, plan)


def test_the_parking_square_is_off_every_target_and_stays_until_reached() -> None:
    grid, starts, _ = parse(POCKETS["end of a row"])
    planner = Planner(grid, seed=1)
    here = dict(starts)
    target = starts["A"]
    parks = set()
    while here["B"] != target:
        here = planner.step({"A": AgentSpec(here["A"]), "B": AgentSpec(here["B"], target)})
        park = planner.parking("A")
        if park is not None:
            parks.add(park)
    assert len(parks) == 1 and target not in parks
    # Once B has arrived and A stands on its parking square, A is idle and stays there.
    for _ in range(5):
        here = planner.step({"A": AgentSpec(here["A"]), "B": AgentSpec(here["B"])})
    settled = dict(here)
    assert planner.parking("A") is None
    for _ in range(10):
        assert planner.step({a: AgentSpec(here[a]) for a in here}) == settled


def test_an_idle_unit_on_nobodys_target_is_left_alone() -> None:
    grid, starts, _ = parse(
        """
        #######
        #A....#
        ###.###
        ###B###
        #######
        """
    )
    planner = Planner(grid, seed=1)
    b_target = Cell(5, 1)
    moves = planner.step({"A": AgentSpec(starts["A"]), "B": AgentSpec(starts["B"], b_target)})
    assert moves["A"] == starts["A"] and planner.parking("A") is None


def test_a_frozen_idle_unit_is_not_sent_away_until_it_may_move() -> None:
    grid, starts, _ = parse(POCKETS["end of a row"])
    planner = Planner(grid, seed=1)
    agents = {"A": AgentSpec(starts["A"], frozen=True), "B": AgentSpec(starts["B"], starts["A"])}
    assert planner.step(agents)["A"] == starts["A"]
    assert planner.parking("A") is None


def test_parking_prefers_open_floor_and_falls_back_to_the_nearest_square() -> None:
    grid, _, _ = parse(
        """
        #######
        #.....#
        ###.###
        ##...##
        ###.###
        #######
        """
    )
    nbrs = neighbour_table(grid)
    w = grid.width
    start = 1 * w + 1
    junction = 1 * w + 3  # (3, 1): where three aisles meet, not a place to wait
    open_floor = 3 * w + 3  # (3, 3): four free neighbours
    assert parking_square(nbrs, start, avoid=set(), occupied=set()) == open_floor
    # The open floor is somebody's target: the nearest other square will do.
    assert parking_square(nbrs, start, avoid={open_floor}, occupied=set()) == 1 * w + 2
    # A square it must pass on the way is no obstacle to getting there.
    assert parking_square(nbrs, start, avoid={1 * w + 2, junction}, occupied=set()) == open_floor
    # Every other square taken: nowhere to go.
    others = set(range(w * grid.height)) - {start}
    assert parking_square(nbrs, start, avoid=set(), occupied=others) is None
