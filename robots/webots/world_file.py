"""A Webots world for a scenario, as text: the arena, its obstacles and one grid unit per unit.

Pure: a scenario and options in, the `.wbt` text out (`robots.webots.cli` writes it). The arena
is the course's: a RectangleArena whose floor holds every square of the map, its chequered tiles
0.2 m (four squares each) so that each square of 0.1 m shows, translated so that the centre of
square (0, 0) is the origin (`geometry`). Blocked squares of the map and the scenario's hidden
obstacles stand as `GridObstacle`s (the fleet still has to sense the hidden ones: only their
colour differs here), and each unit of the scenario as a `GridUnit` on its start square, in its
colour, with its capacity, the map, its battery, the chargers and where to find the broker in its
fields. A world may run
some units only: the others are there as mirrors, following their state (they run elsewhere:
in another Webots, or as simulated units), so that this world shows them and its units' sensors
see them.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol.constants import DEFAULT_ROOT, DEFAULT_STEP_S
from gridfleet.robots.webots.geometry import (
    BLOCK_HEIGHT_M,
    OBSTACLE_SIDE_M,
    SQUARE_M,
    UNIT_SIZE_M,
    arena_centre,
    metres,
    sf_color,
)
from gridfleet.robots.webots.settings import BATTERY_FIELDS
from gridfleet.scenario import Scenario

WEBOTS_VERSION = "R2023b"
WEBOTS_OBJECTS = (
    f"https://raw.githubusercontent.com/cyberbotics/webots/{WEBOTS_VERSION}/projects/objects"
)
BASIC_TIME_STEP_MS = 32
FLOOR_TILE_M = 2 * SQUARE_M  # the chequered texture has 2 x 2 squares per tile (the course)
FIXED_COLOR = "#737373"
HIDDEN_COLOR = "#8d6e63"
TOP_VIEW = "-0.5773 0.5773 0.5773 2.0944"  # looking straight down, north up, east right


@dataclass(frozen=True)
class WorldOptions:
    """What a world says beyond its scenario: where its PROTOs are and how its units connect."""

    protos: str = "../protos"  # the folder of GridUnit.proto, relative to the world file
    source: str = ""  # the scenario file as the world names it (its info)
    units: Sequence[str] | None = None  # run only these units, mirror the others (None: run all)
    brokers: Mapping[str, str] = field(default_factory=dict)  # per unit; "" or absent: default
    root: str = DEFAULT_ROOT
    step_s: float = DEFAULT_STEP_S


def world_text(scenario: Scenario, options: WorldOptions = WorldOptions()) -> str:
    """The `.wbt` text of `scenario`; ConfigError for a unit the scenario does not have."""
    known = [u.id for u in scenario.units]
    chosen = known if options.units is None else list(options.units)
    for uid in chosen:
        if uid not in known:
            raise ConfigError(
                f"unknown unit {uid!r}: scenario {scenario.name!r} has {', '.join(known) or 'none'}"
            )
    grid = scenario.grid
    cx, cy = arena_centre(grid)
    extent = max(grid.width, grid.height) * SQUARE_M
    lines = [f"#VRML_SIM {WEBOTS_VERSION} utf8", ""]
    lines += [
        f'EXTERNPROTO "{WEBOTS_OBJECTS}/backgrounds/protos/TexturedBackground.proto"',
        f'EXTERNPROTO "{WEBOTS_OBJECTS}/backgrounds/protos/TexturedBackgroundLight.proto"',
        f'EXTERNPROTO "{WEBOTS_OBJECTS}/floors/protos/RectangleArena.proto"',
        f'EXTERNPROTO "{options.protos}/GridObstacle.proto"',
        f'EXTERNPROTO "{options.protos}/GridUnit.proto"',
        "",
    ]
    about = f": {scenario.description}" if scenario.description else ""
    info = [f"gridfleet scenario {scenario.name}{about}"]
    made_by = "gridfleet webots-world" + (f" {options.source}" if options.source else "")
    info.append(f"Written by {made_by}; write it again rather than edit it.")
    lines += _node(
        "WorldInfo",
        [
            ("info", _strings(info)),
            ("title", _string(f"gridfleet {scenario.name}")),
            ("basicTimeStep", str(BASIC_TIME_STEP_MS)),
        ],
    )
    # High enough that a 45 degree view holds the whole floor with a margin.
    lines += _node(
        "Viewpoint",
        [("orientation", TOP_VIEW), ("position", _vec(cx, cy, round(extent * 1.4, 3)))],
    )
    lines += _node("TexturedBackground", [])
    lines += _node("TexturedBackgroundLight", [])
    lines += _node(
        "RectangleArena",
        [
            ("translation", _vec(cx, cy, 0)),
            ("floorSize", _vec(grid.width * SQUARE_M, grid.height * SQUARE_M)),
            ("floorTileSize", _vec(FLOOR_TILE_M, FLOOR_TILE_M)),
            ("wallHeight", _num(BLOCK_HEIGHT_M)),
        ],
    )
    hidden = set(scenario.hidden_obstacles)
    fixed = [c for c in _squares(grid.width, grid.height) if not grid.is_free(c)]
    for cell in fixed:
        lines += _obstacle(cell, f"obstacle {cell.x},{cell.y}", FIXED_COLOR)
    for cell in sorted(hidden, key=lambda c: (c.y, c.x)):
        lines += _obstacle(cell, f"hidden obstacle {cell.x},{cell.y}", HIDDEN_COLOR)
    rows = grid.rows()
    chargers = [f"{c.square.x} {c.square.y}" for c in scenario.chargers]
    for unit in scenario.units:
        fields: list[tuple[str, str | list[str]]] = [
            ("translation", _vec(*metres(unit.start), UNIT_SIZE_M / 2)),
            ("name", _string(unit.id)),
            ("color", _vec(*sf_color(unit.color))),
            ("capacity", _num(unit.capacity)),
            ("stepPeriod", _num(options.step_s)),
            ("map", _strings(rows)),
        ]
        broker = options.brokers.get(unit.id, "")
        if broker:
            fields.append(("broker", _string(broker)))
        if options.root != DEFAULT_ROOT:
            fields.append(("root", _string(options.root)))
        if unit.id not in chosen:
            fields.append(("mirror", "TRUE"))
        b = unit.battery
        if b is not None:
            fields.append(("battery", "TRUE"))
            for name, value in zip(
                BATTERY_FIELDS,
                (b.start_pct, b.move_pct, b.idle_pct_per_s, b.charge_pct_per_s),
                strict=True,
            ):
                fields.append((name, f"{value:.10g}"))  # a rate may be a small fraction
        if chargers:
            fields.append(("chargers", chargers))
        lines += _node("GridUnit", fields)
    return "\n".join(lines) + "\n"


def _squares(width: int, height: int) -> Iterable[Cell]:
    """Every square, row by row."""
    return (Cell(x, y) for y in range(height) for x in range(width))


def _obstacle(cell: Cell, name: str, color: str) -> list[str]:
    return _node(
        "GridObstacle",
        [
            ("translation", _vec(*metres(cell), BLOCK_HEIGHT_M / 2)),
            ("name", _string(name)),
            ("size", _vec(OBSTACLE_SIDE_M, OBSTACLE_SIDE_M, BLOCK_HEIGHT_M)),
            ("color", _vec(*sf_color(color))),
        ],
    )


def _node(kind: str, fields: Sequence[tuple[str, str | list[str]]]) -> list[str]:
    """A top-level node, one field a line (a multi-line value indented under its field)."""
    lines = [f"{kind} {{"]
    for name, value in fields:
        if isinstance(value, str):
            lines.append(f"  {name} {value}")
        else:
            lines.append(f"  {name} [")
            lines += [f"    {item}" for item in value]
            lines.append("  ]")
    lines.append("}")
    return lines


def _num(value: float) -> str:
    """A number as Webots writes one: no trailing zeros, never -0."""
    text = f"{value:.4f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _vec(*values: float) -> str:
    return " ".join(_num(v) for v in values)


def _string(text: str) -> str:
    """A VRML string: quoted, with quotes and backslashes escaped."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _strings(texts: Sequence[str]) -> list[str]:
    return [_string(t) for t in texts]
