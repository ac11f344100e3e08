"""Shortest paths on a GridMap: BFS distance fields (scipy csgraph) and route extraction."""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from gridfleet.grid import Cell, GridMap

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

# scipy is imported where it is used: it loads numpy.testing, whose importlib.metadata brings in
# the standard library's email and socket modules, and importing a pure core loads no network
# module (tests/system/test_layers.py). Once loaded, an import inside a function is a dict lookup.

UNREACHABLE = np.iinfo(np.int32).max
COMPACT_UNREACHABLE = int(np.iinfo(np.uint16).max)  # the same in a compact (uint16) field
COMPACT_ABOVE = 4096  # squares: larger grids keep compact fields (smaller ones: as they were)
FIELD_BYTES = 1536 << 20  # what `fields_that_fit` lets a cache hold by default
DistanceField = npt.NDArray[np.int32]  # indexed [y, x]; UNREACHABLE where no path exists


def adjacency(grid: GridMap) -> csr_matrix:
    """The 4-connected adjacency matrix of the free squares, indexed by y * width + x."""
    from scipy.sparse import csr_matrix

    free = ~grid.blocked
    h, w = grid.height, grid.width
    idx = np.arange(h * w).reshape(h, w)
    rows: list[npt.NDArray[np.int64]] = []
    cols: list[npt.NDArray[np.int64]] = []
    horiz = free[:, :-1] & free[:, 1:]
    rows.append(idx[:, :-1][horiz])
    cols.append(idx[:, 1:][horiz])
    vert = free[:-1, :] & free[1:, :]
    rows.append(idx[:-1, :][vert])
    cols.append(idx[1:, :][vert])
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    data = np.ones(2 * len(r), dtype=np.int8)
    return csr_matrix((data, (np.concatenate([r, c]), np.concatenate([c, r]))), shape=(h * w,) * 2)


def distance_field(grid: GridMap, target: Cell, graph: csr_matrix | None = None) -> DistanceField:
    """Steps from every square to `target` (UNREACHABLE where blocked or cut off)."""
    field = _bfs(grid, target, graph, np.dtype(np.int32), UNREACHABLE)
    return field.reshape(grid.height, grid.width)


def _bfs(
    grid: GridMap, target: Cell, graph: csr_matrix | None, dtype: np.dtype[Any], cut_off: int
) -> npt.NDArray[Any]:
    """The field towards `target` by flat index, in `dtype`, `cut_off` where unreachable."""
    n = grid.height * grid.width
    field = np.full(n, cut_off, dtype=dtype)
    if grid.is_free(target):
        from scipy.sparse.csgraph import breadth_first_order

        g = adjacency(grid) if graph is None else graph
        root = target.y * grid.width + target.x
        # A plain BFS is 2-3x faster than scipy's shortest_path on large maps; it returns the
        # visiting order and parents, from which the depths follow level by level.
        order, parent = breadth_first_order(g, root, directed=True, return_predecessors=True)
        field[order] = _depths(order, parent, n)
    return field


def _cheapest(
    grid: GridMap, target: Cell, reversed_costs: csr_matrix, dtype: np.dtype[Any], cut_off: int
) -> npt.NDArray[Any]:
    """The cheapest cost from every square to `target` by flat index, `cut_off` where none."""
    n = grid.height * grid.width
    field = np.full(n, cut_off, dtype=dtype)
    if grid.is_free(target):
        from scipy.sparse.csgraph import dijkstra

        cost = dijkstra(reversed_costs, directed=True, indices=target.y * grid.width + target.x)
        reached = np.isfinite(cost)
        field[reached] = cost[reached]
    return field


def _depths(
    order: npt.NDArray[np.int32], parent: npt.NDArray[np.int32], n: int
) -> npt.NDArray[np.int32]:
    """Depth of each node of a BFS `order`: in BFS order the parents' positions never decrease."""
    position = np.empty(n, dtype=np.int32)
    position[order] = np.arange(len(order), dtype=np.int32)
    up = position[parent[order[1:]]]  # where each later node's parent stands in `order`
    m = len(order)
    # before[b]: how many later nodes have their parent ahead of position b. Depth d + 1 ends
    # where the nodes whose parents are at depth d or less end, so each bound follows from the
    # last by one lookup: counted for every position at once (a search per depth, in a Python
    # loop, took two thirds of a large map's field).
    before = np.zeros(m + 1, dtype=np.int64)
    np.cumsum(np.bincount(up, minlength=m)[:m], out=before[1:])
    bounds = [0, 1]  # order[bounds[d]:bounds[d + 1]] is depth d
    while bounds[-1] < m:
        end = 1 + int(before[bounds[-1]])
        if end <= bounds[-1]:
            raise RuntimeError("breadth_first_order did not visit level by level")
        bounds.append(end)
    return np.repeat(np.arange(len(bounds) - 1, dtype=np.int32), np.diff(bounds))


def distance(field: DistanceField, cell: Cell) -> int:
    """Distance of `cell` in `field`, UNREACHABLE when off the map."""
    h, w = field.shape
    if 0 <= cell.x < w and 0 <= cell.y < h:
        return int(field[cell.y, cell.x])
    return UNREACHABLE


def route(field: DistanceField, start: Cell) -> list[Cell] | None:
    """The squares after `start` down to the field's target, or None when unreachable."""
    d = distance(field, start)
    if d == UNREACHABLE:
        return None
    path: list[Cell] = []
    here = start
    while d > 0:
        # Neighbours come in N E S W order, so ties are broken the same way every time.
        here = next(n for n in here.neighbours() if distance(field, n) == d - 1)
        path.append(here)
        d -= 1
    return path


def fields_that_fit(grid: GridMap, wanted: int, max_bytes: int = FIELD_BYTES) -> int:
    """A cache size for `wanted` distinct targets on `grid`: all of them, or as many fields as
    `max_bytes` holds (at least the default 4096)."""
    return max(4096, min(wanted, max_bytes // DistanceFieldCache.bytes_per_field(grid)))


class DistanceFieldCache:
    """Distance fields of one grid, computed once per target and kept up to `size` targets.

    On grids of more than `COMPACT_ABOVE` squares the fields are kept as uint16 (half the memory:
    10,000 fields of a 500 x 140 map take 1.4 GB, not 2.8), which is exact while fewer than
    65,535 squares are free (no shortest path is longer). `get`, `distance` and `distances` say
    UNREACHABLE either way; `flat` gives the field as kept, `COMPACT_UNREACHABLE` where cut off
    on a compact one (larger than any distance, which is all the planner asks of it).
    """

    def __init__(self, grid: GridMap, size: int = 4096, costs: csr_matrix | None = None) -> None:
        """`costs`: a cost per move (row: from, column: to) instead of one step each; the field
        is then the cheapest cost to the target (Dijkstra), not the fewest steps."""
        self.grid = grid
        self.size = size
        self.compact = DistanceFieldCache.is_compact(grid)
        self._dtype = np.dtype(np.uint16 if self.compact else np.int32)
        self._cut_off = COMPACT_UNREACHABLE if self.compact else UNREACHABLE
        # With float64 weights and sorted indices, as csgraph wants them: else every BFS copies
        # and checks the whole graph first (more than the search itself on a large map).
        self._graph = adjacency(grid).astype(np.float64)
        self._graph.sort_indices()
        # The cost towards a target is searched from it backwards: along each move reversed.
        self._reversed = None if costs is None else costs.T.tocsr().astype(np.float64)
        if self._reversed is not None:
            self._reversed.sort_indices()
        self._fields: OrderedDict[Cell, npt.NDArray[Any]] = OrderedDict()  # flat, as kept
        self.computed = 0  # fields computed so far (more than the targets asked for: thrashing)

    @staticmethod
    def is_compact(grid: GridMap) -> bool:
        """Are `grid`'s fields kept as uint16?"""
        free = grid.width * grid.height - int(grid.blocked.sum())
        return grid.width * grid.height > COMPACT_ABOVE and free < COMPACT_UNREACHABLE

    @staticmethod
    def bytes_per_field(grid: GridMap) -> int:
        """Memory one field of `grid` takes in the cache."""
        per_square = 2 if DistanceFieldCache.is_compact(grid) else 4
        return grid.width * grid.height * per_square

    def _kept(self, target: Cell) -> npt.NDArray[Any]:
        """The field towards `target` by flat index, as kept (computed on first use)."""
        field = self._fields.get(target)
        if field is None:
            if self._reversed is None:
                field = _bfs(self.grid, target, self._graph, self._dtype, self._cut_off)
            else:
                field = _cheapest(self.grid, target, self._reversed, self._dtype, self._cut_off)
            self.computed += 1
            self._fields[target] = field
            if len(self._fields) > self.size:
                self._fields.popitem(last=False)
        else:
            self._fields.move_to_end(target)
        return field

    def get(self, target: Cell) -> DistanceField:
        """The field towards `target`, computed on first use."""
        field = self._kept(target)
        if self.compact:
            field = field.astype(np.int32)
            field[field == COMPACT_UNREACHABLE] = UNREACHABLE
        return field.reshape(self.grid.height, self.grid.width)

    def flat(self, target: Cell) -> memoryview:
        """The field towards `target` by flat index (y * width + x), read as plain ints."""
        # A memoryview over the same memory: indexing it gives a Python int, several times
        # cheaper than a numpy scalar in the planner's hot loop, with no copy kept.
        return self._kept(target).data

    def distance(self, start: Cell, target: Cell) -> int:
        """Path length from `start` to `target` (UNREACHABLE when cut off)."""
        if not self.grid.in_bounds(start):
            return UNREACHABLE
        d = int(self._kept(target)[start.y * self.grid.width + start.x])
        return UNREACHABLE if d == self._cut_off else d

    def distances(self, target: Cell, squares: npt.NDArray[np.intp]) -> npt.NDArray[np.int32]:
        """Path lengths from flat `squares` to `target` (UNREACHABLE when cut off)."""
        d = self._kept(target)[squares].astype(np.int32)
        if self.compact:
            d[d == COMPACT_UNREACHABLE] = UNREACHABLE
        return d

    def warm(self, targets: Iterable[Cell]) -> None:
        """Compute the fields of `targets` not kept yet, before they are wanted."""
        for target in dict.fromkeys(targets):
            self._kept(target)
