"""Moving AI `.map` files: load and save, with errors that name the file, line and problem."""

from __future__ import annotations

from pathlib import Path

from gridfleet.errors import MapError
from gridfleet.grid import BLOCKED_CHARS, FREE_CHARS, GridMap
from gridfleet.shipped import resolve
from gridfleet.textfile import read_text

MAX_MAP_SIDE = 4096


def parse_map(text: str, source: str = "<map>") -> GridMap:
    """Parse the text of a Moving AI map (`type`, `height`, `width`, `map`, then rows)."""
    lines = text.splitlines()
    header: dict[str, str] = {}
    body_start = None
    for number, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line:
            continue
        if line == "map":
            body_start = number
            break
        key, _, value = line.partition(" ")
        if key not in ("type", "height", "width"):
            raise MapError(
                f"{source}:{number}: unknown header line {line!r} "
                "(expected 'type', 'height', 'width' then 'map')"
            )
        header[key] = value.strip()
    if body_start is None:
        raise MapError(f"{source}: no 'map' line: not a Moving AI map file")
    height = _dimension(header, "height", source)
    width = _dimension(header, "width", source)
    rows = lines[body_start : body_start + height]
    if len(rows) < height:
        raise MapError(f"{source}: header says height {height} but only {len(rows)} rows follow")
    for offset, row in enumerate(rows):
        number = body_start + 1 + offset
        row = row.rstrip("\r")
        if len(row) != width:
            raise MapError(
                f"{source}:{number}: row has {len(row)} squares, header says width {width}"
            )
        for col, ch in enumerate(row):
            if ch not in FREE_CHARS and ch not in BLOCKED_CHARS:
                raise MapError(f"{source}:{number}: unknown character {ch!r} in column {col}")
    extra = [
        n for n, r in enumerate(lines[body_start + height :], body_start + height + 1) if r.strip()
    ]
    if extra:
        raise MapError(f"{source}:{extra[0]}: more rows than the header's height {height}")
    return GridMap.from_rows((r.rstrip("\r") for r in rows), name=Path(source).stem)


def _dimension(header: dict[str, str], key: str, source: str) -> int:
    if key not in header:
        raise MapError(f"{source}: header has no '{key}' line")
    try:
        value = int(header[key])
    except ValueError:
        raise MapError(f"{source}: {key} {header[key]!r} is not a whole number") from None
    if not 1 <= value <= MAX_MAP_SIDE:
        raise MapError(f"{source}: {key} {value} is outside 1..{MAX_MAP_SIDE}")
    return value


def load_map(path: str | Path) -> GridMap:
    """Load a `.map` file, or a shipped map by name (`playfield`); every problem raises MapError
    naming the file."""
    p = resolve(path, ".map", "map", MapError)
    return parse_map(read_text(p, "map", MapError), source=str(p))


def format_map(grid: GridMap) -> str:
    """The Moving AI text of `grid`."""
    body = "\n".join(grid.rows())
    return f"type octile\nheight {grid.height}\nwidth {grid.width}\nmap\n{body}\n"
