"""Distance fields: the fast BFS agrees with scipy's shortest paths on any grid."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.csgraph import shortest_path

from gridfleet.grid import Cell, GridMap
from gridfleet.paths import UNREACHABLE, adjacency, distance_field, route


def oracle(grid: GridMap, target: Cell) -> np.ndarray:
    """Steps to `target` from scipy's Dijkstra on the same graph (slower, long trusted)."""
    field = np.full((grid.height, grid.width), UNREACHABLE, dtype=np.int32)
    if grid.is_free(target):
        d = shortest_path(
            adjacency(grid), unweighted=True, indices=target.y * grid.width + target.x
        )
        flat = field.reshape(-1)
        flat[np.isfinite(d)] = d[np.isfinite(d)].astype(np.int32)
    return field


@st.composite
def grids_and_targets(draw: st.DrawFn) -> tuple[GridMap, Cell]:
    w, h = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    blocked = draw(st.lists(st.booleans(), min_size=w * h, max_size=w * h))
    grid = GridMap(np.array(blocked).reshape(h, w))
    return grid, Cell(draw(st.integers(0, w - 1)), draw(st.integers(0, h - 1)))


@settings(max_examples=300, deadline=None)
@given(grids_and_targets())
def test_the_field_matches_shortest_paths_on_any_grid(case: tuple[GridMap, Cell]) -> None:
    grid, target = case
    assert np.array_equal(distance_field(grid, target), oracle(grid, target))


def test_a_walled_off_region_is_unreachable_and_routes_follow_the_field() -> None:
    grid = GridMap.from_rows(["...@..", ".@.@..", ".@...."])
    field = distance_field(grid, Cell(0, 0))
    assert field[0, 4] == 8 and field[1, 1] == UNREACHABLE
    assert route(field, Cell(4, 0)) is not None and len(route(field, Cell(4, 0)) or []) == 8
    walled = GridMap.from_rows(["..@.."])
    assert distance_field(walled, Cell(0, 0))[0, 4] == UNREACHABLE
    assert (distance_field(walled, Cell(2, 0)) == UNREACHABLE).all()  # a blocked target
