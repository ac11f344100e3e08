"""A scenario's named places load (the chargers offered as places too); each kind of bad place is
refused at load in one line naming the file, the line and the place."""

from __future__ import annotations

from pathlib import Path

import pytest

from gridfleet.errors import ScenarioError
from gridfleet.grid import Cell
from gridfleet.protocol.constants import MAX_PLACES
from gridfleet.scenario import PlaceSpec, load_scenario

MAP = "type octile\nheight 3\nwidth 4\nmap\n....\n.@..\n....\n"
CHARGER = '[[chargers]]\nsquare = [0, 2]\nname = "C1"\n'


def place(name: str = "A3", square: str = "[3, 0]", kinds: str | None = '["pickup"]') -> str:
    """One [[places]] table (`kinds` None: left out)."""
    table = f'[[places]]\nname = "{name}"\nsquare = {square}\n'
    return table + (f"kinds = {kinds}\n" if kinds is not None else "")


def scenario(tmp_path: Path, body: str) -> Path:
    """A scenario on a 4 x 3 map (a wall at [1, 1]) with `body`."""
    (tmp_path / "m.map").write_text(MAP)
    path = tmp_path / "s.toml"
    path.write_text('map = "m.map"\n' + body)
    return path


def refusal(path: Path) -> str:
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    return str(info.value)


def test_places_load_with_their_kinds_and_pickup_and_dropoff_by_default(tmp_path: Path) -> None:
    path = scenario(
        tmp_path, place() + place("P2", "[2, 2]", None) + place("K", "[0, 0]", '["parking"]')
    )
    assert load_scenario(path).places == (
        PlaceSpec("A3", Cell(3, 0), ("pickup",)),
        PlaceSpec("P2", Cell(2, 2), ("pickup", "dropoff")),
        PlaceSpec("K", Cell(0, 0), ("parking",)),
    )


def test_every_charger_is_a_place_unless_a_place_has_its_name_or_its_square(tmp_path: Path) -> None:
    two = CHARGER + '[[chargers]]\nsquare = [3, 2]\nname = "C2"\n[[chargers]]\nsquare = [2, 0]\n'
    path = scenario(tmp_path, two)
    assert load_scenario(path).places == (
        PlaceSpec("C1", Cell(0, 2), ("charger",)),
        PlaceSpec("C2", Cell(3, 2), ("charger",)),
        PlaceSpec("C3", Cell(2, 0), ("charger",)),
    )
    # C1 named by a place of its own (with a second kind), C2's square named otherwise.
    mine = place("C1", "[0, 2]", '["charger", "parking"]') + place("dock", "[3, 2]", '["charger"]')
    path = scenario(tmp_path, two + mine)
    assert load_scenario(path).places == (
        PlaceSpec("C1", Cell(0, 2), ("charger", "parking")),
        PlaceSpec("dock", Cell(3, 2), ("charger",)),
        PlaceSpec("C3", Cell(2, 0), ("charger",)),
    )


def test_a_scenario_without_places_or_chargers_has_none(tmp_path: Path) -> None:
    assert load_scenario(scenario(tmp_path, "")).places == ()


@pytest.mark.parametrize(
    ("body", "line", "problem"),
    [
        (
            place("a/b"),
            2,
            "place #1: name 'a/b' is not a valid id (letters, digits, '_', '.', '-')",
        ),
        (place() + place(square="[0, 0]"), 6, "place 'A3': name used twice"),
        (place(square="[4, 0]"), 2, "place 'A3': square [4, 0] is off the 4x3 map"),
        (place(square="[1, 1]"), 2, "place 'A3': square [1, 1] is on a wall or fixed obstacle"),
        (
            "hidden_obstacles = [[3, 0]]\n" + place(),
            3,
            "place 'A3': square [3, 0] is a hidden obstacle",
        ),
        (place() + place("A4"), 6, "place 'A4': square [3, 0] is place 'A3' already"),
        (
            place(kinds='["pickup", "shelf"]'),
            2,
            "place 'A3': kinds: unknown kind 'shelf' (known: pickup, dropoff, charger, parking)",
        ),
        (
            place(kinds="[]"),
            2,
            "place 'A3': kinds is empty: give one or more of pickup, dropoff, charger, parking",
        ),
        (place(kinds='["pickup", "pickup"]'), 2, "place 'A3': kinds: 'pickup' given twice"),
        (
            place(kinds='"pickup"'),
            2,
            "place 'A3': kinds must be a list of pickup, dropoff, charger, parking, "
            'e.g. kinds = ["pickup"]',
        ),
        (place(square="[3]"), 2, "place 'A3': square must be [x, y] with whole numbers, got [3]"),
        (
            place() + "shelf = 4\n",
            2,
            "place 'A3': unknown key 'shelf' (known: kinds, name, square)",
        ),
        (
            place(kinds='["charger"]'),
            2,
            "place 'A3': kind 'charger', but square [3, 0] has no charger ([[chargers]])",
        ),
        (
            CHARGER + place("out", "[0, 2]", '["dropoff"]'),
            5,
            "place 'out': a dropoff on charger 'C1' [0, 2]: a unit charging there would block it",
        ),
        ('places = "A3"\n', 2, "'places' must be a list of tables ([[places]])"),
    ],
    ids=[
        "name not an id",
        "name twice",
        "off the map",
        "on a wall",
        "hidden obstacle",
        "two on one square",
        "unknown kind",
        "no kinds",
        "kind twice",
        "kinds not a list",
        "square not x y",
        "unknown key",
        "charger kind without a charger",
        "dropoff on a charger",
        "not tables",
    ],
)
def test_a_bad_place_is_refused_naming_the_file_the_line_and_the_place(
    tmp_path: Path, body: str, line: int, problem: str
) -> None:
    path = scenario(tmp_path, body)
    assert refusal(path) == f"{path}:{line}: {problem}"


def test_more_places_than_a_map_may_have_are_refused(tmp_path: Path) -> None:
    side = 65  # 4,225 free squares: room for one place more than MAX_PLACES
    (tmp_path / "big.map").write_text(
        f"type octile\nheight {side}\nwidth {side}\nmap\n" + ("." * side + "\n") * side
    )
    squares = [(x, y) for y in range(side) for x in range(side)][: MAX_PLACES + 1]
    tables = "".join(place(f"p{i}", f"[{x}, {y}]") for i, (x, y) in enumerate(squares))
    path = tmp_path / "s.toml"
    path.write_text('map = "big.map"\n' + tables)
    line = 2 + 4 * MAX_PLACES  # the first table too many
    assert refusal(path) == (
        f"{path}:{line}: place #{MAX_PLACES + 1}: more than {MAX_PLACES} places "
        f"(a map has at most {MAX_PLACES})"
    )
    path.write_text('map = "big.map"\n' + tables[: tables.rindex("[[places]]")])
    assert len(load_scenario(path).places) == MAX_PLACES, "as many as a map may have: loaded"


def test_more_places_with_the_chargers_than_a_map_may_have_are_refused(tmp_path: Path) -> None:
    side = 65
    (tmp_path / "big.map").write_text(
        f"type octile\nheight {side}\nwidth {side}\nmap\n" + ("." * side + "\n") * side
    )
    squares = [(x, y) for y in range(side) for x in range(side)]
    tables = "".join(place(f"p{i}", f"[{x}, {y}]") for i, (x, y) in enumerate(squares[:MAX_PLACES]))
    x, y = squares[MAX_PLACES]
    path = tmp_path / "s.toml"
    path.write_text(f'map = "big.map"\n[[chargers]]\nsquare = [{x}, {y}]\nname = "C1"\n' + tables)
    assert refusal(path) == (
        f"{path}:2: charger 'C1': more than {MAX_PLACES} places with the chargers (each charger "
        "is a place too, unless a place has its name or its square)"
    )
