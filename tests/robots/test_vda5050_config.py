"""The vehicles file: a good one loads; every kind of mistake is one line naming file and line."""

from __future__ import annotations

from pathlib import Path

import pytest

from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import EnergyModel
from gridfleet.robots.vda5050.config import load_vehicles

MAP = "[maps.hall]\norigin = [1.0, 2.0]\nx_axis = [1, 0]\ny_axis = [0, -1]\nsquare_m = 0.5\n"
AGV = (
    '[[vehicles]]\nunit = "agv1"\nmanufacturer = "acme"\nserial_number = "sn-7"\n'
    'version = "2.0.0"\nmap = "hall"\ncapacity_kg = 20.0\n'
)


def test_a_vehicles_file_loads(tmp_path: Path) -> None:
    path = tmp_path / "vehicles.toml"
    v21 = AGV.replace('"agv1"', '"agv2"').replace('"sn-7"', '"sn-8"').replace("2.0.0", "2.1.0")
    path.write_text(
        MAP
        + AGV
        + "margin_m = 0.04\nlegacy_actions_key = true\n"
        + v21.replace("capacity_kg = 20.0\n", "")
    )
    first, second = load_vehicles(path)
    assert first.vehicle.topic("state") == "uagv/v2/acme/sn-7/state"
    assert first.frame.position(Cell(2, 2)) == (2.0, 1.0)
    assert (first.capacity_kg, first.margin_m, first.legacy_actions_key) == (20.0, 0.04, True)
    assert (second.vehicle.version, second.capacity_kg) == ("2.1.0", None)  # from its factsheet


@pytest.mark.parametrize(
    ("body", "line", "problem"),
    [
        (MAP + AGV + "speed = 2\n", 6, "vehicles.0: unknown key 'speed'"),
        (MAP + AGV.replace('unit = "agv1"\n', ""), 6, "vehicles #1: unit: missing"),
        (
            MAP + AGV.replace("2.0.0", "1.1.0"),
            6,
            "vehicles #1: version: input should be '2.0.0' or '2.1.0'",
        ),
        (MAP + AGV.replace("capacity_kg = 20.0\n", ""), 6, "a 2.0.0 vehicle needs capacity_kg"),
        (
            MAP + AGV.replace("capacity_kg = 20.0", "capacity_kg = 0"),
            6,
            "capacity_kg: input should be greater than 0",
        ),
        (MAP + AGV.replace('map = "hall"', 'map = "yard"'), 6, "no [maps.yard] table"),
        (MAP + AGV + AGV.replace('"sn-7"', '"sn-9"'), 13, "vehicle 'agv1': unit id used twice"),
        (MAP + AGV + AGV.replace('"agv1"', '"agv2"'), 13, "the same vehicle as unit 'agv1'"),
        (MAP + AGV.replace('"acme"', '"ac/me"'), 6, "manufacturer 'ac/me' cannot be a topic level"),
        (MAP + AGV.replace('"agv1"', '"agv 1"'), 6, "agv 1"),
        (MAP.replace("y_axis = [0, -1]", "y_axis = [1, 0]") + AGV, 3, "at right angles"),
        (MAP.replace("[1.0, 2.0]", '["a", 2.0]') + AGV, 2, "maps.hall: origin"),
        (
            MAP + AGV + "energy = { move_pct = 0.5, idle_pct_per_s = 0.01 }\n",
            6,
            "vehicles #1: energy.charge_pct_per_s: missing",
        ),
        (
            MAP + AGV + "energy = { move_pct = 120, idle_pct_per_s = 0, charge_pct_per_s = 2 }\n",
            6,
            "vehicles #1: energy.move_pct: input should be less than or equal to 100, got 120",
        ),
        (
            MAP + AGV + "energy = { move_pct = 1, idle_pct_per_s = 0, charge_pct_per_s = 0 }\n",
            6,
            "energy.charge_pct_per_s: input should be greater than 0",
        ),
        (
            MAP + AGV + 'energy = { move_pct = "1", idle_pct_per_s = 0, charge_pct_per_s = 1 }\n',
            6,
            "energy.move_pct: input should be a valid",
        ),
        (
            MAP
            + AGV
            + "energy = { move_pct = 1, idle_pct_per_s = 0, charge_pct_per_s = 1, x = 1 }\n",
            6,
            "vehicles.0.energy: unknown key 'x'",
        ),
        (MAP + AGV + "energy = 3\n", 6, "vehicles #1: energy: should be a table, got 3"),
        ("vehicle = 3\n", 1, "unknown key 'vehicle' (known: maps, vehicles)"),
        ("[[vehicles]\n", 1, "not valid TOML"),
    ],
)
def test_a_bad_vehicles_file_is_one_line_naming_file_and_line(
    tmp_path: Path, body: str, line: int, problem: str
) -> None:
    path = tmp_path / "vehicles.toml"
    path.write_text(body)
    with pytest.raises(ConfigError) as info:
        load_vehicles(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}:{line}:"), message
    assert problem in message, message


def test_a_vehicles_energy_model_is_its_units_and_without_one_it_has_none(tmp_path: Path) -> None:
    path = tmp_path / "vehicles.toml"
    second = AGV.replace('"agv1"', '"agv2"').replace('"sn-7"', '"sn-8"')
    path.write_text(
        MAP
        + AGV
        + "energy = { move_pct = 0.5, idle_pct_per_s = 0, charge_pct_per_s = 2 }\n"
        + second
    )
    managed, unmanaged = load_vehicles(path)
    assert managed.energy == EnergyModel(move_pct=0.5, idle_pct_per_s=0.0, charge_pct_per_s=2.0)
    assert unmanaged.energy is None


def test_a_missing_vehicles_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such vehicles file"):
        load_vehicles(tmp_path / "absent.toml")
