"""One-way lanes derived from the map: a route costs more against the traffic's flow.

A warehouse's aisles are one square wide. Units that take shortest routes meet head on in them,
and PIBT spends its steps backing one out. A city grid avoids that with one-way streets in
alternating directions: a route that follows them meets others only from behind or across.
Here every square gets a direction along its row and one along its column: lanes that are
aisles (with a square walled on both sides) alternate in the order they come on the map, the
other rows and columns alternate by their index. A move along its lane costs `WITH_COST`, one
against it `AGAINST_COST`, and the fields PIBT descends are the cheapest costs to each target
(`paths.DistanceFieldCache` with costs): units take a detour to follow the lanes where one is
short enough, and still go against a lane where none is.

It is a cost, never a rule: every move stays allowed, so no square becomes unreachable.

Pure: a grid in, a cost per move out.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from gridfleet.grid import GridMap
from gridfleet.paths import adjacency

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

WITH_COST = 1  # what a move along its lane costs a route ...
AGAINST_COST = 2  # ... and one against it (measured: bench/README.md, "One-way lanes")


def lane_directions(walled: npt.NDArray[np.bool_]) -> npt.NDArray[np.int8]:
    """+1 or -1 per lane (row or column index, along axis 0 of `walled`): aisle lanes (those with a
    square walled on both sides) alternate in map order, the others alternate by their index."""
    lanes = walled.shape[0]
    is_aisle = walled.any(axis=1)
    direction = np.where(np.arange(lanes) % 2 == 0, 1, -1)
    rank = np.cumsum(is_aisle) - 1  # each aisle's place among the aisles
    return np.where(is_aisle, np.where(rank % 2 == 0, 1, -1), direction).astype(np.int8)


def _directions(grid: GridMap) -> tuple[npt.NDArray[np.int8], npt.NDArray[np.int8]]:
    """Per column: +1 south (y grows), -1 north; per row: +1 east (x grows), -1 west."""
    free = ~grid.blocked
    padded = np.pad(free, 1, constant_values=False)
    # A square of a column aisle: walled left and right (it is moved through up or down).
    walled_sides = free & ~padded[1:-1, :-2] & ~padded[1:-1, 2:]
    # A square of a row aisle: walled above and below.
    walled_ends = free & ~padded[:-2, 1:-1] & ~padded[2:, 1:-1]
    return lane_directions(walled_sides.T), lane_directions(walled_ends)


def lane_costs(grid: GridMap) -> csr_matrix:
    """The cost of every move (row: from, column: to): `WITH_COST` along its lane, else
    `AGAINST_COST`."""
    down, east = _directions(grid)
    moves = adjacency(grid).tocoo()
    w = grid.width
    here, there = moves.row.astype(np.int64), moves.col.astype(np.int64)
    forward = np.where(there > here, 1, -1)
    same_row = there // w == here // w
    lane = np.where(same_row, east[here // w], down[here % w])
    cost = np.where(forward == lane, WITH_COST, AGAINST_COST).astype(np.float64)
    from scipy.sparse import csr_matrix

    return csr_matrix((cost, (here, there)), shape=moves.shape)
