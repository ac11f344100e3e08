"""Shortest paths on a GridMap: BFS distance fields (scipy csgraph) and route extraction."""

from __future__ import annotations

from collections import OrderedDict
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from gridfleet.grid import Cell, GridMap

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

# scipy is imported where it is used: it loads numpy.testing, whose importlib.metadata brings in
# the standard library's email and socket modules, and importing a pure core loads no network
# module (tests/test_layers.py). Once loaded, an import inside a function is a dict lookup.

UNREACHABLE = np.iinfo(np.int32).max
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
    n = grid.height * grid.width
    field = np.full(n, UNREACHABLE, dtype=np.int32)
    if grid.is_free(target):
        from scipy.sparse.csgraph import breadth_first_order

        g = adjacency(grid) if graph is None else graph
        root = target.y * grid.width + target.x
        # A plain BFS is 2-3x faster than scipy's shortest_path on large maps; it returns the
        # visiting order and parents, from which the depths follow level by level.
        order, parent = breadth_first_order(g, root, directed=True, return_predecessors=True)
        field[order] = _depths(order, parent, n)
    return field.reshape(grid.height, grid.width)


def _depths(
    order: npt.NDArray[np.int32], parent: npt.NDArray[np.int32], n: int
) -> npt.NDArray[np.int32]:
    """Depth of each node of a BFS `order`: in BFS order the parents' positions never decrease."""
    position = np.empty(n, dtype=np.int64)
    position[order] = np.arange(len(order))
    up = position[parent[order[1:]]]  # where each later node's parent stands in `order`
    bounds = [0, 1]  # order[bounds[d]:bounds[d + 1]] is depth d
    while bounds[-1] < len(order):
        # The nodes of the next depth are those whose parent is at a depth already bounded.
        end = 1 + int(np.searchsorted(up, bounds[-1]))
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


class DistanceFieldCache:
    """Distance fields of one grid, computed once per target and kept up to `size` targets."""

    def __init__(self, grid: GridMap, size: int = 4096) -> None:
        self.grid = grid
        self.size = size
        self._graph = adjacency(grid)
        self._fields: OrderedDict[Cell, DistanceField] = OrderedDict()

    def get(self, target: Cell) -> DistanceField:
        """The field towards `target`, computed on first use."""
        field = self._fields.get(target)
        if field is None:
            field = distance_field(self.grid, target, self._graph)
            self._fields[target] = field
            if len(self._fields) > self.size:
                self._fields.popitem(last=False)
        else:
            self._fields.move_to_end(target)
        return field

    def flat(self, target: Cell) -> memoryview:
        """The field towards `target` by flat index (y * width + x), read as plain ints."""
        # A memoryview over the same memory: indexing it gives a Python int, several times
        # cheaper than a numpy scalar in the planner's hot loop, with no copy kept.
        return self.get(target).reshape(-1).data

    def distance(self, start: Cell, target: Cell) -> int:
        """Path length from `start` to `target` (UNREACHABLE when cut off)."""
        return distance(self.get(target), start)
