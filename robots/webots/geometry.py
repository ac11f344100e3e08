"""Where squares are in Webots, how big things are, and what a distance sensor's value means.

The one place the playfield meets metres. Webots R2023b is z-up (x east, y north); the course's
arena is translated so that the centre of square (0, 0) is the origin, one square is 0.1 m, and
the grid unit moves by setting its translation. Rows grow southwards here: square (x, y) is at
(0.1·x, -0.1·y). The course's listing (written for Webots R2020a) reads y = round(10·pos[1]);
with the sign, Webots' top view shows the map as the dashboard does, (0, 0) top-left, north up,
and `Direction.N` (y - 1) is Webots' +y.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol.messages import SensorReading

SQUARE_M = 0.1  # the side of a square
UNIT_SIZE_M = 0.1  # a grid unit is a block filling its square (the course's robot)
OBSTACLE_SIDE_M = 0.06  # an obstacle is a narrower block, so that its sensor value differs
BLOCK_HEIGHT_M = 0.1  # units, obstacles and the arena's walls are this tall
SENSOR_OFFSET_M = 0.04  # each distance sensor sits this far from the unit's centre (the course)
SENSOR_RANGE_M = 0.1  # lookupTable [0 0 0, 0.1 1000 0]: the DistanceSensor's default
SENSOR_MAX_VALUE = 1000.0  # the value at the end of the range: nothing seen
# A unit's face or the arena's wall is 0.01 m from the sensor; an obstacle's is 0.03 m. Halfway
# between them, so that a little noise or rounding never turns one into the other.
UNIT_OR_WALL_BELOW_M = 0.02

# Each sensor's and LED's name, and the heading of its axis about z (radians: 0 is east).
SENSOR_NAMES = {d: f"ds {d.value}" for d in Direction}
LED_NAMES = {d: f"led {d.value}" for d in Direction}
HEADINGS = {
    Direction.E: 0.0,
    Direction.N: math.pi / 2,
    Direction.W: math.pi,
    Direction.S: -math.pi / 2,
}


def metres(cell: Cell) -> tuple[float, float]:
    """The centre of `cell` in Webots' x and y (metres)."""
    return (round(cell.x * SQUARE_M, 6), round(-cell.y * SQUARE_M, 6))


def square_at(x_m: float, y_m: float) -> Cell:
    """The square whose centre is nearest to the point (x_m, y_m) of Webots' floor."""
    return Cell(round(x_m / SQUARE_M), round(-y_m / SQUARE_M))


def offset(direction: Direction, distance_m: float) -> tuple[float, float]:
    """The x, y offset of `distance_m` towards `direction` (north is +y)."""
    return (round(direction.dx * distance_m, 6), round(-direction.dy * distance_m, 6))


def arena_centre(grid: GridMap) -> tuple[float, float]:
    """The x, y of the middle of the floor that holds every square of `grid`."""
    return (
        round((grid.width - 1) * SQUARE_M / 2, 6),
        round(-(grid.height - 1) * SQUARE_M / 2, 6),
    )


def reading(value: float, beyond_map: bool) -> SensorReading:
    """What a distance sensor's `value` says is in the neighbouring square.

    Off the map is a wall whatever the value (the arena's wall stands there). On the map,
    the maximum means nothing is there; a face as near as a neighbouring unit's is a unit; a
    farther one is an obstacle. A value that is not a number (a sensor not measured yet) reads
    as a unit: never free, and never an obstacle the unit would report to the fleet.
    """
    if beyond_map:
        return "wall"
    if value >= SENSOR_MAX_VALUE:
        return "free"
    distance = value / SENSOR_MAX_VALUE * SENSOR_RANGE_M
    return "obstacle" if distance >= UNIT_OR_WALL_BELOW_M else "unit"


def hex_color(rgb: Sequence[float]) -> str:
    """Webots' SFColor (three numbers 0..1) as #rrggbb."""
    if len(rgb) != 3 or not all(0.0 <= c <= 1.0 for c in rgb):
        raise ValueError(f"a colour is three numbers from 0 to 1, got {list(rgb)}")
    return "#" + "".join(f"{round(c * 255):02x}" for c in rgb)


def sf_color(color: str) -> tuple[float, float, float]:
    """#rrggbb as Webots' SFColor (three numbers 0..1, four decimals: enough to come back)."""
    r, g, b = (int(color[i : i + 2], 16) for i in (1, 3, 5))
    return (round(r / 255, 4), round(g / 255, 4), round(b / 255, 4))
