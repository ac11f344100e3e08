"""Public benchmark data: League of Robot Runners lifelong instances and Moving AI scenarios.

Both formats give squares as (row, col) or (x, y) in their own ways; everything here returns
gridfleet `Cell(x, y)` with x the column. Every problem raises ConfigError naming the file.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gridfleet.errors import ConfigError, MapError
from gridfleet.grid import Cell, GridMap
from gridfleet.maps import load_map
from gridfleet.textfile import read_text

ANCHORS_ENV = "GRIDFLEET_ANCHORS"


@dataclass(frozen=True)
class LifelongInstance:
    """A lifelong MAPF instance: agents start on tasks 0..n-1 and take the next task when done."""

    name: str
    grid: GridMap
    starts: tuple[Cell, ...]
    tasks: tuple[tuple[Cell, ...], ...]  # in reveal order; each task is errands visited in order
    horizon: int
    best_tasks_finished: int | None = None  # the competition's best, for reference
    action_model: str = "4-connected"
    # MR24: this many tasks are known at the start and one more each time one is finished, and
    # any agent may take any known task (None: MR23, agent i takes task i, then the next)
    open_tasks: int | None = None

    @property
    def agents(self) -> int:
        """How many agents the instance has."""
        return len(self.starts)


@dataclass(frozen=True)
class ScenAgent:
    """One agent of a Moving AI scenario: start and goal."""

    start: Cell
    goal: Cell


def find_anchors(given: str | Path | None) -> Path:
    """The benchmark data folder: `given`, else $GRIDFLEET_ANCHORS, else shared/anchors beside
    the checkout (or beside the current folder)."""
    if given or os.environ.get(ANCHORS_ENV):
        candidates = [Path(given or os.environ[ANCHORS_ENV])]
    else:
        checkout = Path(__file__).resolve().parents[1]
        beside = [p.parent / "shared" / "anchors" for p in (checkout, Path.cwd().resolve())]
        candidates = list(dict.fromkeys(beside))  # run from the checkout: the same folder twice
    for folder in candidates:
        if (folder / "maps").is_dir():
            return folder
    raise ConfigError(
        f"no benchmark data in {' or '.join(map(str, candidates))} (it needs maps/ and "
        f"instances/): pass --anchors DIR or set {ANCHORS_ENV}; see bench/README.md"
    )


def _cells(value: Any, where: str, grid: GridMap) -> tuple[Cell, ...]:
    """[[row, col], ...] as cells, each checked to be a free square of `grid`."""
    if not isinstance(value, list):
        raise ConfigError(f"{where}: expected a list of [row, col], got {type(value).__name__}")
    out = []
    for item in value:
        ok = isinstance(item, list) and len(item) == 2
        if not ok or not all(isinstance(v, int) and not isinstance(v, bool) for v in item):
            raise ConfigError(f"{where}: expected [row, col] with whole numbers, got {item!r}")
        cell = Cell(item[1], item[0])
        if not grid.is_free(cell):
            raise ConfigError(f"{where}: [row, col] {item} is not a free square of {grid.name}")
        out.append(cell)
    return tuple(out)


def load_instance(path: str | Path, maps: Path | None = None) -> LifelongInstance:
    """Load a lifelong instance (JSON, see anchors/README.md); its map is looked up in `maps`."""
    p = Path(path)
    try:
        data = json.loads(read_text(p, "instance", ConfigError))
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{p}: not a readable JSON instance: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a JSON object")
    for key in ("map", "starts", "tasks", "horizon"):
        if key not in data:
            raise ConfigError(f"{p}: no '{key}' (an instance needs map, starts, tasks, horizon)")
    map_dir = maps if maps is not None else p.parent.parent / "maps"
    try:
        grid = load_map(map_dir / str(data["map"]))
    except MapError as exc:
        raise ConfigError(f"{p}: its map: {exc}") from None
    starts = _cells(data["starts"], f"{p}: starts", grid)
    if len(set(starts)) != len(starts):
        raise ConfigError(f"{p}: two agents start on one square")
    if not isinstance(data["tasks"], list):
        raise ConfigError(f"{p}: 'tasks' must be a list of tasks")
    tasks = tuple(_cells(t, f"{p}: task {i}", grid) for i, t in enumerate(data["tasks"]))
    if len(tasks) < len(starts) or any(not t for t in tasks):
        raise ConfigError(f"{p}: needs a non-empty task for every agent to start on")
    horizon = data["horizon"]
    if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1:
        raise ConfigError(f"{p}: 'horizon' must be a whole number of ticks > 0, got {horizon!r}")
    best = data.get("best_tasks_finished")
    reveal = data.get("task_reveal_t")
    if reveal is not None and (
        not isinstance(reveal, list) or not all(isinstance(t, int) for t in reveal)
    ):
        raise ConfigError(f"{p}: 'task_reveal_t' must be a list of ticks, got {reveal!r:.60}")
    return LifelongInstance(
        name=str(data.get("name", p.stem)),
        grid=grid,
        starts=starts,
        tasks=tasks,
        horizon=horizon,
        best_tasks_finished=best if isinstance(best, int) else None,
        action_model=str(data.get("action_model", "4-connected")),
        open_tasks=None if reveal is None else max(len(starts), reveal.count(0)),
    )


def lifelong_instances(anchors: Path) -> list[Path]:
    """The instance files of `anchors` that carry a task stream, by name."""
    found = []
    for path in sorted((anchors / "instances").glob("*.json")):
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            found.append(path)  # let load_instance name the problem
            continue
        if isinstance(data, dict) and data.get("tasks"):
            found.append(path)
    return found


def load_scen(path: str | Path, maps: Path | None = None) -> tuple[GridMap, list[ScenAgent]]:
    """The map and agents of a Moving AI `.scen` file (version 1; x = column, y = row).

    The map is the one the scenario names, looked up in `maps` (default: the scenario's folder).
    """
    p = Path(path)
    lines = read_text(p, "scenario", ConfigError).splitlines()
    if not lines or not lines[0].startswith("version"):
        raise ConfigError(f"{p}:1: expected 'version 1'")
    agents = []
    grid: GridMap | None = None
    for n, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        fields = line.split("\t")
        if len(fields) < 8:
            raise ConfigError(f"{p}:{n}: expected 9 tab-separated fields, got {len(fields)}")
        if grid is None:
            try:
                grid = load_map((maps if maps is not None else p.parent) / fields[1])
            except MapError as exc:
                raise ConfigError(f"{p}:{n}: its map: {exc}") from None
        try:
            sx, sy, gx, gy = (int(v) for v in fields[4:8])
        except ValueError:
            raise ConfigError(f"{p}:{n}: start and goal must be whole numbers") from None
        start, goal = Cell(sx, sy), Cell(gx, gy)
        for what, cell in (("start", start), ("goal", goal)):
            if not grid.is_free(cell):
                raise ConfigError(f"{p}:{n}: {what} {list(cell)} is not free on {grid.name}")
        agents.append(ScenAgent(start, goal))
    if grid is None:
        raise ConfigError(f"{p}: no agents")
    return grid, agents
