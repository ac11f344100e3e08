"""Squares and headings on the grid: value types with no dependency beyond the standard library
(the protocol's messages use them, and a command's start should not wait for numpy)."""

from __future__ import annotations

from collections.abc import Iterator
from enum import Enum
from typing import NamedTuple


class Cell(NamedTuple):
    """A square of the playfield: x = column, y = row, (0, 0) is the top-left square."""

    x: int
    y: int

    def step(self, direction: Direction) -> Cell:
        """The neighbouring square in `direction`."""
        return Cell(self.x + direction.dx, self.y + direction.dy)

    def neighbours(self) -> Iterator[Cell]:
        """The four orthogonal neighbours, in N E S W order."""
        for d in Direction:
            yield self.step(d)

    def direction_to(self, other: Cell) -> Direction | None:
        """The direction of an adjacent square, or None when `other` is not adjacent."""
        return Direction.between(self, other)

    def manhattan(self, other: Cell) -> int:
        """Manhattan distance to `other`."""
        return abs(self.x - other.x) + abs(self.y - other.y)


class Direction(Enum):
    """A heading on the grid; north is y - 1."""

    N = "N"
    E = "E"
    S = "S"
    W = "W"

    @property
    def dx(self) -> int:
        """Column change of one step this way."""
        return _DELTAS[self][0]

    @property
    def dy(self) -> int:
        """Row change of one step this way."""
        return _DELTAS[self][1]

    @property
    def opposite(self) -> Direction:
        """The direction pointing back."""
        return _OPPOSITE[self]

    @staticmethod
    def between(a: Cell, b: Cell) -> Direction | None:
        """The direction from `a` to adjacent `b`, None when not adjacent."""
        return _BY_DELTA.get((b.x - a.x, b.y - a.y))


_DELTAS = {Direction.N: (0, -1), Direction.E: (1, 0), Direction.S: (0, 1), Direction.W: (-1, 0)}
_OPPOSITE = {
    Direction.N: Direction.S,
    Direction.S: Direction.N,
    Direction.E: Direction.W,
    Direction.W: Direction.E,
}
_BY_DELTA = {v: k for k, v in _DELTAS.items()}
