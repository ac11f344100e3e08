"""Distance fields: the fast BFS agrees with scipy's shortest paths on any grid."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.csgraph import shortest_path

from gridfleet.grid import Cell, GridMap
from gridfleet.paths import (
    COMPACT_UNREACHABLE,
    FIELD_BYTES,
    UNREACHABLE,
    DistanceFieldCache,
    adjacency,
    distance_field,
    fields_that_fit,
    route,
)


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


def test_a_large_grid_keeps_compact_fields_that_read_as_the_plain_ones() -> None:
    rng = np.random.default_rng(7)
    blocked = rng.random((70, 70)) < 0.2  # 4900 squares: above COMPACT_ABOVE
    blocked[:, 35] = True  # two halves: half the squares are cut off from any target
    grid = GridMap(blocked)
    cache = DistanceFieldCache(grid, size=3)
    assert cache.compact and not DistanceFieldCache(GridMap.from_rows(["..."])).compact
    targets = [c for c in grid.free_cells()[:: len(grid.free_cells()) // 5]][:5]
    cache.warm(targets)
    assert cache.computed == 5  # each once; the cache keeps the last three
    squares = np.flatnonzero(np.ones(grid.width * grid.height, dtype=bool))
    for target in targets:
        plain = distance_field(grid, target)
        assert np.array_equal(cache.get(target), plain)
        assert np.array_equal(cache.distances(target, squares), plain.reshape(-1))
        flat = cache.flat(target)
        cut_off = plain.reshape(-1) == UNREACHABLE
        assert cut_off.any() and all(
            flat[i] == COMPACT_UNREACHABLE for i in np.flatnonzero(cut_off)
        )
        assert all(cache.distance(c, target) == plain[c.y, c.x] for c in grid.free_cells()[::97])
    assert cache.distance(Cell(-1, 0), targets[0]) == UNREACHABLE


def test_a_cache_is_sized_to_the_targets_within_its_memory_bound() -> None:
    small, open_floor = GridMap.from_rows(["." * 32] * 32), np.zeros((140, 500), dtype=bool)
    assert fields_that_fit(small, 800) == 4096  # never below the default
    assert fields_that_fit(GridMap(open_floor), 30_000) == FIELD_BYTES // (140 * 500 * 4)
    open_floor[::2, ::2] = True  # 52,500 squares free: fewer than uint16 counts, compact
    assert fields_that_fit(GridMap(open_floor), 30_000) == FIELD_BYTES // (140 * 500 * 2)
    assert fields_that_fit(GridMap(open_floor), 5000) == 5000
