"""A scenario's batteries, chargers and charge thresholds load; each bad value fails in one line."""

from __future__ import annotations

from pathlib import Path

import pytest

from gridfleet.energy import BatterySpec, ChargingSpec
from gridfleet.errors import ScenarioError
from gridfleet.grid import Cell
from gridfleet.scenario import load_scenario

MAP = "type octile\nheight 3\nwidth 5\nmap\n.....\n.@...\n.....\n"
UNITS = """
[[units]]
id = "u1"
start = [0, 0]
capacity = 5.0
{battery}

[[units]]
id = "u2"
start = [4, 0]
capacity = 5.0
"""


def scenario(tmp_path: Path, head: str = "", battery: str = "", tail: str = "") -> Path:
    """A scenario file on a 5 x 3 map with two units; `head`, `battery` and `tail` added."""
    (tmp_path / "m.map").write_text(MAP)
    path = tmp_path / "s.toml"
    path.write_text(f'map = "m.map"\n{head}\n{UNITS.format(battery=battery)}\n{tail}\n')
    return path


def test_without_battery_units_never_run_down_and_there_are_no_chargers(tmp_path: Path) -> None:
    s = load_scenario(scenario(tmp_path))
    assert [u.battery for u in s.units] == [None, None]
    assert s.chargers == ()
    assert s.charging == ChargingSpec()


def test_the_battery_table_is_every_units_default_and_a_unit_overrides_any_key(
    tmp_path: Path,
) -> None:
    head = "[battery]\nstart_pct = 90.0\nmove_pct = 1\nidle_pct_per_s = 0.0\n"
    s = load_scenario(scenario(tmp_path, head, "battery = { start_pct = 40.0, move_pct = 2.5 }"))
    own, default = (u.battery for u in s.units)
    assert own == BatterySpec(40.0, 2.5, 0.0, 2.0)
    assert default == BatterySpec(90.0, 1.0, 0.0, 2.0)


def test_a_units_battery_alone_gives_only_that_unit_a_battery(tmp_path: Path) -> None:
    s = load_scenario(scenario(tmp_path, battery="battery = { start_pct = 30 }"))
    assert [u.battery for u in s.units] == [BatterySpec(start_pct=30.0), None]


def test_chargers_are_named_in_order_unless_named(tmp_path: Path) -> None:
    tail = '[[chargers]]\nsquare = [0, 2]\n\n[[chargers]]\nsquare = [4, 2]\nname = "dock-east"\n'
    s = load_scenario(scenario(tmp_path, tail=tail))
    assert [(c.name, c.square) for c in s.chargers] == [
        ("C1", Cell(0, 2)),
        ("dock-east", Cell(4, 2)),
    ]


def test_charging_thresholds_are_read(tmp_path: Path) -> None:
    head = '[charging]\ncritical_pct = 10\ngood_pct = 30\nsufficient_pct = 60\nfull_pct = 100\navailable_from = "full"\n'
    s = load_scenario(scenario(tmp_path, head))
    assert s.charging == ChargingSpec(10.0, 30.0, 60.0, 100.0, "full")


@pytest.mark.parametrize(
    ("head", "battery", "tail", "problem"),
    [
        (
            "",
            "battery = { start_pct = 140.0 }",
            "",
            ":4: unit 'u1': battery: 'start_pct' must be a number from 0 to 100",
        ),
        ("", "battery = { start_pct = -1 }", "", "'start_pct' must be a number from 0 to 100"),
        ("", 'battery = { move_pct = "fast" }', "", "'move_pct' must be a number 0 or more"),
        (
            "",
            "battery = { idle_pct_per_s = -0.5 }",
            "",
            "'idle_pct_per_s' must be a number 0 or more",
        ),
        (
            "",
            "battery = { charge_pct_per_s = 0 }",
            "",
            "'charge_pct_per_s' must be a number greater than 0",
        ),
        (
            "",
            "battery = { charge_pct_per_s = nan }",
            "",
            "'charge_pct_per_s' must be a number greater than 0",
        ),
        ("", "battery = { volts = 24 }", "", "battery: unknown key 'volts'"),
        ("", "battery = 40", "", "'battery' must be a table"),
        (
            "[battery]\nmove_pct = -1\n",
            "",
            "",
            ":2: [battery]: 'move_pct' must be a number 0 or more",
        ),
        ("[battery]\nwatts = 1\n", "", "", "[battery]: unknown key 'watts'"),
        ("battery = 3\n", "", "", "'battery' must be a table ([battery])"),
        (
            "",
            "",
            "[[chargers]]\nsquare = [9, 0]\n",
            "charger 'C1': square [9, 0] is off the 5x3 map",
        ),
        ("", "", "[[chargers]]\nsquare = [1, 1]\n", "charger 'C1': square [1, 1] is on a wall"),
        ("", "", "[[chargers]]\nsquare = [1, 1.5]\n", "square must be [x, y] with whole numbers"),
        ("", "", '[[chargers]]\nsquare = [0, 2]\nname = "a/b"\n', "name 'a/b' is not a valid id"),
        (
            "",
            "",
            "[[chargers]]\nsquare = [0, 2]\n[[chargers]]\nsquare = [0, 2]\n",
            "square [0, 2] already has charger 'C1'",
        ),
        (
            "",
            "",
            '[[chargers]]\nsquare = [0, 2]\nname = "X"\n[[chargers]]\nsquare = [1, 2]\nname = "X"\n',
            "charger 'X': name used twice",
        ),
        ("", "", "[[chargers]]\nsquare = [0, 2]\nvolts = 3\n", "charger #1: unknown key 'volts'"),
        (
            "hidden_obstacles = [[2, 2]]\n",
            "",
            "[[chargers]]\nsquare = [2, 2]\n",
            "square [2, 2] is a hidden obstacle",
        ),
        ("[charging]\ngood_pct = 10\n", "", "", "[charging]: thresholds must rise"),
        (
            "[charging]\ngood_pct = 90\nsufficient_pct = 90\nfull_pct = 90\n",
            "",
            "",
            "[charging]: good_pct must be below full_pct",
        ),
        (
            "",
            "",
            "[[chargers]]\nsquare = [0, 2]\n[[jobs]]\npickup = [0, 2]\ndropoff = [3, 2]\nmass = 1.0\n",
            "job #1: pickup [0, 2] is charger 'C1': a unit charging there would block it",
        ),
        (
            "[charging]\nfull_pct = 101\n",
            "",
            "",
            "[charging]: 'full_pct' must be a number from 0 to 100",
        ),
        (
            '[charging]\ncritical_pct = "low"\n',
            "",
            "",
            "[charging]: 'critical_pct' must be a number from 0 to 100",
        ),
        (
            '[charging]\navailable_from = "half"\n',
            "",
            "",
            '\'available_from\' must be "sufficient" or "full"',
        ),
    ],
)
def test_bad_energy_values_fail_with_one_clear_line(
    tmp_path: Path, head: str, battery: str, tail: str, problem: str
) -> None:
    path = scenario(tmp_path, head, battery, tail)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert problem in message, message
    assert "\n" not in message and str(path) in message


def test_a_charger_no_unit_can_drive_to_is_refused(tmp_path: Path) -> None:
    (tmp_path / "walled.map").write_text("type octile\nheight 2\nwidth 6\nmap\n....@.\n....@.\n")
    path = tmp_path / "s.toml"
    path.write_text(
        'map = "walled.map"\n[[units]]\nid = "u1"\nstart = [0, 0]\ncapacity = 5.0\n'
        "[[chargers]]\nsquare = [3, 1]\n[[chargers]]\nsquare = [5, 0]\n"
    )
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert str(info.value) == (
        f"{path}:8: charger 'C2': square [5, 0] cannot be reached from any unit's start (walled in)"
    )
    path.write_text('map = "walled.map"\n[[chargers]]\nsquare = [5, 0]\n')  # no units: a map
    assert [c.name for c in load_scenario(path).chargers] == ["C1"]
