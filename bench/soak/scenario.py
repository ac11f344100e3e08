"""The soak's scenario: the shipped warehouse (else the playfield) scaled to N units."""

from __future__ import annotations

import random
import shutil
from pathlib import Path

from gridfleet.grid import Cell
from gridfleet.scenario import Scenario, load_scenario
from gridfleet.shipped import shipped_dir

MAPS = shipped_dir()  # the shipped scenarios: the checkout's maps/, or a wheel's


def base_scenario() -> Scenario:
    """The warehouse when it is shipped, else the playfield."""
    for name in ("warehouse", "playfield"):
        if (MAPS / f"{name}.toml").exists():
            return load_scenario(MAPS / f"{name}.toml")
    raise FileNotFoundError(f"no warehouse or playfield scenario in {MAPS}")


def make_soak_scenario(units: int, seed: int, directory: Path) -> Scenario:
    """Write the base scenario with `units` units into `directory` and load it (validated).

    Fewer units than the base: its first ones. More: extra units on random free squares, with the
    base's capacities in turn. Jobs: the base's that one of the units can carry, at most 2 per
    unit (the feed keeps more coming).
    """
    base = base_scenario()
    rng = random.Random(seed)
    specs = [(u.id, u.start, u.capacity) for u in base.units[:units]]
    taken: set[Cell] = {s for _, s, _ in specs} | set(base.hidden_obstacles)
    spare = [c for c in base.grid.free_cells() if c not in taken]
    rng.shuffle(spare)
    for n in range(len(specs), units):
        capacity = base.units[n % len(base.units)].capacity
        specs.append((f"s{n + 1:03d}", spare.pop(), capacity))
    heaviest = max(c for _, _, c in specs)
    jobs = [j for j in base.jobs if j.mass <= heaviest][: 2 * units]
    shutil.copy(base.map_path, directory / base.map_path.name)
    lines = [
        f'name = "soak-{base.name}-{units}"',
        f'description = "chaos soak: {base.name} with {units} units"',
        f'map = "{base.map_path.name}"',
        f"hidden_obstacles = {[[c.x, c.y] for c in base.hidden_obstacles]}",
    ]
    for uid, start, capacity in specs:
        lines += ["", "[[units]]", f'id = "{uid}"', f"start = [{start.x}, {start.y}]"]
        lines += [f"capacity = {capacity}"]
    for job in jobs:
        lines += ["", "[[jobs]]", f"pickup = [{job.pickup.x}, {job.pickup.y}]"]
        lines += [f"dropoff = [{job.dropoff.x}, {job.dropoff.y}]", f"mass = {job.mass}"]
    path = directory / "soak.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return load_scenario(path)
