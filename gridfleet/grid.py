"""The static map of a playfield (walls, fixed obstacles); squares and headings are in squares.py."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from gridfleet.squares import Cell, Direction

__all__ = ["BLOCKED_CHARS", "FREE_CHARS", "Cell", "Direction", "GridMap"]


class GridMap:
    """The static map: which squares are blocked (walls, fixed obstacles); off the map is wall."""

    __slots__ = ("blocked", "height", "name", "width")

    def __init__(self, blocked: npt.ArrayLike, name: str = "map") -> None:
        arr = np.array(blocked, dtype=bool)
        if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
            raise ValueError(f"blocked must be a non-empty 2-D array, got shape {arr.shape}")
        arr.setflags(write=False)
        self.blocked: npt.NDArray[np.bool_] = arr  # indexed [y, x]
        self.height, self.width = int(arr.shape[0]), int(arr.shape[1])
        self.name = name

    @classmethod
    def from_rows(cls, rows: Iterable[str], name: str = "map") -> GridMap:
        """Build from text rows where '.' is free and any of '@ O T W #' is blocked."""
        rows = list(rows)
        return cls([[ch in BLOCKED_CHARS for ch in row] for row in rows], name=name)

    def in_bounds(self, cell: Cell) -> bool:
        """True when `cell` lies on the map."""
        return 0 <= cell.x < self.width and 0 <= cell.y < self.height

    def is_free(self, cell: Cell) -> bool:
        """True when `cell` is on the map and not a wall or fixed obstacle."""
        return self.in_bounds(cell) and not bool(self.blocked[cell.y, cell.x])

    def free_neighbours(self, cell: Cell) -> list[Cell]:
        """Free orthogonal neighbours of `cell`."""
        return [n for n in cell.neighbours() if self.is_free(n)]

    def with_blocked(self, cells: Iterable[Cell]) -> GridMap:
        """A copy with extra squares blocked (e.g. obstacles the fleet has discovered)."""
        arr = self.blocked.copy()
        for c in cells:
            if self.in_bounds(c):
                arr[c.y, c.x] = True
        return GridMap(arr, name=self.name)

    def rows(self) -> list[str]:
        """Text rows: '.' free, '@' blocked."""
        return ["".join("@" if b else "." for b in row) for row in self.blocked]

    def map_id(self) -> str:
        """A short fingerprint of the walls (not the name): units and coordinator on one map
        share it (protocol.md §4.2)."""
        text = "\n".join(self.rows()).encode()
        return hashlib.sha256(text).hexdigest()[:12]

    def free_cells(self) -> list[Cell]:
        """Every free square, row by row."""
        ys, xs = np.nonzero(~self.blocked)
        return [Cell(int(x), int(y)) for y, x in zip(ys, xs, strict=True)]

    def __repr__(self) -> str:
        return f"GridMap({self.name!r}, {self.width}x{self.height})"


FREE_CHARS = frozenset(".GES")
BLOCKED_CHARS = frozenset("@OTW#")
