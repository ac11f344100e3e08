"""Scenario files (TOML): a map plus hidden obstacles, units, jobs and goals."""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gridfleet.errors import MapError, ScenarioError
from gridfleet.grid import Cell, GridMap
from gridfleet.maps import load_map
from gridfleet.protocol.constants import ID_PATTERN
from gridfleet.textfile import read_text

_ID_RE = re.compile(ID_PATTERN)
_COLOR_RE = re.compile(r"^#[0-9a-fA-F]{6}$")
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


@dataclass(frozen=True)
class UnitSpec:
    """A unit of a scenario: id, start square, capacity (kg) and display colour."""

    id: str
    start: Cell
    capacity: float
    color: str


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

    def unit(self, unit_id: str) -> UnitSpec:
        """The unit with `unit_id`; KeyError when there is none."""
        for u in self.units:
            if u.id == unit_id:
                return u
        raise KeyError(unit_id)


_TOP_KEYS = {"map", "name", "description", "hidden_obstacles", "units", "jobs", "goals"}
_UNIT_KEYS = {"id", "start", "capacity", "color"}
_JOB_KEYS = {"pickup", "dropoff", "mass", "priority", "id"}
_GOAL_KEYS = {"unit", "target"}


class _Where:
    """Finds the line of a key or of the n-th `[[table]]` in the TOML text, for error messages."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.lines = text.splitlines()

    def key(self, key: str) -> int:
        pattern = re.compile(rf"^\s*{re.escape(key)}\s*=")
        return next((i for i, line in enumerate(self.lines, 1) if pattern.match(line)), 1)

    def table(self, name: str, index: int) -> int:
        pattern = re.compile(rf"^\s*\[\[\s*{re.escape(name)}\s*\]\]")
        hits = [i for i, line in enumerate(self.lines, 1) if pattern.match(line)]
        return hits[index] if index < len(hits) else self.key(name)

    def error(self, line: int, problem: str) -> ScenarioError:
        return ScenarioError(f"{self.path}:{line}: {problem}")


def load_scenario(path: str | Path) -> Scenario:
    """Load and validate a scenario; every problem raises ScenarioError naming file and line."""
    p = Path(path)
    text = read_text(p, "scenario", ScenarioError)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        match = re.search(r"line (\d+)", str(exc))
        end = str(max(1, len(text.splitlines())))
        line = match.group(1) if match else (end if "end of document" in str(exc) else "1")
        raise ScenarioError(f"{p}:{line}: not valid TOML: {exc}") from None
    return _build(p, data, _Where(p, text))


def _build(path: Path, data: dict[str, Any], where: _Where) -> Scenario:
    unknown = set(data) - _TOP_KEYS
    if unknown:
        key = sorted(unknown)[0]
        raise where.error(
            where.key(key), f"unknown key {key!r} (known: {', '.join(sorted(_TOP_KEYS))})"
        )
    if not isinstance(data.get("map"), str):
        raise where.error(where.key("map"), "'map' must name a .map file relative to this scenario")
    map_path = (path.parent / data["map"]).resolve()
    try:
        grid = load_map(map_path)
    except MapError as exc:
        raise where.error(where.key("map"), f"map {data['map']!r}: {exc}") from None

    def square(value: Any, line: int, what: str) -> Cell:
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        ):
            raise where.error(line, f"{what} must be [x, y] with whole numbers, got {value!r}")
        cell = Cell(value[0], value[1])
        if not grid.in_bounds(cell):
            raise where.error(
                line, f"{what} {list(cell)} is off the {grid.width}x{grid.height} map"
            )
        if not grid.is_free(cell):
            raise where.error(line, f"{what} {list(cell)} is on a wall or fixed obstacle")
        return cell

    def table_list(name: str) -> list[dict[str, Any]]:
        value = data.get(name, [])
        if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
            raise where.error(where.key(name), f"'{name}' must be a list of tables ([[{name}]])")
        return value

    def check_keys(table: dict[str, Any], known: set[str], line: int, what: str) -> None:
        extra = set(table) - known
        if extra:
            raise where.error(
                line,
                f"{what}: unknown key {sorted(extra)[0]!r} (known: {', '.join(sorted(known))})",
            )

    def number(table: dict[str, Any], key: str, line: int, what: str) -> float:
        value = table.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise where.error(line, f"{what}: '{key}' must be a number of kg, got {value!r}")
        if not value > 0 or value != value or value == float("inf"):
            raise where.error(line, f"{what}: '{key}' must be greater than 0, got {value!r}")
        return float(value)

    hidden_line = where.key("hidden_obstacles")
    raw_hidden = data.get("hidden_obstacles", [])
    if not isinstance(raw_hidden, list):
        raise where.error(hidden_line, "'hidden_obstacles' must be a list of [x, y] squares")
    hidden = tuple(square(v, hidden_line, "hidden obstacle") for v in raw_hidden)

    units: list[UnitSpec] = []
    taken: dict[Cell, str] = {}
    for i, t in enumerate(table_list("units")):
        line = where.table("units", i)
        check_keys(t, _UNIT_KEYS, line, f"unit #{i + 1}")
        uid = t.get("id")
        if not isinstance(uid, str) or not _ID_RE.match(uid):
            raise where.error(
                line,
                f"unit #{i + 1}: id {uid!r} is not a valid id (letters, digits,"
                " '_', '.', '-'; no '/ + # $')",
            )
        if any(u.id == uid for u in units):
            raise where.error(line, f"unit {uid!r}: id used twice")
        start = square(t.get("start"), line, f"unit {uid!r}: start")
        if start in taken:
            raise where.error(
                line, f"unit {uid!r}: start {list(start)} is taken by unit {taken[start]!r}"
            )
        if start in hidden:
            raise where.error(line, f"unit {uid!r}: start {list(start)} is a hidden obstacle")
        taken[start] = uid
        capacity = number(t, "capacity", line, f"unit {uid!r}")
        color = t.get("color", DEFAULT_COLORS[i % len(DEFAULT_COLORS)])
        if not isinstance(color, str) or not _COLOR_RE.match(color):
            raise where.error(line, f"unit {uid!r}: color {color!r} is not #rrggbb")
        units.append(UnitSpec(uid, start, capacity, color))

    jobs: list[JobSpec] = []
    for i, t in enumerate(table_list("jobs")):
        line = where.table("jobs", i)
        what = f"job #{i + 1}"
        check_keys(t, _JOB_KEYS, line, what)
        pickup = square(t.get("pickup"), line, f"{what}: pickup")
        dropoff = square(t.get("dropoff"), line, f"{what}: dropoff")
        for name, cell in (("pickup", pickup), ("dropoff", dropoff)):
            if cell in hidden:
                raise where.error(line, f"{what}: {name} {list(cell)} is a hidden obstacle")
        mass = number(t, "mass", line, what)
        priority = t.get("priority", 0)
        if isinstance(priority, bool) or not isinstance(priority, int) or not 0 <= priority <= 100:
            raise where.error(
                line, f"{what}: priority must be a whole number 0..100, got {priority!r}"
            )
        job_id = t.get("id")
        if job_id is not None and (not isinstance(job_id, str) or not _ID_RE.match(job_id)):
            raise where.error(line, f"{what}: id {job_id!r} is not a valid id")
        if job_id is not None and any(j.id == job_id for j in jobs):
            raise where.error(line, f"{what}: id {job_id!r} used twice")
        jobs.append(JobSpec(pickup, dropoff, mass, priority, job_id))

    goals: list[GoalSpec] = []
    for i, t in enumerate(table_list("goals")):
        line = where.table("goals", i)
        check_keys(t, _GOAL_KEYS, line, f"goal #{i + 1}")
        uid = t.get("unit")
        if not any(u.id == uid for u in units):
            raise where.error(line, f"goal #{i + 1}: unknown unit {uid!r}")
        if any(g.unit == uid for g in goals):
            raise where.error(line, f"goal #{i + 1}: unit {uid!r} already has a goal")
        target = square(t.get("target"), line, f"goal #{i + 1}: target")
        if target in hidden:
            raise where.error(line, f"goal #{i + 1}: target {list(target)} is a hidden obstacle")
        goals.append(GoalSpec(str(uid), target))

    name = data.get("name", path.stem)
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise where.error(where.key("name"), "'name' and 'description' must be strings")
    return Scenario(
        path=path,
        map_path=map_path,
        grid=grid,
        name=name,
        hidden_obstacles=hidden,
        units=tuple(units),
        jobs=tuple(jobs),
        goals=tuple(goals),
        description=description,
    )


def with_units(scenario: Scenario) -> Scenario:
    """`scenario`, when it has units to run; a map-only scenario raises ScenarioError."""
    if not scenario.units:
        raise ScenarioError(f"{scenario.path}: no units to run (add [[units]] tables)")
    return scenario
