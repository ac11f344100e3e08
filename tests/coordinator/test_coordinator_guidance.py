"""Traffic-flow guidance: guide paths around the others' traffic, fields that lead back to them."""

from __future__ import annotations

import pytest

from gridfleet.coordinator.planning import guidance as guidance_module
from gridfleet.coordinator.planning.guidance import MAX_SQUARES, Guidance
from gridfleet.coordinator.planning.pibt import neighbour_table
from gridfleet.coordinator.planning.planner import AgentSpec, Planner
from gridfleet.grid import Cell, GridMap
from gridfleet.paths import DistanceFieldCache

HALL = GridMap.from_rows(["." * 9, "." * 9])  # two rows: room to pass on the other one
W = HALL.width


def sq(x: int, y: int) -> int:
    return y * W + x


def guidance(grid: GridMap = HALL) -> Guidance:
    cache = DistanceFieldCache(grid)
    return Guidance(
        neighbour_table(grid), lambda s: cache.flat(Cell(s % grid.width, s // grid.width))
    )


def test_a_unit_alone_is_guided_along_a_shortest_path() -> None:
    g = guidance()
    g.field("a", sq(0, 0), sq(8, 0))
    assert g.guide("a") == [sq(x, 0) for x in range(1, 9)]


def test_a_unit_going_the_other_way_is_guided_along_the_other_row() -> None:
    g = guidance()
    g.field("a", sq(0, 0), sq(8, 0))
    g.field("b", sq(7, 0), sq(1, 0))
    # Six steps head on against a's traffic cost more than eight steps on the free row.
    assert g.guide("b") == [sq(7, 1), *(sq(x, 1) for x in range(6, 0, -1)), sq(1, 0)]


def test_a_unit_going_the_same_way_shares_the_row() -> None:
    g = guidance()
    g.field("a", sq(0, 0), sq(8, 0))
    g.field("b", sq(1, 0), sq(7, 0))
    assert g.guide("b") == [sq(x, 0) for x in range(2, 8)]


def test_the_field_leads_back_to_the_guide_path_and_along_it() -> None:
    g = guidance()
    g.field("a", sq(0, 0), sq(8, 0))
    field = g.field("b", sq(7, 0), sq(1, 0))
    assert field is not None
    assert [field[sq(x, 1)] for x in (7, 4, 1)] == [7, 4, 1]  # on the path: what is left of it
    # Off the path, the nearest path square and the rest from there; b does not cut back across.
    assert field[sq(8, 0)] == 1 + field[sq(8, 1)]
    assert field[sq(4, 0)] == 1 + field[sq(4, 1)] and field[sq(1, 0)] == 0


def test_traffic_counts_only_what_is_still_ahead_and_goes_with_the_unit() -> None:
    g = guidance()
    g.field("a", sq(0, 0), sq(8, 0))
    assert g.traffic(sq(0, 0), sq(1, 0)) == 1 and g.traffic(sq(7, 0), sq(8, 0)) == 1
    g.field("a", sq(4, 0), sq(8, 0))  # a has come as far as (4, 0)
    assert g.traffic(sq(3, 0), sq(4, 0)) == 0 and g.traffic(sq(4, 0), sq(5, 0)) == 1
    g.keep_only({"someone else"})
    assert g.traffic(sq(4, 0), sq(5, 0)) == 0 and g.guide("a") == []


def test_a_new_target_replaces_the_old_guide_and_its_traffic() -> None:
    g = guidance()
    g.field("a", sq(0, 0), sq(8, 0))
    g.field("a", sq(0, 0), sq(0, 1))
    assert g.traffic(sq(0, 0), sq(1, 0)) == 0 and g.guide("a") == [sq(0, 1)]


def test_a_target_cut_off_gives_no_guide_and_the_unit_stays() -> None:
    grid = GridMap.from_rows(["..@.."])
    g = guidance(grid)
    field = g.field("a", 0, 4)
    assert field is not None and g.guide("a") == [] and field[0] < field[1]


def test_the_planner_guides_on_small_maps_and_not_on_large_ones() -> None:
    assert Planner(HALL).guidance is not None
    assert Planner(HALL, guided=False).guidance is None
    side = int(MAX_SQUARES**0.5) + 1
    assert Planner(GridMap.from_rows(["." * side] * side)).guidance is None


def test_a_guided_planner_sends_opposite_traffic_along_the_other_row() -> None:
    planner = Planner(HALL)
    agents = {"a": AgentSpec(Cell(0, 0), Cell(8, 0)), "b": AgentSpec(Cell(7, 0), Cell(1, 0))}
    moves = planner.step(agents)
    assert moves == {"a": Cell(1, 0), "b": Cell(7, 1)}  # b steps aside at once, not at the meeting


def test_the_route_shown_for_a_guided_unit_is_its_guide_path() -> None:
    planner = Planner(HALL)
    agents = {"a": AgentSpec(Cell(0, 0), Cell(8, 0)), "b": AgentSpec(Cell(7, 0), Cell(1, 0))}
    planner.step(agents)
    shown = planner.route(Cell(7, 1), Cell(1, 0), unit="b")
    assert shown == [*(Cell(x, 1) for x in range(6, 0, -1)), Cell(1, 0)]
    assert planner.route(Cell(7, 0), Cell(1, 0)) == [Cell(x, 0) for x in range(6, 0, -1)]
    assert planner.route(Cell(5, 0), Cell(1, 0), unit="b")[0] == Cell(4, 0)  # off its guide


def test_guide_paths_are_made_anew_in_turn_round_the_fleet() -> None:
    g = guidance()
    names = ["a", "b", "c"]
    for i, unit in enumerate(names):
        g.field(unit, sq(i, 0), sq(8, 1))
    g.renew(names)
    assert g.guide("a") == [] and g.guide("b") and g.guide("c")  # a's is made anew next step
    assert g.traffic(sq(0, 0), sq(1, 0)) == 0  # and its traffic no longer counts
    g.renew(names)
    g.renew(names)
    assert g.guide("b") == g.guide("c") == []


def test_a_step_makes_only_so_many_new_guide_paths_and_the_rest_wait_their_turn(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(guidance_module, "WORK_PER_STEP", 5 * HALL.width * HALL.height)
    g = guidance()
    made = [g.field(f"u{i}", sq(i % 9, i // 9), sq(8, 1)) for i in range(17)]
    assert sum(f is not None for f in made) == 5  # the rest descend the plain field this step
    g.begin_step()
    assert g.field("u16", sq(7, 1), sq(8, 1)) is not None and g.guide("u16") == [sq(8, 1)]
