"""Scenario files (TOML): a map plus hidden obstacles, units, jobs, goals, batteries, chargers
and named places."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, ValidationError
from pydantic_core import ErrorDetails

from gridfleet.energy import BatterySpec, ChargingSpec, thresholds_problem
from gridfleet.errors import MapError, ScenarioError
from gridfleet.grid import Cell, GridMap
from gridfleet.maps import load_map
from gridfleet.paths import UNREACHABLE, adjacency, distance_field
from gridfleet.protocol.constants import ID_PATTERN, MAX_PLACES
from gridfleet.protocol.messages import PlaceKind
from gridfleet.shipped import resolve
from gridfleet.textfile import TomlFile

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

DEFAULT_COLORS = (
    "#d32f2f",
    "#1976d2",
    "#388e3c",
    "#f9a825",
    "#7b1fa2",
    "#00838f",
    "#ef6c00",
    "#5d4037",
)
PLACE_KINDS: tuple[PlaceKind, ...] = get_args(PlaceKind)
DEFAULT_PLACE_KINDS: tuple[PlaceKind, ...] = ("pickup", "dropoff")  # a place that names no kinds


@dataclass(frozen=True)
class UnitSpec:
    """A unit of a scenario: id, start square, capacity (kg), display colour and battery."""

    id: str
    start: Cell
    capacity: float
    color: str
    battery: BatterySpec | None = None  # None: it never runs down (it reports no energy)


@dataclass(frozen=True)
class ChargerSpec:
    """A charger of a scenario: its name and square (one unit at a time)."""

    name: str
    square: Cell


@dataclass(frozen=True)
class PlaceSpec:
    """A named square of a scenario and what may happen there (protocol.md §5.10)."""

    name: str
    square: Cell
    kinds: tuple[PlaceKind, ...]


@dataclass(frozen=True)
class JobSpec:
    """A pick-and-deliver job of a scenario."""

    pickup: Cell
    dropoff: Cell
    mass: float
    priority: int = 0
    id: str | None = None


@dataclass(frozen=True)
class GoalSpec:
    """A goal of a scenario: send `unit` to `target`."""

    unit: str
    target: Cell


@dataclass(frozen=True)
class Scenario:
    """A loaded, validated scenario."""

    path: Path
    map_path: Path
    grid: GridMap
    name: str
    hidden_obstacles: tuple[Cell, ...] = ()
    units: tuple[UnitSpec, ...] = ()
    jobs: tuple[JobSpec, ...] = ()
    goals: tuple[GoalSpec, ...] = ()
    description: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    chargers: tuple[ChargerSpec, ...] = ()
    charging: ChargingSpec = field(default_factory=ChargingSpec)  # [charging]; else defaults
    places: tuple[PlaceSpec, ...] = ()  # [[places]], then each charger not named by one

    def unit(self, unit_id: str) -> UnitSpec:
        """The unit with `unit_id`; KeyError when there is none."""
        for u in self.units:
            if u.id == unit_id:
                return u
        raise KeyError(unit_id)


Square = Annotated[list[StrictInt], Field(min_length=2, max_length=2)]
Id = Annotated[str, Field(pattern=ID_PATTERN)]
Kg = Annotated[StrictFloat | StrictInt, Field(gt=0, allow_inf_nan=False)]
Pct = Annotated[StrictFloat | StrictInt, Field(ge=0, le=100, allow_inf_nan=False)]
Rate = Annotated[StrictFloat | StrictInt, Field(ge=0, le=100, allow_inf_nan=False)]
ChargeRate = Annotated[StrictFloat | StrictInt, Field(gt=0, le=100, allow_inf_nan=False)]


class _Table(BaseModel):
    """A table of the file: exact types (TOML's, no coercion), no key it does not know."""

    model_config = ConfigDict(extra="forbid", strict=True)


class _BatteryTable(_Table):
    start_pct: Pct | None = None
    move_pct: Rate | None = None
    idle_pct_per_s: Rate | None = None
    charge_pct_per_s: ChargeRate | None = None


class _UnitTable(_Table):
    id: Id
    start: Square
    capacity: Kg
    color: Annotated[str, Field(pattern=r"^#[0-9a-fA-F]{6}$")] | None = None
    battery: _BatteryTable | None = None


class _ChargerTable(_Table):
    square: Square
    name: Id | None = None


class _PlaceTable(_Table):
    name: Id
    square: Square
    kinds: Annotated[list[PlaceKind], Field(min_length=1)] = list(DEFAULT_PLACE_KINDS)


class _ChargingTable(_Table):
    critical_pct: Pct = 20.0
    good_pct: Pct = 50.0
    sufficient_pct: Pct = 80.0
    full_pct: Pct = 95.0
    available_from: Literal["sufficient", "full"] = "sufficient"


class _JobTable(_Table):
    pickup: Square
    dropoff: Square
    mass: Kg
    priority: Annotated[StrictInt, Field(ge=0, le=100)] = 0
    id: Id | None = None


class _GoalTable(_Table):
    unit: str
    target: Square


class _ScenarioFile(_Table):
    map: str
    name: str | None = None
    description: str = ""
    hidden_obstacles: list[Square] = []
    units: list[_UnitTable] = []
    jobs: list[_JobTable] = []
    goals: list[_GoalTable] = []
    battery: _BatteryTable | None = None
    chargers: list[_ChargerTable] = []
    charging: _ChargingTable | None = None
    places: list[_PlaceTable] = []


_TABLES: dict[str, tuple[str, type[_Table]]] = {
    "units": ("unit", _UnitTable),
    "jobs": ("job", _JobTable),
    "goals": ("goal", _GoalTable),
    "chargers": ("charger", _ChargerTable),
    "places": ("place", _PlaceTable),
}
_SECTIONS: dict[str, type[_Table]] = {"battery": _BatteryTable, "charging": _ChargingTable}
_SQUARES = {"start", "pickup", "dropoff", "target", "square"}
_PERCENTS = {"start_pct", "critical_pct", "good_pct", "sufficient_pct", "full_pct"}
_RATES = {"move_pct", "idle_pct_per_s", "charge_pct_per_s"}


def load_scenario(path: str | Path) -> Scenario:
    """Load and validate a scenario, a file or a shipped one by name (`playfield`); every
    problem raises ScenarioError naming file and line."""
    p = resolve(path, ".toml", "scenario", ScenarioError)
    where = TomlFile(p, "scenario", ScenarioError)
    return _build(p, where.data, where)


def _words(field: str, kind: str, value: Any) -> str:
    """What is wrong with a table's `field`, in the words of the file's author."""
    if field in _SQUARES:
        return f"{field} must be [x, y] with whole numbers, got {value!r}"
    if field in ("capacity", "mass"):
        if kind in ("greater_than", "finite_number"):
            return f"'{field}' must be greater than 0, got {value!r}"
        return f"'{field}' must be a number of kg, got {value!r}"
    if field == "id":
        return f"id {value!r} is not a valid id (letters, digits, '_', '.', '-'; no '/ + # $')"
    if field == "color":
        return f"color {value!r} is not #rrggbb"
    if field == "priority":
        return f"priority must be a whole number 0..100, got {value!r}"
    if field in _PERCENTS:
        return f"'{field}' must be a number from 0 to 100 (% of a full charge), got {value!r}"
    if field in _RATES:
        low = "greater than 0" if field == "charge_pct_per_s" else "0 or more"
        return (
            f"'{field}' must be a number {low} and at most 100 (% of a full charge), got {value!r}"
        )
    if field == "available_from":
        return f'\'available_from\' must be "sufficient" or "full", got {value!r}'
    if field == "battery":
        return "'battery' must be a table, e.g. battery = { start_pct = 40.0 }"
    if field == "name":
        return f"name {value!r} is not a valid id (letters, digits, '_', '.', '-')"
    if field == "kinds":
        known = ", ".join(PLACE_KINDS)
        if isinstance(value, list) and not value:
            return f"kinds is empty: give one or more of {known}"
        if isinstance(value, list):
            odd = next((k for k in value if k not in PLACE_KINDS), None)
            return f"kinds: unknown kind {odd!r} (known: {known})"
        return f'kinds must be a list of {known}, e.g. kinds = ["pickup"]'
    return f"unknown unit {value!r}"  # a goal's unit


def _shape_error(
    error: ErrorDetails, data: dict[str, Any], where: TomlFile[ScenarioError]
) -> ScenarioError:
    """One line for the first thing pydantic found wrong with the file's shape."""
    loc, kind = error["loc"], error["type"]
    top = str(loc[0])
    if kind == "extra_forbidden" and len(loc) == 1:
        known = ", ".join(sorted(_ScenarioFile.model_fields))
        return where.error(where.key(top), f"unknown key {top!r} (known: {known})")
    if top in _TABLES:
        noun, model = _TABLES[top]
        tables = data[top]
        if len(loc) < 3 or not isinstance(tables[loc[1]], dict):
            return where.error(where.key(top), f"'{top}' must be a list of tables ([[{top}]])")
        index = int(loc[1])
        table, field = tables[index], str(loc[2])
        what = _what(noun, index, table, field)
        if field == "battery" and len(loc) > 3 and isinstance(table.get("battery"), dict):
            inner, battery = str(loc[3]), table["battery"]
            if kind == "extra_forbidden":
                known = ", ".join(sorted(_BatteryTable.model_fields))
                problem = f"battery: unknown key {inner!r} (known: {known})"
            else:
                problem = f"battery: {_words(inner, kind, battery.get(inner))}"
            return where.error(where.table(top, index), f"{what}: {problem}")
        if kind == "extra_forbidden":
            known = ", ".join(sorted(model.model_fields))
            problem = f"unknown key {field!r} (known: {known})"
        else:
            problem = _words(field, kind, table.get(field))
        return where.error(where.table(top, index), f"{what}: {problem}")
    if top in _SECTIONS:
        line = where.section(top)
        section = data[top]
        if len(loc) < 2 or not isinstance(section, dict):
            return where.error(line, f"'{top}' must be a table ([{top}])")
        field = str(loc[1])
        if kind == "extra_forbidden":
            known = ", ".join(sorted(_SECTIONS[top].model_fields))
            return where.error(line, f"[{top}]: unknown key {field!r} (known: {known})")
        return where.error(line, f"[{top}]: {_words(field, kind, section.get(field))}")
    if top == "hidden_obstacles":
        if len(loc) == 1:
            return where.error(
                where.key(top), "'hidden_obstacles' must be a list of [x, y] squares"
            )
        value = data[top][loc[1]]
        return where.error(
            where.key(top), f"hidden obstacle must be [x, y] with whole numbers, got {value!r}"
        )
    if top == "map":
        return where.error(where.key(top), "'map' must name a .map file relative to this scenario")
    return where.error(where.key(top), "'name' and 'description' must be strings")


def _what(noun: str, index: int, table: dict[str, Any], field: str) -> str:
    """How an error names a table: a unit by its id, a place by its name, else by its number."""
    uid, name = table.get("id"), table.get("name")
    if noun == "unit" and isinstance(uid, str):
        return f"unit {uid!r}"
    if noun == "place" and isinstance(name, str) and field != "name":
        return f"place {name!r}"
    return f"{noun} #{index + 1}"


def _build(path: Path, data: dict[str, Any], where: TomlFile[ScenarioError]) -> Scenario:
    try:
        shape = _ScenarioFile.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        # An unknown key first (a misspelt one explains the rest), then the map, then in order.
        first = min(errors, key=lambda e: (e["type"] != "extra_forbidden", e["loc"][0] != "map"))
        raise _shape_error(first, data, where) from None
    map_path = (path.parent / shape.map).resolve()
    try:
        grid = load_map(map_path)
    except MapError as exc:
        raise where.error(where.key("map"), f"map {shape.map!r}: {exc}") from None

    def square(value: list[int], line: int, what: str) -> Cell:
        cell = Cell(value[0], value[1])
        if not grid.in_bounds(cell):
            raise where.error(
                line, f"{what} {list(cell)} is off the {grid.width}x{grid.height} map"
            )
        if not grid.is_free(cell):
            raise where.error(line, f"{what} {list(cell)} is on a wall or fixed obstacle")
        return cell

    hidden_line = where.key("hidden_obstacles")
    hidden = tuple(square(v, hidden_line, "hidden obstacle") for v in shape.hidden_obstacles)

    units: list[UnitSpec] = []
    taken: dict[Cell, str] = {}
    for i, u in enumerate(shape.units):
        line = where.table("units", i)
        if any(known.id == u.id for known in units):
            raise where.error(line, f"unit {u.id!r}: id used twice")
        start = square(u.start, line, f"unit {u.id!r}: start")
        if start in taken:
            raise where.error(
                line, f"unit {u.id!r}: start {list(start)} is taken by unit {taken[start]!r}"
            )
        if start in hidden:
            raise where.error(line, f"unit {u.id!r}: start {list(start)} is a hidden obstacle")
        taken[start] = u.id
        color = u.color or DEFAULT_COLORS[i % len(DEFAULT_COLORS)]
        battery = _battery(shape.battery, u.battery)
        units.append(UnitSpec(u.id, start, float(u.capacity), color, battery))

    jobs: list[JobSpec] = []
    for i, j in enumerate(shape.jobs):
        line = where.table("jobs", i)
        what = f"job #{i + 1}"
        pickup = square(j.pickup, line, f"{what}: pickup")
        dropoff = square(j.dropoff, line, f"{what}: dropoff")
        for name, cell in (("pickup", pickup), ("dropoff", dropoff)):
            if cell in hidden:
                raise where.error(line, f"{what}: {name} {list(cell)} is a hidden obstacle")
        if j.id is not None and any(known.id == j.id for known in jobs):
            raise where.error(line, f"{what}: id {j.id!r} used twice")
        jobs.append(JobSpec(pickup, dropoff, float(j.mass), j.priority, j.id))

    goals: list[GoalSpec] = []
    for i, g in enumerate(shape.goals):
        line = where.table("goals", i)
        if not any(u.id == g.unit for u in units):
            raise where.error(line, f"goal #{i + 1}: unknown unit {g.unit!r}")
        if any(known.unit == g.unit for known in goals):
            raise where.error(line, f"goal #{i + 1}: unit {g.unit!r} already has a goal")
        target = square(g.target, line, f"goal #{i + 1}: target")
        if target in hidden:
            raise where.error(line, f"goal #{i + 1}: target {list(target)} is a hidden obstacle")
        goals.append(GoalSpec(g.unit, target))

    chargers: list[ChargerSpec] = []
    for i, c in enumerate(shape.chargers):
        line = where.table("chargers", i)
        name = c.name if c.name is not None else f"C{i + 1}"
        what = f"charger {name!r}"
        at = square(c.square, line, f"{what}: square")
        if at in hidden:
            raise where.error(line, f"{what}: square {list(at)} is a hidden obstacle")
        for known in chargers:
            if known.name == name:
                raise where.error(line, f"{what}: name used twice")
            if known.square == at:
                raise where.error(
                    line, f"{what}: square {list(at)} already has charger {known.name!r}"
                )
        chargers.append(ChargerSpec(name, at))
    at_charger = {c.square: c.name for c in chargers}  # a unit may start on one; a job may not
    for i, job in enumerate(jobs):
        for what, cell in (("pickup", job.pickup), ("dropoff", job.dropoff)):
            if cell in at_charger:
                raise where.error(
                    where.table("jobs", i),
                    f"job #{i + 1}: {what} {list(cell)} is charger {at_charger[cell]!r}: "
                    "a unit charging there would block it",
                )

    graph = adjacency(grid) if units and chargers else None  # one graph for every charger
    for i, placed in enumerate(chargers):
        if graph is not None and not _reachable(grid, graph, placed.square, units):
            raise where.error(
                where.table("chargers", i),
                f"charger {placed.name!r}: square {list(placed.square)} cannot be reached from "
                "any unit's start (walled in)",
            )

    places = _places(shape.places, chargers, square, hidden, where)

    return Scenario(
        path=path,
        map_path=map_path,
        grid=grid,
        name=shape.name if shape.name is not None else path.stem,
        hidden_obstacles=hidden,
        units=tuple(units),
        jobs=tuple(jobs),
        goals=tuple(goals),
        description=shape.description,
        chargers=tuple(chargers),
        charging=_charging(shape.charging, where),
        places=places,
    )


def _places(
    tables: Sequence[_PlaceTable],
    chargers: Sequence[ChargerSpec],
    square: Callable[[list[int], int, str], Cell],
    hidden: Sequence[Cell],
    where: TomlFile[ScenarioError],
) -> tuple[PlaceSpec, ...]:
    """The [[places]] (each checked: a free square of its own, a name of its own, known kinds,
    a charger only where one is), then each charger that no place names or stands on, as a place
    of kind charger named by the charger's name."""
    if len(tables) > MAX_PLACES:
        raise where.error(
            where.table("places", MAX_PLACES),
            f"place #{MAX_PLACES + 1}: more than {MAX_PLACES} places (a map has at most {MAX_PLACES})",
        )
    at_charger = {c.square: c.name for c in chargers}
    by_name: dict[str, PlaceSpec] = {}
    by_square: dict[Cell, str] = {}
    for i, table in enumerate(tables):
        line = where.table("places", i)
        what = f"place {table.name!r}"
        if table.name in by_name:
            raise where.error(line, f"{what}: name used twice")
        at = square(table.square, line, f"{what}: square")
        if at in hidden:
            raise where.error(line, f"{what}: square {list(at)} is a hidden obstacle")
        if at in by_square:
            raise where.error(line, f"{what}: square {list(at)} is place {by_square[at]!r} already")
        twice = next((k for n, k in enumerate(table.kinds) if k in table.kinds[:n]), None)
        if twice is not None:
            raise where.error(line, f"{what}: kinds: {twice!r} given twice")
        charger = at_charger.get(at)
        if "charger" in table.kinds and charger is None:
            raise where.error(
                line, f"{what}: kind 'charger', but square {list(at)} has no charger ([[chargers]])"
            )
        carried = next((k for k in table.kinds if k in ("pickup", "dropoff")), None)
        if carried is not None and charger is not None:
            raise where.error(
                line,
                f"{what}: a {carried} on charger {charger!r} {list(at)}: a unit charging there "
                "would block it",
            )
        by_name[table.name] = PlaceSpec(table.name, at, tuple(table.kinds))
        by_square[at] = table.name
    offered = [c for c in chargers if c.name not in by_name and c.square not in by_square]
    if len(by_name) + len(offered) > MAX_PLACES:
        first = offered[MAX_PLACES - len(by_name)]
        index = next(i for i, c in enumerate(chargers) if c is first)
        raise where.error(
            where.table("chargers", index),
            f"charger {first.name!r}: more than {MAX_PLACES} places with the chargers (each "
            "charger is a place too, unless a place has its name or its square)",
        )
    places = list(by_name.values())
    places += [PlaceSpec(c.name, c.square, ("charger",)) for c in offered]
    return tuple(places)


def _reachable(grid: GridMap, graph: csr_matrix, square: Cell, units: Sequence[UnitSpec]) -> bool:
    """Whether any of `units` can drive from its start to `square` on the static map."""
    field = distance_field(grid, square, graph)
    return any(field[u.start.y, u.start.x] != UNREACHABLE for u in units)


def _battery(default: _BatteryTable | None, own: _BatteryTable | None) -> BatterySpec | None:
    """A unit's battery: the scenario's [battery], with the keys the unit gives its own."""
    if default is None and own is None:
        return None  # it never runs down: today's units
    merged = {
        **(default.model_dump(exclude_none=True) if default is not None else {}),
        **(own.model_dump(exclude_none=True) if own is not None else {}),
    }
    return BatterySpec(**{k: float(v) for k, v in merged.items()})


def _charging(table: _ChargingTable | None, where: TomlFile[ScenarioError]) -> ChargingSpec:
    """The thresholds of [charging], which must rise: critical < good <= sufficient <= full."""
    if table is None:
        return ChargingSpec()
    spec = ChargingSpec(
        float(table.critical_pct),
        float(table.good_pct),
        float(table.sufficient_pct),
        float(table.full_pct),
        table.available_from,
    )
    problem = thresholds_problem(spec)
    if problem is not None:
        raise where.error(where.section("charging"), f"[charging]: {problem}")
    return spec


def with_units(scenario: Scenario) -> Scenario:
    """`scenario`, when it has units to run; a map-only scenario raises ScenarioError."""
    if not scenario.units:
        raise ScenarioError(f"{scenario.path}: no units to run (add [[units]] tables)")
    return scenario
