"""A grid unit's settings, read from its PROTO fields in the Webots world (`GridUnit`)."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from gridfleet.config import DEFAULT_MQTT_URL, check_step, parse_brokers
from gridfleet.energy import BatterySpec
from gridfleet.errors import ConfigError, GridfleetError
from gridfleet.grid import FREE_CHARS, Cell, GridMap
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.protocol.topics import Topics, validate_id
from gridfleet.robots.webots.api import Field, Supervisor
from gridfleet.robots.webots.geometry import hex_color, square_at

BROKER_ENV = "GRIDFLEET_BROKER"  # the broker of every unit whose `broker` field is empty
T = TypeVar("T")


@dataclass(frozen=True)
class UnitSettings:
    """Who the unit is and where it joins: id, start, capacity, colour, step, map, broker, energy."""

    unit_id: str
    start: Cell
    capacity_kg: float
    color: str
    step_s: float
    grid: GridMap
    broker: str
    root: str
    mirror: bool = False  # the unit runs elsewhere: this one shows where its state says it is
    battery: BatterySpec | None = None  # None: it never runs down (it reports no energy)
    chargers: frozenset[Cell] = frozenset()  # the squares where it charges


def read_settings(robot: Supervisor, environ: dict[str, str] | None = None) -> UnitSettings:
    """The settings in the robot's fields; anything wrong raises ConfigError in one line."""
    env = os.environ if environ is None else environ
    unit_id = robot.getName()
    where = f"grid unit {unit_id!r}"
    node = robot.getSelf()

    def field(name: str) -> Field:
        found = node.getField(name)
        if found is None:
            raise ConfigError(f"{where}: no field {name!r} (is it a GridUnit from gridfleet?)")
        return found

    def checked(name: str, read: Callable[[], T]) -> T:
        try:
            return read()
        except (GridfleetError, ValueError) as exc:
            raise ConfigError(f"{where}: field {name!r}: {exc}") from None

    checked("name", lambda: validate_id(unit_id, "unit id"))
    rows_field = field("map")
    rows = [rows_field.getMFString(i) for i in range(rows_field.getCount())]
    grid = checked("map", lambda: _grid(rows, unit_id))
    x, y, _ = field("translation").getSFVec3f()
    start = square_at(x, y)
    if not grid.is_free(start):
        raise ConfigError(
            f"{where}: stands on square {list(start)}, which is off the map or blocked"
        )
    capacity = field("capacity").getSFFloat()
    if not capacity > 0:
        raise ConfigError(f"{where}: field 'capacity': {capacity} kg; give a number > 0")
    step_s = check_step(field("stepPeriod").getSFFloat(), f"{where}: field 'stepPeriod'")
    broker = field("broker").getSFString()
    source = "field 'broker'"
    if not broker and env.get(BROKER_ENV):
        broker, source = env[BROKER_ENV], f"${BROKER_ENV}"
    broker = broker or DEFAULT_MQTT_URL
    try:
        parse_brokers(broker)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {source}: {exc}") from None
    root = field("root").getSFString() or DEFAULT_ROOT
    checked("root", lambda: Topics(root))

    def percent(name: str) -> float:
        return checked(name, lambda: _pct(field(name).getSFFloat(), name))

    has_battery = field("battery").getSFBool()
    battery = BatterySpec(*(percent(n) for n in BATTERY_FIELDS)) if has_battery else None
    chargers = checked("chargers", lambda: _squares(field("chargers"), grid))
    return UnitSettings(
        unit_id=unit_id,
        start=start,
        capacity_kg=capacity,
        color=checked("color", lambda: hex_color(field("color").getSFColor())),
        step_s=step_s,
        grid=grid,
        broker=broker,
        root=root,
        mirror=bool(field("mirror").getSFBool()),
        battery=battery,
        chargers=chargers,
    )


BATTERY_FIELDS = ("batteryPct", "movePct", "idlePctPerS", "chargePctPerS")  # BatterySpec's order


def _pct(value: float, name: str) -> float:
    """A battery field's value: % of a full charge, 0 to 100 (a charge rate above 0)."""
    low_ok = name != "chargePctPerS"
    if not (0.0 <= value <= 100.0 and (low_ok or value > 0.0)):
        low = "0" if low_ok else "above 0"
        raise ValueError(f"{value:g}: give a number from {low} to 100 (% of a full charge)")
    return value


def _squares(found: Field, grid: GridMap) -> frozenset[Cell]:
    """The squares an MFVec2f field lists, each a free square of the map (ValueError if not)."""
    squares = set()
    for i in range(found.getCount()):
        x, y = found.getMFVec2f(i)
        cell = Cell(round(x), round(y))
        if (cell.x, cell.y) != (x, y) or not grid.is_free(cell):
            raise ValueError(f"square {x:g} {y:g} is not a free square of the map")
        squares.add(cell)
    return frozenset(squares)


def _grid(rows: list[str], name: str) -> GridMap:
    """The static map from its rows ('.' free, '@' blocked); ValueError when it is not one."""
    if not rows or not rows[0]:
        raise ValueError("no rows: the world must give the unit its map")
    if any(len(row) != len(rows[0]) for row in rows):
        raise ValueError("rows of different lengths")
    known = FREE_CHARS | {"@"}
    bad = sorted({ch for row in rows for ch in row} - known)
    if bad:
        raise ValueError(f"unknown square {bad[0]!r} (use '.' free and '@' blocked)")
    return GridMap.from_rows(rows, name=name)
