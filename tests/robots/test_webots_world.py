"""`gridfleet webots-world`: the world's structure, every square in its place, the shipped file."""

from __future__ import annotations

import stat
import subprocess
from pathlib import Path

import pytest

from gridfleet.accounts import default_accounts, write_accounts
from gridfleet.grid import Cell
from gridfleet.robots.webots.cli import protos_from
from gridfleet.robots.webots.geometry import (
    BLOCK_HEIGHT_M,
    OBSTACLE_SIDE_M,
    SQUARE_M,
    UNIT_SIZE_M,
    metres,
    sf_color,
)
from gridfleet.robots.webots.world_file import WorldOptions, world_text
from gridfleet.scenario import Scenario, load_scenario

from support.cli import gridfleet
from support.paths import MAPS, REPO
from support.vrml import Node, VrmlError, World, read_world

SCENARIOS = sorted(MAPS.glob("*.toml"))
SHIPPED = REPO / "robots" / "webots" / "worlds" / "playfield.wbt"


def numbers(node: Node, name: str) -> list[float]:
    return [float(v) for v in node.fields[name]]  # type: ignore[union-attr, arg-type]


def text_of(node: Node, name: str) -> str:
    (value,) = node.fields[name]  # type: ignore[misc]
    return str(value)


def square_of(node: Node) -> Cell:
    x, y, _ = numbers(node, "translation")
    cell = Cell(round(x / SQUARE_M), round(-y / SQUARE_M))
    assert (x, y) == pytest.approx(metres(cell)), "on a square's centre"
    return cell


def world_of(scenario: Scenario, **options: object) -> World:
    return read_world(world_text(scenario, WorldOptions(**options)))  # type: ignore[arg-type]


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return gridfleet("webots-world", *args, cwd=REPO)


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_every_shipped_scenario_makes_a_world_with_everything_in_its_place(path: Path) -> None:
    scenario = load_scenario(path)
    world = world_of(scenario)
    grid = scenario.grid
    assert world.header == "#VRML_SIM R2023b utf8"
    # Every PROTO the world uses is declared, and nothing else.
    used = {n.type for n in world.nodes}
    declared = {p.rsplit("/", 1)[1].removesuffix(".proto") for p in world.externprotos}
    assert declared == used - {"WorldInfo", "Viewpoint"}
    assert {"RectangleArena", "GridUnit", "TexturedBackground"} <= used
    # The floor holds exactly the map, square (0, 0) centred on the origin, tiles of 4 squares.
    (arena,) = world.of_type("RectangleArena")
    cx, cy, cz = numbers(arena, "translation")
    sx, sy = numbers(arena, "floorSize")
    assert (sx, sy) == pytest.approx((grid.width * SQUARE_M, grid.height * SQUARE_M))
    assert (cx - sx / 2, cy + sy / 2, cz) == pytest.approx((-SQUARE_M / 2, SQUARE_M / 2, 0))
    assert numbers(arena, "floorTileSize") == [2 * SQUARE_M, 2 * SQUARE_M]
    # One obstacle on every blocked square and every hidden obstacle, nowhere else.
    obstacles = world.of_type("GridObstacle")
    fixed = [o for o in obstacles if not text_of(o, "name").startswith("hidden")]
    hidden = [o for o in obstacles if text_of(o, "name").startswith("hidden")]
    blocked = {Cell(x, y) for y in range(grid.height) for x in range(grid.width)}
    blocked = {c for c in blocked if not grid.is_free(c)}
    assert sorted(square_of(o) for o in fixed) == sorted(blocked)
    assert sorted(square_of(o) for o in hidden) == sorted(scenario.hidden_obstacles)
    for obstacle in obstacles:
        assert numbers(obstacle, "size") == [OBSTACLE_SIDE_M, OBSTACLE_SIDE_M, BLOCK_HEIGHT_M]
        assert numbers(obstacle, "translation")[2] == BLOCK_HEIGHT_M / 2  # on the floor
    # One grid unit per scenario unit, on its start, in its colour, with its capacity and map.
    units = {text_of(u, "name"): u for u in world.of_type("GridUnit")}
    assert list(units) == [u.id for u in scenario.units]
    for spec in scenario.units:
        node = units[spec.id]
        assert square_of(node) == spec.start
        assert numbers(node, "translation")[2] == UNIT_SIZE_M / 2
        assert numbers(node, "color") == list(sf_color(spec.color))
        assert numbers(node, "capacity") == [spec.capacity]
        assert node.fields["map"] == grid.rows()
        assert "broker" not in node.fields  # no broker given: the PROTO's default
    # Webots wants every solid's name unique among its siblings.
    names = [text_of(n, "name") for n in world.nodes if "name" in n.fields]
    assert len(names) == len(set(names))


def test_a_world_runs_some_units_and_mirrors_the_others() -> None:
    scenario = load_scenario(MAPS / "playfield.toml")
    world = world_of(
        scenario,
        units=["unit3"],
        brokers={"unit3": "mqtt://10.0.0.5:1883"},
        root="lab/fleet",
        step_s=0.5,
    )
    units = {text_of(u, "name"): u for u in world.of_type("GridUnit")}
    assert list(units) == ["unit1", "unit2", "unit3", "unit4"]  # every unit is shown
    assert {n for n, u in units.items() if u.fields.get("mirror") == (True,)} == {
        "unit1",
        "unit2",
        "unit4",
    }
    unit3 = units["unit3"]
    assert "mirror" not in unit3.fields  # the PROTO's default: it runs here
    assert text_of(unit3, "broker") == "mqtt://10.0.0.5:1883"
    assert text_of(unit3, "root") == "lab/fleet"
    assert numbers(unit3, "stepPeriod") == [0.5]


def test_a_description_with_quotes_stays_one_string() -> None:
    base = load_scenario(MAPS / "playfield.toml")
    scenario = Scenario(**{**base.__dict__, "description": 'say "hi" \\ bye'})
    (info,) = world_of(scenario).of_type("WorldInfo")
    assert info.fields["info"][0] == 'gridfleet scenario playfield: say "hi" \\ bye'  # type: ignore[index]


def test_the_shipped_playfield_world_is_what_the_generator_makes_now() -> None:
    options = WorldOptions(protos=protos_from(SHIPPED.parent), source="maps/playfield.toml")
    expected = world_text(load_scenario(MAPS / "playfield.toml"), options)
    assert SHIPPED.read_text(encoding="utf-8") == expected, (
        "write it again: gridfleet webots-world maps/playfield.toml -o "
        + str(SHIPPED.relative_to(REPO))
    )
    assert options.protos == "../protos"


def test_the_reader_refuses_unbalanced_text() -> None:
    good = SHIPPED.read_text(encoding="utf-8")
    read_world(good)
    with pytest.raises(VrmlError):
        read_world(good.rstrip().removesuffix("}"))  # the last node never closes
    with pytest.raises(VrmlError):
        read_world(good.replace("  map [", "  map [ [", 1))  # a list opened twice, closed once
    with pytest.raises(VrmlError):
        read_world(good.replace('"unit1"', '"unit1', 1))  # an unclosed string


def test_the_command_writes_a_world_that_reads(tmp_path: Path) -> None:
    out = tmp_path / "worlds" / "maze.wbt"
    out.parent.mkdir()
    done = run_cli("maps/maze.toml", "-o", str(out), "--units", "unit2", "--step", "0.5")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"wrote {out}: maze, 1 grid unit(s), 2 mirrored")
    world = read_world(out.read_text(encoding="utf-8"))
    mirrored = [u.fields.get("mirror") == (True,) for u in world.of_type("GridUnit")]
    assert mirrored == [True, False, True]
    # The PROTOs are found from wherever the world is written.
    proto = (out.parent / world.externprotos[-1]).resolve()
    assert proto == REPO / "robots" / "webots" / "protos" / "GridUnit.proto"


def test_with_accounts_each_unit_logs_in_as_itself_and_the_file_is_private(
    tmp_path: Path,
) -> None:
    scenario = load_scenario(MAPS / "playfield.toml")
    accounts = default_accounts([u.id for u in scenario.units])
    write_accounts(accounts, tmp_path / "fleet-accounts.toml")
    out = tmp_path / "lan.wbt"
    done = run_cli(
        "maps/playfield.toml",
        "-o",
        str(out),
        "--broker",
        "mqtt://192.168.1.10:1883",
        "--accounts",
        str(tmp_path / "fleet-accounts.toml"),
        "--units",
        "unit1,unit2",
    )
    assert done.returncode == 0, done.stderr
    assert stat.S_IMODE(out.stat().st_mode) == 0o600
    for unit in read_world(out.read_text(encoding="utf-8")).of_type("GridUnit"):
        uid = text_of(unit, "name")
        # A unit run here logs in as itself; a mirror as the dashboard, which reads every state.
        login = uid if uid in ("unit1", "unit2") else "dashboard"
        password = accounts.get(login).password
        assert text_of(unit, "broker") == f"mqtt://{login}:{password}@192.168.1.10:1883"
        assert password not in done.stdout + done.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["maps/absent.toml", "-o", "{tmp}/x.wbt"], "maps/absent.toml: no such scenario file"),
        (["maps/playfield.toml", "-o", "{tmp}/no/such/dir/x.wbt"], "cannot write the world"),
        (["maps/playfield.toml", "-o", "{tmp}"], "cannot write the world"),
        (["maps/playfield.toml", "-o", "{tmp}/x.wbt", "--units", "ghost"], "unknown unit 'ghost'"),
        (["maps/playfield.toml", "-o", "{tmp}/x.wbt", "--units", ","], "--units: give at least"),
        (["maps/playfield.toml", "-o", "{tmp}/x.wbt", "--broker", "http://x"], "broker URL"),
        (["maps/playfield.toml", "-o", "{tmp}/x.wbt", "--step", "0"], "--step 0"),
        (["maps/playfield.toml", "-o", "{tmp}/x.wbt", "--root", "a/+"], "topic root"),
        (
            ["maps/playfield.toml", "-o", "{tmp}/x.wbt", "--accounts", "{tmp}/none.toml"],
            "no such accounts file",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, args: list[str], message: str) -> None:
    done = run_cli(*(a.format(tmp=tmp_path) for a in args))
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gridfleet webots-world: error: "), done.stderr
    assert message in lines[0]
    assert not (tmp_path / "x.wbt").exists()
