"""Every shipped scenario loads and is solvable: all squares it uses connect, hidden obstacles included."""

from __future__ import annotations

from pathlib import Path

import pytest

from gridfleet.paths import UNREACHABLE, DistanceFieldCache
from gridfleet.scenario import load_scenario

from support.paths import MAPS

SCENARIOS = sorted(MAPS.glob("*.toml"))


def test_at_least_six_scenarios_ship() -> None:
    names = {p.stem for p in SCENARIOS}
    assert {"playfield", "corridor", "crossing", "maze", "warehouse", "heavy"} <= names


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_every_used_square_is_reachable_from_every_unit(path: Path) -> None:
    s = load_scenario(path)
    truth = s.grid.with_blocked(s.hidden_obstacles)
    fields = DistanceFieldCache(truth)
    squares = [j.pickup for j in s.jobs] + [j.dropoff for j in s.jobs]
    squares += [g.target for g in s.goals]
    for unit in s.units:
        for square in squares:
            assert fields.distance(unit.start, square) != UNREACHABLE, (unit.id, square)
