"""A busy scenario for `gridfleet simulate`: the system bench's map and units, plus random jobs.

`python -m gridfleet.bench.busy_scenario DIR [--units 16] [--jobs 40] [--seed 1]` writes `DIR/bench.toml`
(and its map) for the overload run of bench/README.md (requests under a loaded broker).
"""

from __future__ import annotations

import argparse
import random
from pathlib import Path

from gridfleet.bench.system.scenario import CAPACITY_KG, make_scenario
from gridfleet.scenario import Scenario, load_scenario


def make_busy(units: int, jobs: int, seed: int, directory: Path) -> Scenario:
    """The bench scenario of `units` in `directory`, with `jobs` random jobs every unit can carry."""
    scenario = make_scenario(units, seed, directory)
    rng = random.Random(seed + 2)
    free = scenario.grid.free_cells()
    lines = []
    for _ in range(jobs):
        pickup, dropoff = rng.sample(free, 2)
        mass = round(rng.uniform(0.5, CAPACITY_KG), 1)
        lines += [
            "",
            "[[jobs]]",
            f"pickup = [{pickup.x}, {pickup.y}]",
            f"dropoff = [{dropoff.x}, {dropoff.y}]",
            f"mass = {mass}",
        ]
    path = directory / "bench.toml"
    with path.open("a", encoding="utf-8") as out:
        out.write("\n".join(lines) + "\n")
    return load_scenario(path)


def main() -> None:
    """Write the scenario and say where."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", type=Path)
    parser.add_argument("--units", type=int, default=16)
    parser.add_argument("--jobs", type=int, default=40)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    args.directory.mkdir(parents=True, exist_ok=True)
    scenario = make_busy(args.units, args.jobs, args.seed, args.directory)
    print(
        f"{args.directory / 'bench.toml'}: {len(scenario.units)} units, {len(scenario.jobs)} jobs"
    )


if __name__ == "__main__":
    main()
