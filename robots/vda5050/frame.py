"""Squares ↔ a vehicle's map coordinates (metres), one documented transform per vehicle.

gridfleet's squares are 0.1 m by default, x to the right and y down the map's rows. A vehicle's
map has its own origin and axes: `origin` is where the centre of square (0, 0) lies in it, and
`x_axis`/`y_axis` are the unit vectors (each one of (1, 0), (-1, 0), (0, 1), (0, -1)) along which
a square's x and y grow there. The default, y_axis (0, -1), is a map with y up, as VDA 5050's is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gridfleet.errors import ConfigError
from gridfleet.squares import Cell

AXES = ((1, 0), (-1, 0), (0, 1), (0, -1))


@dataclass(frozen=True)
class Frame:
    """Where a grid's squares lie on one vehicle's map."""

    map_id: str
    origin: tuple[float, float] = (0.0, 0.0)
    x_axis: tuple[int, int] = (1, 0)
    y_axis: tuple[int, int] = (0, -1)
    square_m: float = 0.1

    def __post_init__(self) -> None:
        if self.x_axis not in AXES or self.y_axis not in AXES:
            raise ConfigError(f"map {self.map_id!r}: x_axis and y_axis must each be one of {AXES}")
        if self.x_axis[0] * self.y_axis[0] + self.x_axis[1] * self.y_axis[1] != 0:
            raise ConfigError(f"map {self.map_id!r}: x_axis and y_axis must be at right angles")
        if not (self.square_m > 0 and math.isfinite(self.square_m)):
            raise ConfigError(f"map {self.map_id!r}: square_m must be a positive number of metres")

    def position(self, cell: Cell) -> tuple[float, float]:
        """The centre of `cell` on the vehicle's map, in metres."""
        ox, oy = self.origin
        x = ox + self.square_m * (cell.x * self.x_axis[0] + cell.y * self.y_axis[0])
        y = oy + self.square_m * (cell.x * self.x_axis[1] + cell.y * self.y_axis[1])
        return round(x, 6), round(y, 6)

    def heading(self, frm: Cell, to: Cell) -> float:
        """The map angle (radians, VDA 5050's theta) of a move from `frm` to the next square `to`."""
        (x0, y0), (x1, y1) = self.position(frm), self.position(to)
        # Cut to micro-radians toward zero: rounded, a move along -x would be 3.141593, beyond
        # the schemas' bound of pi (3.14159265359).
        return math.trunc(math.atan2(y1 - y0, x1 - x0) * 1e6) / 1e6

    def squares_under(
        self, x: float, y: float, margin_m: float = 0.0, within: tuple[int, int] | None = None
    ) -> frozenset[Cell]:
        """Every square a vehicle whose reference point is at (x, y) may stand on: one at a
        square's centre, both on a boundary, and every square within `margin_m` (its body beyond
        the point, its position's deviation) more: it holds them all.

        `within` (width, height): only the squares of a grid that size count, so a point far off
        the grid (any number a double holds) or a margin wider than it costs no more than the
        grid's squares; a point beyond what a double holds on the grid's axes is on none.
        """
        gx, gy = self._grid_coords(x, y)
        reach = 0.5 + margin_m / self.square_m

        def under(g: float, size: int | None) -> list[int]:
            low, high = g - reach, g + reach
            if size is not None:
                low, high = max(low, -1.0), min(high, float(size))
            if not (math.isfinite(low) and math.isfinite(high)) or low > high:
                return []
            # Overlapping a square counts, touching its edge does not; a point on the boundary
            # between two squares is on both.
            near = range(math.floor(low), math.ceil(high) + 1)
            return [
                i
                for i in near
                if (size is None or 0 <= i < size)
                and (abs(g - i) < reach - 1e-9 or abs(g - i) <= 0.5 + 1e-9)
            ]

        width, height = within if within is not None else (None, None)
        return frozenset(Cell(i, j) for i in under(gx, width) for j in under(gy, height))

    def _grid_coords(self, x: float, y: float) -> tuple[float, float]:
        """(x, y) on the map, in squares along the grid's axes (square centres are integers)."""
        dx, dy = x - self.origin[0], y - self.origin[1]
        along_x = (dx * self.x_axis[0] + dy * self.x_axis[1]) / self.square_m
        along_y = (dx * self.y_axis[0] + dy * self.y_axis[1]) / self.square_m
        return along_x, along_y
