"""Squares in metres, sensor values as readings, colours: the numbers Webots and the fleet share."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.robots.webots.geometry import (
    BLOCK_HEIGHT_M,
    LED_NAMES,
    OBSTACLE_SIDE_M,
    SENSOR_MAX_VALUE,
    SENSOR_NAMES,
    SENSOR_OFFSET_M,
    SENSOR_RANGE_M,
    SQUARE_M,
    UNIT_OR_WALL_BELOW_M,
    UNIT_SIZE_M,
    arena_centre,
    hex_color,
    metres,
    offset,
    reading,
    sf_color,
    square_at,
)
from gridfleet.scenario import DEFAULT_COLORS

from support.vrml import Node, read_proto
from support.webots_double import PROTOS
from support.webots_rays import Ray, unit_geometry

GRID_UNIT = read_proto((PROTOS / "GridUnit.proto").read_text(encoding="utf-8"))


def test_square_zero_is_the_origin_and_north_is_plus_y() -> None:
    assert metres(Cell(0, 0)) == (0.0, 0.0)
    assert metres(Cell(3, 5)) == (0.3, -0.5)
    assert metres(Cell(0, 0).step(Direction.N)) == (0.0, 0.1)
    assert metres(Cell(0, 0).step(Direction.E)) == (0.1, 0.0)
    for d in Direction:
        assert offset(d, SQUARE_M) == metres(Cell(0, 0).step(d))


@given(st.integers(-50, 4095), st.integers(-50, 4095))
def test_a_square_comes_back_from_its_metres(x: int, y: int) -> None:
    cell = Cell(x, y)
    assert square_at(*metres(cell)) == cell
    mx, my = metres(cell)
    # Anything within 0.049 m of the centre (a position read back with rounding) is that square.
    assert square_at(mx + 0.049, my - 0.049) == cell


def test_the_arena_centre_puts_square_zero_at_the_origin() -> None:
    grid = GridMap.from_rows(["." * 7] * 4)
    cx, cy = arena_centre(grid)
    assert (cx - 7 * SQUARE_M / 2, cy + 4 * SQUARE_M / 2) == pytest.approx((-0.05, 0.05))


@pytest.mark.parametrize(
    ("value", "beyond", "expected"),
    [
        (1000.0, False, "free"),
        (1000.0, True, "wall"),  # off the map is a wall, whatever the sensor says
        (100.0, True, "wall"),
        (100.0, False, "unit"),  # a neighbour's face 0.01 m away
        (300.0, False, "obstacle"),  # an obstacle's face 0.03 m away
        (199.0, False, "unit"),
        (200.0, False, "obstacle"),
        (999.9, False, "obstacle"),
        (math.nan, False, "unit"),  # not measured yet: never free, never reported as obstacle
    ],
)
def test_sensor_values_read_as_the_unit_logic_expects(
    value: float, beyond: bool, expected: str
) -> None:
    assert reading(value, beyond) == expected


def test_the_split_lies_between_a_units_face_and_an_obstacles() -> None:
    unit_face = SQUARE_M - UNIT_SIZE_M / 2 - SENSOR_OFFSET_M
    obstacle_face = SQUARE_M - OBSTACLE_SIDE_M / 2 - SENSOR_OFFSET_M
    assert unit_face < UNIT_OR_WALL_BELOW_M < obstacle_face < SENSOR_RANGE_M
    # The range reaches into the neighbouring square only, never the one beyond it.
    assert SENSOR_OFFSET_M + SENSOR_RANGE_M < 1.5 * SQUARE_M


@pytest.mark.parametrize("color", DEFAULT_COLORS)
def test_colours_go_to_webots_and_back(color: str) -> None:
    assert hex_color(sf_color(color)) == color


@given(st.from_regex(r"#[0-9a-f]{6}", fullmatch=True))
def test_any_colour_goes_to_webots_and_back(color: str) -> None:
    assert hex_color(sf_color(color)) == color


@pytest.mark.parametrize("bad", [(1.2, 0, 0), (0.5, 0.5), (-0.1, 0, 0)])
def test_a_colour_out_of_range_is_refused(bad: tuple[float, ...]) -> None:
    with pytest.raises(ValueError, match="three numbers from 0 to 1"):
        hex_color(bad)


def test_the_grid_unit_proto_places_its_sensors_as_the_geometry_says() -> None:
    side, rays = unit_geometry(GRID_UNIT)
    assert side == UNIT_SIZE_M
    by_name = {r.name: r for r in rays}
    assert sorted(by_name) == sorted(SENSOR_NAMES.values())
    for d, name in SENSOR_NAMES.items():
        ray: Ray = by_name[name]
        # 0.04 m off centre towards its side, looking out that way.
        assert (ray.x, ray.y) == pytest.approx(offset(d, SENSOR_OFFSET_M))
        assert (math.cos(ray.heading), math.sin(ray.heading)) == pytest.approx(
            offset(d, 1.0), abs=1e-4
        )
        assert ray.table == ((0.0, 0.0), (SENSOR_RANGE_M, SENSOR_MAX_VALUE))


def test_the_grid_unit_proto_has_its_four_leds_and_what_the_course_asks() -> None:
    nodes = GRID_UNIT.body.nodes()
    leds = [n for n in nodes if n.type == "GridLed"]
    assert sorted(str(n.fields["name"][0]) for n in leds) == sorted(LED_NAMES.values())  # type: ignore[index]
    for led in leds:
        direction = Direction(str(led.fields["name"][0]).split()[1])  # type: ignore[index]
        x, y, z = (float(v) for v in led.fields["translation"])  # type: ignore[union-attr, arg-type]
        assert (x, y) == pytest.approx(offset(direction, 0.03))  # on top, on its side
        assert z > UNIT_SIZE_M / 2
    robot = GRID_UNIT.body
    assert robot.type == "Robot"
    assert robot.fields["supervisor"] == (True,)
    fields = ("name", "color", "translation", "capacity", "broker", "map", "stepPeriod", "root")
    for name in (*fields, "mirror"):
        assert name in GRID_UNIT.interface, name


def test_the_obstacle_proto_is_as_narrow_as_the_geometry_says() -> None:
    proto = read_proto((PROTOS / "GridObstacle.proto").read_text(encoding="utf-8"))
    _, size = proto.interface["size"]
    assert size == (OBSTACLE_SIDE_M, OBSTACLE_SIDE_M, BLOCK_HEIGHT_M)
    assert isinstance(proto.body, Node) and proto.body.type == "Solid"
    assert "boundingObject" in proto.body.fields  # what a distance sensor sees


@pytest.mark.parametrize("path", sorted(PROTOS.glob("*.proto")), ids=lambda p: p.name)
def test_every_proto_reads_as_balanced_vrml_of_r2023b(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    assert text.startswith("#VRML_SIM R2023b utf8\n")
    proto = read_proto(text)
    assert proto.name == path.stem
