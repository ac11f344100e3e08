"""Every shipped scenario loads and is solvable (all squares it uses connect, hidden obstacles included) and loads by its name from anywhere."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from gridfleet.errors import MapError, ScenarioError
from gridfleet.maps import load_map
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
    squares += [g.target for g in s.goals] + [p.square for p in s.places]
    for unit in s.units:
        for square in squares:
            assert fields.distance(unit.start, square) != UNREACHABLE, (unit.id, square)


def test_the_warehouses_name_their_places_alike_and_the_energy_ones_their_chargers_too() -> None:
    plain, energy = load_scenario(MAPS / "warehouse.toml"), load_scenario("warehouse-energy")
    kinds = {k for p in plain.places for k in p.kinds}
    assert kinds == {"pickup", "dropoff", "parking"} and len(plain.places) == 72
    chargers = tuple(p for p in energy.places if p.kinds == ("charger",))
    assert [(p.name, p.square) for p in chargers] == [(c.name, c.square) for c in energy.chargers]
    assert energy.places == plain.places + chargers
    assert {p.name for p in load_scenario("playfield").places} == {
        "A1", "A2", "A3", "A4", "P1", "P2", "P3", "P4",
    }  # fmt: skip


def test_a_shipped_scenario_or_map_loads_by_name_from_anywhere(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # no maps/ here
    scenario = load_scenario("playfield")
    assert scenario.path == MAPS / "playfield.toml" and scenario.map_path == MAPS / "playfield.map"
    assert load_map("maze").rows() == load_map(MAPS / "maze.map").rows()


def test_a_path_that_exists_wins_over_a_shipped_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    shutil.copy(MAPS / "corridor.toml", tmp_path / "playfield")
    shutil.copy(MAPS / "corridor.map", tmp_path / "corridor.map")
    assert load_scenario("playfield").name == "corridor"


def test_an_unknown_name_is_refused_naming_the_shipped_ones() -> None:
    with pytest.raises(ScenarioError) as scenario:
        load_scenario("nowhere")
    assert str(scenario.value) == (
        "nowhere: no such scenario file, and no shipped scenario of that name "
        "(corridor, crossing, heavy, maze, playfield, playfield-energy, warehouse, warehouse-energy)"
    )
    with pytest.raises(MapError) as grid:
        load_map("nowhere")
    assert str(grid.value) == (
        "nowhere: no such map file, and no shipped map of that name "
        "(corridor, crossing, maze, playfield, warehouse)"
    )


def test_a_path_stays_a_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # playfield.toml is no name: not the shipped one
    with pytest.raises(ScenarioError, match=r"^playfield\.toml: no such scenario file$"):
        load_scenario("playfield.toml")
    with pytest.raises(MapError, match=r"^maps/playfield\.map: no such map file$"):
        load_map("maps/playfield.map")
