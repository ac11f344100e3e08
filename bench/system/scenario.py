"""The system bench's scenario: a square-ish open map with pillars, and N units spread over it."""

from __future__ import annotations

import math
import random
from pathlib import Path

from gridfleet.grid import Cell, GridMap
from gridfleet.maps import format_map
from gridfleet.scenario import Scenario, load_scenario

FILL = 0.125  # units take ~12.5 % of the free squares: busy, but room to pass
PILLAR_CHANCE = 0.6  # of the squares where a pillar may stand
CAPACITY_KG = 10.0


def bench_grid(units: int, seed: int) -> GridMap:
    """A map with room for `units` at ~12.5 % fill; single-square pillars never cut it apart."""
    rng = random.Random(seed)
    # Pillars stand only on squares with x % 3 == 1 and y % 3 == 1, at most 1/9 of the map.
    wanted_free = math.ceil(units / FILL)
    side = max(5, math.ceil(math.sqrt(wanted_free / (1 - PILLAR_CHANCE / 9))))
    width, height = side + side // 4, max(5, side - side // 5)  # square-ish, not square
    while width * height * (1 - PILLAR_CHANCE / 9) < wanted_free:
        width += 1
    # A pillar's eight neighbours are free, so the free squares stay one connected region.
    rows = [
        "".join(
            "@"
            if x % 3 == 1
            and y % 3 == 1
            and 0 < x < width - 1
            and 0 < y < height - 1
            and rng.random() < PILLAR_CHANCE
            else "."
            for x in range(width)
        )
        for y in range(height)
    ]
    return GridMap.from_rows(rows, name=f"bench-{units}")


def make_scenario(units: int, seed: int, directory: Path) -> Scenario:
    """Write the bench's map and scenario into `directory` and load them (validated)."""
    grid = bench_grid(units, seed)
    rng = random.Random(seed + 1)
    starts: list[Cell] = rng.sample(grid.free_cells(), units)
    (directory / "bench.map").write_text(format_map(grid), encoding="utf-8")
    lines = [
        f'name = "bench-{units}"',
        f'description = "system bench: {units} units, seed {seed}"',
        'map = "bench.map"',
    ]
    for n, start in enumerate(starts, start=1):
        lines += [
            "",
            "[[units]]",
            f'id = "u{n:03d}"',
            f"start = [{start.x}, {start.y}]",
            f"capacity = {CAPACITY_KG}",
        ]
    path = directory / "bench.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return load_scenario(path)
