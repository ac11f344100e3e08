"""Maps and scenarios load, and every kind of bad file fails with one clear line."""

from __future__ import annotations

from pathlib import Path

import pytest

from gridfleet.errors import MapError, ScenarioError
from gridfleet.grid import Cell, GridMap
from gridfleet.maps import format_map, load_map, parse_map
from gridfleet.scenario import (
    BatterySpec,
    ChargerSpec,
    ChargingSpec,
    load_scenario,
    with_units,
)

ANCHORS = Path(__file__).resolve().parents[3] / "shared" / "anchors" / "maps"
MAP = "type octile\nheight 3\nwidth 4\nmap\n....\n.@..\n....\n"


def test_playfield_loads(playfield: Path) -> None:
    s = load_scenario(playfield)
    assert (s.grid.width, s.grid.height) == (10, 10)
    assert len(s.units) == 4 and len({u.capacity for u in s.units}) == 4
    assert len(s.hidden_obstacles) == 2 and s.jobs
    for cell in s.hidden_obstacles:
        assert s.grid.is_free(cell), "hidden obstacles are not on the static map"
    assert s.unit("unit1").start == Cell(0, 0)


def test_map_round_trips_and_reads_walls() -> None:
    grid = parse_map(MAP)
    assert not grid.is_free(Cell(1, 1)) and grid.is_free(Cell(0, 0))
    assert not grid.is_free(Cell(-1, 0)) and not grid.is_free(Cell(4, 0)), "off the map is wall"
    assert parse_map(format_map(grid)).rows() == grid.rows()


@pytest.mark.skipif(not ANCHORS.exists(), reason="shared anchors not beside the checkout")
def test_public_benchmark_maps_load() -> None:
    grid = load_map(ANCHORS / "random-32-32-20.map")
    assert (grid.width, grid.height) == (32, 32)
    assert len(grid.free_cells()) == 819


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("type octile\nheight 3\nwidth 4\nmap\n....\n.X..\n....\n", ":6: unknown character 'X'"),
        ("type octile\nheight 3\nwidth 4\nmap\n....\n...\n....\n", ":6: row has 3 squares"),
        ("type octile\nheight 3\nwidth 4\nmap\n....\n....\n", "only 2 rows"),
        ("type octile\nheight 2\nwidth 4\nmap\n....\n....\n....\n", ":7: more rows"),
        ("type octile\nheight x\nwidth 4\nmap\n....\n", "height 'x' is not a whole number"),
        ("type octile\nwidth 4\nmap\n....\n", "no 'height'"),
        ("hello\n", ":1: unknown header line"),
        ("type octile\nheight 1\nwidth 1\n", "no 'map' line"),
    ],
)
def test_bad_maps_fail_with_one_clear_line(tmp_path: Path, text: str, problem: str) -> None:
    path = tmp_path / "bad.map"
    path.write_text(text)
    with pytest.raises(MapError) as info:
        load_map(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message and problem in message


UNIT = '[[units]]\nid = "u1"\nstart = [0, 0]\ncapacity = 5.0\n'


@pytest.mark.parametrize(
    ("body", "line", "problem"),
    [
        ('map = "m.map"\n' + UNIT.replace("[0, 0]", "[1, 1]"), 2, "is on a wall"),
        ('map = "m.map"\n' + UNIT + UNIT.replace('"u1"', '"u2"'), 6, "is taken by unit 'u1'"),
        ('map = "m.map"\n' + UNIT + UNIT, 6, "id used twice"),
        ('map = "m.map"\n' + UNIT.replace("[0, 0]", "[4, 0]"), 2, "off the 4x3 map"),
        ('map = "m.map"\n' + UNIT.replace("[0, 0]", "[0]"), 2, "must be [x, y]"),
        ('map = "m.map"\n' + UNIT.replace("5.0", "0"), 2, "'capacity' must be greater than 0"),
        ('map = "m.map"\n' + UNIT.replace('"u1"', '"u/1"'), 2, "not a valid id"),
        (
            'map = "m.map"\n[[jobs]]\npickup = [0, 0]\ndropoff = [3, 2]\nmass = 0\n',
            2,
            "'mass' must be greater than 0",
        ),
        (
            'map = "m.map"\n[[jobs]]\npickup = [0, 0]\ndropoff = [3, 2]\nmass = -2.5\n',
            2,
            "'mass' must be greater than 0",
        ),
        (
            'map = "m.map"\n[[jobs]]\npickup = [0, 0]\ndropoff = [9, 9]\nmass = 1\n',
            2,
            "dropoff [9, 9] is off",
        ),
        ('map = "m.map"\n[[jobs]]\npickup = [0, 0]\ndropoff = [1, 1]\nmass = 1\n', 2, "on a wall"),
        ('map = "m.map"\nhidden_obstacles = [[1, 1]]\n', 2, "hidden obstacle [1, 1] is on a wall"),
        ('map = "m.map"\nhidden_obstacles = [[0, 0]]\n' + UNIT, 3, "is a hidden obstacle"),
        ('map = "m.map"\n[[goals]]\nunit = "ghost"\ntarget = [0, 0]\n', 2, "unknown unit 'ghost'"),
        (
            'map = "m.map"\n'
            + '[[jobs]]\nid = "a"\npickup = [0, 0]\ndropoff = [3, 2]\nmass = 1\n' * 2,
            7,
            "job #2: id 'a' used twice",
        ),
        (
            'map = "m.map"\n' + UNIT + '[[goals]]\nunit = "u1"\ntarget = [3, 2]\n' * 2,
            9,
            "goal #2: unit 'u1' already has a goal",
        ),
        ('map = "m.map"\nspeed = 3\n', 2, "unknown key 'speed'"),
        ('map = "m.map"\n' + UNIT + 'colour = "red"\n', 2, "unknown key 'colour'"),
        ('map = "nope.map"\n', 1, "no such map file"),
        ('map = "m.map"\nunits = [\n', 2, "not valid TOML"),
        ("units = []\n", 1, "'map' must name a .map file"),
        ("map = 3\n", 1, "'map' must name a .map file"),
        ('map = "m.map"\n' + UNIT.replace("5.0", "true"), 2, "'capacity' must be a number of kg"),
        ('map = "m.map"\n' + UNIT.replace("5.0", "nan"), 2, "'capacity' must be greater than 0"),
        ('map = "m.map"\n' + UNIT.replace("5.0", '"5"'), 2, "unit 'u1': 'capacity' must be a"),
        ('map = "m.map"\n' + UNIT.replace("[0, 0]", "[0, 1.5]"), 2, "start must be [x, y]"),
        ('map = "m.map"\n' + UNIT.replace("start = [0, 0]\n", ""), 2, "start must be [x, y]"),
        ('map = "m.map"\n' + UNIT + 'color = "red"\n', 2, "color 'red' is not #rrggbb"),
        ('map = "m.map"\n' + UNIT.replace('"u1"', "7"), 2, "unit #1: id 7 is not a valid id"),
        ('map = "m.map"\nunits = [1, 2]\n', 2, "'units' must be a list of tables"),
        ('map = "m.map"\nunits = "u1"\n', 2, "'units' must be a list of tables"),
        ('map = "m.map"\nhidden_obstacles = 3\n', 2, "must be a list of [x, y] squares"),
        ('map = "m.map"\nhidden_obstacles = [[0]]\n', 2, "hidden obstacle must be [x, y]"),
        ('map = "m.map"\nname = 5\n', 2, "'name' and 'description' must be strings"),
        ('map = "m.map"\n[[goals]]\nunit = 5\ntarget = [0, 0]\n', 2, "unknown unit 5"),
        (
            'map = "m.map"\n[[jobs]]\npickup = [0, 0]\ndropoff = [3, 2]\nmass = 1\npriority = 101\n',
            2,
            "job #1: priority must be a whole number 0..100, got 101",
        ),
        (
            'map = "m.map"\n[[jobs]]\npickup = [0, 0]\ndropoff = [3, 2]\nmass = 1\nid = "a/b"\n',
            2,
            "job #1: id 'a/b' is not a valid id",
        ),
        (
            'map = "m.map"\n[[jobs]]\npickup = [0, 0]\ndropoff = [3, 2]\nmass = 1\nkg = 1\n',
            2,
            "job #1: unknown key 'kg' (known: dropoff, id, mass, pickup, priority)",
        ),
        # A misspelt key is named first, whatever else is wrong.
        ('mapp = "m.map"\n' + UNIT.replace("5.0", "0"), 1, "unknown key 'mapp'"),
    ],
)
def test_bad_scenarios_fail_with_one_clear_line(
    tmp_path: Path, body: str, line: int, problem: str
) -> None:
    (tmp_path / "m.map").write_text(MAP)
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}:{line}:"), message
    assert problem in message


def test_missing_scenario_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="no such scenario file"):
        load_scenario(tmp_path / "absent.toml")


def test_gridmap_refuses_a_bad_array() -> None:
    with pytest.raises(ValueError, match="non-empty 2-D"):
        GridMap([])


def test_with_units_passes_a_fleet_and_refuses_a_map_only_scenario(tmp_path: Path) -> None:
    (tmp_path / "m.map").write_text(MAP)
    (tmp_path / "fleet.toml").write_text('map = "m.map"\n' + UNIT)
    (tmp_path / "empty.toml").write_text('map = "m.map"\n')
    fleet = load_scenario(tmp_path / "fleet.toml")
    assert with_units(fleet) is fleet
    with pytest.raises(ScenarioError, match="no units to run") as info:
        with_units(load_scenario(tmp_path / "empty.toml"))
    assert str(tmp_path / "empty.toml") in str(info.value)


# ---- energy: [battery], a unit's battery, [[chargers]], [charging] -----------------------------


def test_batteries_chargers_and_thresholds_load_with_their_defaults(tmp_path: Path) -> None:
    (tmp_path / "m.map").write_text(MAP)
    path = tmp_path / "energy.toml"
    path.write_text(
        'map = "m.map"\n'
        "[battery]\nstart_pct = 90\nmove_pct = 0.25\n"
        + UNIT
        + "battery = { start_pct = 40.0 }\n"
        + UNIT.replace('"u1"', '"u2"').replace("[0, 0]", "[3, 0]")
        + '[[chargers]]\nsquare = [0, 2]\n[[chargers]]\nsquare = [3, 2]\nname = "dock"\n'
        + '[charging]\ncritical_pct = 15\navailable_from = "full"\n'
    )
    s = load_scenario(path)
    assert s.unit("u1").battery == BatterySpec(start_pct=40.0, move_pct=0.25)
    assert s.unit("u2").battery == BatterySpec(start_pct=90.0, move_pct=0.25)
    assert s.chargers == (ChargerSpec("C1", Cell(0, 2)), ChargerSpec("dock", Cell(3, 2)))
    assert s.charging == ChargingSpec(critical_pct=15.0, available_from="full")


def test_without_a_battery_table_units_never_run_down(tmp_path: Path) -> None:
    (tmp_path / "m.map").write_text(MAP)
    path = tmp_path / "plain.toml"
    path.write_text('map = "m.map"\n' + UNIT)
    s = load_scenario(path)
    assert s.unit("u1").battery is None and s.chargers == () and s.charging == ChargingSpec()
    path.write_text('map = "m.map"\n' + UNIT + "battery = { move_pct = 1 }\n")
    assert load_scenario(path).unit("u1").battery == BatterySpec(move_pct=1.0)


CHARGER = "[[chargers]]\nsquare = [0, 2]\n"


@pytest.mark.parametrize(
    ("body", "line", "problem"),
    [
        ("[battery]\nstart_pct = 101\n", 2, "[battery]: 'start_pct' must be a number from 0 to"),
        ("[battery]\nmove_pct = -1\n", 2, "'move_pct' must be a number 0 or more and at most"),
        ('[battery]\nidle_pct_per_s = "a"\n', 2, "'idle_pct_per_s' must be a number 0 or more"),
        ("[battery]\ncharge_pct_per_s = 0\n", 2, "'charge_pct_per_s' must be a number greater"),
        ("[battery]\nvolts = 12\n", 2, "[battery]: unknown key 'volts'"),
        (UNIT + "battery = { start_pct = -5 }\n", 2, "unit 'u1': battery: 'start_pct' must be"),
        (UNIT + "battery = { amps = 1 }\n", 2, "unit 'u1': battery: unknown key 'amps'"),
        (UNIT + "battery = 40\n", 2, "unit 'u1': 'battery' must be a table"),
        (CHARGER.replace("[0, 2]", "[4, 2]"), 2, "charger 'C1': square [4, 2] is off the 4x3 map"),
        (CHARGER.replace("[0, 2]", "[1, 1]"), 2, "charger 'C1': square [1, 1] is on a wall"),
        ("hidden_obstacles = [[0, 2]]\n" + CHARGER, 3, "square [0, 2] is a hidden obstacle"),
        (CHARGER * 2, 4, "charger 'C2': square [0, 2] already has charger 'C1'"),
        (
            CHARGER + CHARGER.replace("[0, 2]", "[3, 2]") + 'name = "C1"\n',
            4,
            "charger 'C1': name used twice",
        ),
        ("[charging]\ngood_pct = 10\n", 2, "thresholds must rise"),
        ('[charging]\navailable_from = "half"\n', 2, "'available_from' must be \"sufficient\""),
    ],
)
def test_bad_energy_keys_fail_with_one_clear_line(
    tmp_path: Path, body: str, line: int, problem: str
) -> None:
    (tmp_path / "m.map").write_text(MAP)
    path = tmp_path / "bad.toml"
    path.write_text('map = "m.map"\n' + body)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}:{line}:"), message
    assert problem in message, message
