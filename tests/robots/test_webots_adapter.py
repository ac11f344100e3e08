"""`WebotsWorld` and the unit's settings, against the test double of Webots' controller API."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace

import pytest

from gridfleet.energy import BatterySpec
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell, Direction
from gridfleet.protocol.messages import Leds
from gridfleet.robots.webots.adapter import WebotsWorld
from gridfleet.robots.webots.host import MODEL, WebotsUnit
from gridfleet.robots.webots.settings import BROKER_ENV, read_settings
from gridfleet.robots.webots.world_file import WorldOptions, world_text
from gridfleet.scenario import ChargerSpec, Scenario, load_scenario

from support.paths import MAPS
from support.webots_double import SceneDouble, SharedTruth, SupervisorDouble, WebotsExited

PLAYFIELD = MAPS / "playfield.toml"
N, E, S, W = Direction.N, Direction.E, Direction.S, Direction.W
DARK = Leds(N=False, E=False, S=False, W=False)

Make = Callable[..., tuple[WebotsWorld, SupervisorDouble, SceneDouble]]


@pytest.fixture
def scenario() -> Scenario:
    return load_scenario(PLAYFIELD)


@pytest.fixture
def make(scenario: Scenario) -> Make:
    """A scene of the playfield with its units on the given squares; the adapter of one unit."""

    def build(
        unit: str = "unit1",
        at: dict[str, Cell] | None = None,
        leds: Callable[[], Leds] = lambda: DARK,
        **options: object,
    ) -> tuple[WebotsWorld, SupervisorDouble, SceneDouble]:
        truth = SharedTruth.from_scenario(scenario)
        for uid, cell in (at or {}).items():
            truth.resume(uid, cell)
        scene = SceneDouble(world_text(scenario, WorldOptions(**options)), truth)  # type: ignore[arg-type]
        robot = scene.robot(unit)
        return WebotsWorld(robot, unit, scenario.grid, leds=leds), robot, scene

    return build


def test_it_senses_walls_free_squares_obstacles_hidden_ones_and_units(make: Make) -> None:
    world, _, _ = make()
    assert world.sense("unit1") == {N: "wall", E: "free", S: "free", W: "wall"}
    # (1, 2): a fixed obstacle east at (2, 2); (4, 4): the hidden one south at (4, 5).
    world, _, _ = make(at={"unit1": Cell(1, 2)})
    assert world.sense("unit1") == {N: "free", E: "obstacle", S: "free", W: "free"}
    world, _, _ = make(at={"unit1": Cell(4, 4)})
    assert world.sense("unit1") == {N: "free", E: "free", S: "obstacle", W: "free"}
    world, _, _ = make(at={"unit1": Cell(5, 5), "unit2": Cell(5, 4), "unit3": Cell(4, 5)})
    assert world.sense("unit1") == {N: "unit", E: "obstacle", S: "free", W: "unit"}


def test_a_move_sets_the_translation_and_the_sensors_read_from_the_new_square(
    make: Make,
) -> None:
    world, robot, scene = make()
    assert world.move("unit1", E)
    assert robot.square() == Cell(1, 0) == world.position("unit1")
    assert [(a.start, a.end) for a in robot.applied] == [(Cell(0, 0), Cell(1, 0))]
    assert world.sense("unit1") == {N: "wall", E: "free", S: "free", W: "free"}
    assert world.moves == {"unit1": 1}
    assert (world.collisions, world.prevented, scene.truth.collisions) == (0, 0, 0)


def test_a_move_the_sensor_sees_blocked_is_refused_and_counted(make: Make) -> None:
    world, robot, scene = make()
    steps = robot.steps
    assert not world.move("unit1", W)  # off the map
    assert not world.move("unit1", N)
    assert world.move("unit1", S)
    assert (world.prevented, world.moves["unit1"], robot.steps) == (2, 1, steps + 1)
    assert [a.end for a in robot.applied] == [Cell(0, 1)]  # only the allowed move was made
    world, robot, scene = make(at={"unit1": Cell(1, 2)})
    assert not world.move("unit1", E)  # the obstacle at (2, 2)
    assert (world.prevented, robot.applied, scene.truth.collisions) == (1, [], 0)


def test_a_translation_webots_did_not_take_is_no_move(make: Make) -> None:
    world, robot, _ = make()
    robot.node.fields["translation"].setSFVec3f = lambda value: None  # type: ignore[method-assign]
    assert not world.move("unit1", E)
    assert (world.position("unit1"), world.moves["unit1"], robot.square()) == (
        Cell(0, 0),
        0,
        Cell(0, 0),
    )


def test_it_counts_a_unit_that_took_the_square_after_the_sensor_looked(make: Make) -> None:
    world, robot, scene = make()
    assert world.sense("unit1")[E] == "free"
    # Within one Webots step, another unit arrives on (1, 0); the sensor has not seen it yet.
    sensor = robot.sensors["ds E"]
    seen = sensor.getValue()
    sensor.getValue = lambda: seen  # type: ignore[method-assign]
    with scene.truth.lock:
        scene.truth.resume("unit2", Cell(1, 0))
    assert world.move("unit1", E)
    assert world.collisions == 1 and world.log[0].kind == "vertex"
    assert world.log[0].units == ("unit1", "unit2")
    assert scene.truth.collisions == 1  # the double's ground truth saw the same


def test_a_mirror_on_the_square_is_no_collision_of_this_world(make: Make) -> None:
    # unit2 runs elsewhere; its mirror here follows its state a little late: not counted.
    world, robot, scene = make(units=["unit1"])
    sensor = robot.sensors["ds E"]
    seen = sensor.getValue()
    sensor.getValue = lambda: seen  # type: ignore[method-assign]
    with scene.truth.lock:
        scene.truth.resume("unit2", Cell(1, 0))
    assert world.move("unit1", E)
    assert world.collisions == 0
    assert scene.truth.collisions == 1  # the double's truth still has both on one square


def test_the_leds_show_the_intention_as_a_step_begins_and_ends(make: Make) -> None:
    intention = [Leds(N=False, E=True, S=False, W=False)]
    world, robot, _ = make(leds=lambda: intention[0])
    assert robot.lit() == frozenset("E")  # lit at start, before the first step
    with world.turn():
        assert robot.lit() == frozenset("E")
        assert world.move("unit1", E)
        intention[0] = Leds(N=False, E=False, S=True, W=False)
    assert robot.lit() == frozenset("S")
    assert robot.applied[0].lit == frozenset("E")  # the move went the way the LEDs showed
    intention[0] = Leds(N=True, E=True, S=True, W=True)  # the emergency stop: all four
    assert world.advance()
    assert robot.lit() == frozenset("NESW")
    # Each LED is set only when it changes: E went on before the first step, off, on again.
    assert [value for _, value in robot.leds["led E"].history] == [1, 0, 1]
    assert robot.leds["led E"].history[0][0] == 0


def test_webots_ending_the_controller_shows_in_advance(make: Make) -> None:
    world, _, scene = make()
    assert world.advance() and not world.ended
    scene.ended.set()
    assert not world.advance()
    assert world.ended


ALL_LIT = Leds(N=True, E=True, S=True, W=True)


def _turn_with_new_leds(world: WebotsWorld, intention: list[Leds]) -> None:
    intention[0] = ALL_LIT  # the LEDs would have to change, were they shown
    with world.turn():
        pass


AFTER_THE_END: dict[str, Callable[[WebotsWorld, list[Leds]], object]] = {
    "advance": lambda world, intention: world.advance(),
    "advance with other LEDs": lambda world, intention: world.advance(ALL_LIT),
    "sense": lambda world, intention: world.sense("unit1"),
    "move": lambda world, intention: world.move("unit1", E),
    "resume": lambda world, intention: world.resume("unit1", Cell(0, 4)),
    "turn": _turn_with_new_leds,
}


@pytest.mark.parametrize("call", AFTER_THE_END, ids=str)
def test_after_a_step_returned_minus_one_nothing_calls_webots(make: Make, call: str) -> None:
    # Webots' library ends the process at the next step or field read after -1: the unit would
    # go without its goodbye. The double raises and lists any such call.
    intention = [DARK]
    world, robot, scene = make(leds=lambda: intention[0])
    scene.ended.set()
    assert not world.advance()  # the step that returns -1
    assert robot.exited
    AFTER_THE_END[call](world, intention)
    assert robot.calls_after_end == []


def test_after_the_end_the_unit_holds_still_and_its_sensors_read_as_not_measured(
    make: Make,
) -> None:
    world, robot, scene = make()
    scene.ended.set()
    assert not world.advance() and world.ended
    assert not world.advance()  # and stays so
    # Not measured reads as a unit: never free, never an obstacle reported to the fleet.
    assert world.sense("unit1") == {N: "wall", E: "unit", S: "unit", W: "wall"}
    assert not world.move("unit1", E)
    world.resume("unit1", Cell(0, 4))
    assert (world.position("unit1"), world.moves["unit1"], world.prevented) == (Cell(0, 0), 0, 0)
    assert (robot.applied, robot.calls_after_end) == ([], [])


def test_webots_ending_during_a_move_makes_no_move_and_reads_nothing_after(make: Make) -> None:
    world, robot, scene = make()
    scene.end_on_move = True  # Webots quits in the very step that would move the unit
    assert not world.move("unit1", E)
    assert world.ended
    assert (world.position("unit1"), world.moves["unit1"], world.collisions) == (Cell(0, 0), 0, 0)
    assert (robot.applied, robot.calls_after_end) == ([], [])
    world, robot, scene = make()
    scene.end_on_move = True
    world.resume("unit1", Cell(0, 4))  # a mirror following its unit: the same
    assert world.ended and world.position("unit1") == Cell(0, 0)
    assert (robot.applied, robot.calls_after_end) == ([], [])


def test_the_double_fails_any_call_after_minus_one_as_webots_ends_the_process(
    make: Make,
) -> None:
    _, robot, scene = make()
    timestep = int(robot.getBasicTimeStep())
    own = robot.getSelf()
    root = robot.getRoot()
    scene.ended.set()
    assert robot.step(timestep) == -1
    calls: list[Callable[[], object]] = [
        lambda: robot.step(timestep),
        robot.getSelf,
        lambda: own.getField("name"),
        lambda: robot.node.fields["translation"].getSFVec3f(),
        lambda: robot.sensors["ds N"].getValue(),
        lambda: robot.leds["led N"].set(1),
        lambda: root.getField("children"),
    ]
    for call in calls:
        with pytest.raises(WebotsExited):
            call()
    assert robot.calls_after_end == [
        "Robot.step",
        "Supervisor.getSelf",
        "Node.getField",
        "Field.getSFVec3f",
        "DistanceSensor.getValue",
        "LED.set",
        "Node.getField",
    ]
    assert not scene.robot("unit2").exited  # each controller ends at its own -1


def test_the_double_answers_as_webots_does(make: Make, capsys: pytest.CaptureFixture[str]) -> None:
    _, robot, scene = make(units=["unit1"])  # unit2..unit4 are mirrors here
    # The C function behind getSFBool returns an int, and Webots' Python passes it on.
    flags = [scene.robot(u).node.fields["mirror"].getSFBool() for u in ("unit1", "unit2")]
    assert flags == [0, 1] and all(type(f) is int for f in flags)
    # A vector that is not a list is refused with a message, and nothing moves.
    translation = robot.node.fields["translation"]
    translation.setSFVec3f((0.1, 0.0, 0.05))  # type: ignore[arg-type]
    assert robot.step(int(robot.getBasicTimeStep())) == 0
    assert robot.applied == [] and robot.square() == Cell(0, 0)
    assert "Error: new field value has wrong type or length." in capsys.readouterr().err


def test_other_units_are_known_only_from_what_they_said(make: Make) -> None:
    world, _, _ = make()
    with pytest.raises(KeyError):
        world.position("unit2")
    world.observe("unit2", Cell(5, 5))
    world.observe("unit1", Cell(7, 7))  # its own square comes from Webots, not from messages
    assert dict(world.positions) == {"unit1": Cell(0, 0), "unit2": Cell(5, 5)}
    for call in (lambda: world.sense("unit2"), lambda: world.move("unit2", E)):
        with pytest.raises(KeyError):
            call()


def test_resume_puts_the_unit_back_where_it_stood(make: Make) -> None:
    world, robot, scene = make()
    world.resume("unit1", Cell(0, 4))
    assert robot.square() == Cell(0, 4) == world.position("unit1")
    assert scene.jumps == [("unit1", Cell(0, 0), Cell(0, 4))]
    assert world.moves == {"unit1": 0}


def test_a_robot_without_the_grid_units_devices_is_refused(make: Make, scenario: Scenario) -> None:
    _, robot, _ = make()
    del robot.leds["led W"]
    with pytest.raises(ConfigError, match="grid unit 'unit1': no device 'led W'"):
        WebotsWorld(robot, "unit1", scenario.grid)


# ---- the settings in the GridUnit's fields --------------------------------------------------


def test_the_settings_come_from_the_world_file(make: Make, scenario: Scenario) -> None:
    _, robot, _ = make(unit="unit3", brokers={"unit3": "mqtt://10.1.2.3:1883"}, step_s=0.25)
    settings = read_settings(robot, environ={})
    spec = scenario.unit("unit3")
    assert (settings.unit_id, settings.start, settings.capacity_kg, settings.color) == (
        "unit3",
        spec.start,
        spec.capacity,
        spec.color,
    )
    assert settings.grid.map_id() == scenario.grid.map_id()  # the coordinator accepts it
    assert (settings.step_s, settings.broker, settings.root) == (
        0.25,
        "mqtt://10.1.2.3:1883",
        "gridfleet",
    )


def test_the_mirror_field_is_a_bool_though_webots_gives_an_int(make: Make) -> None:
    _, robot, scene = make(units=["unit1"])
    assert read_settings(robot, environ={}).mirror is False
    assert read_settings(scene.robot("unit2"), environ={}).mirror is True


def test_an_empty_broker_field_takes_the_environment_then_the_default(make: Make) -> None:
    _, robot, _ = make()
    assert read_settings(robot, environ={}).broker == "mqtt://127.0.0.1:1883"
    assert read_settings(robot, environ={BROKER_ENV: "mqtt://fleet:1883"}).broker == (
        "mqtt://fleet:1883"
    )
    _, robot, _ = make(brokers={"unit1": "mqtt://mine:1883"})
    assert read_settings(robot, environ={BROKER_ENV: "mqtt://fleet:1883"}).broker == (
        "mqtt://mine:1883"
    )


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"name": ("bad id",)}, "'bad id' is not a valid id"),
        ({"capacity": (0.0,)}, "field 'capacity': 0.0 kg"),
        ({"stepPeriod": (-1.0,)}, "field 'stepPeriod' -1: the step period must be in"),
        ({"map": []}, "field 'map': no rows"),
        ({"map": ["..", "..."]}, "field 'map': rows of different lengths"),
        ({"map": ["..x"]}, "field 'map': unknown square 'x'"),
        ({"map": ["@.."]}, "stands on square [0, 0], which is off the map or blocked"),
        ({"broker": ("ftp://x",)}, "field 'broker': broker URL 'ftp://x'"),
        ({"root": ("a/#",)}, "field 'root': topic root 'a/#'"),
        ({"color": (2.0, 0.0, 0.0)}, "field 'color': a colour is three numbers"),
        ({"capacity": None}, "no field 'capacity' (is it a GridUnit from gridfleet?)"),
        (
            {"battery": (True,), "batteryPct": (101.0,)},
            "field 'batteryPct': 101: give a number from 0 to 100 (% of a full charge)",
        ),
        ({"battery": (True,), "movePct": (-0.5,)}, "field 'movePct': -0.5: give a number from 0"),
        ({"battery": (True,), "chargePctPerS": (0.0,)}, "field 'chargePctPerS': 0: give a number"),
        ({"chargers": (0.5, 2.0)}, "field 'chargers': square 0.5 2 is not a free square"),
        ({"chargers": (12.0, 2.0)}, "field 'chargers': square 12 2 is not a free square"),
    ],
)
def test_bad_fields_are_refused_in_one_line(
    make: Make, change: dict[str, object], message: str
) -> None:
    _, robot, _ = make()
    for name, value in change.items():
        if name == "name":
            robot.unit_id = str(value[0])  # type: ignore[index]
        elif value is None:
            del robot.node.fields[name]
        else:
            robot.node.fields[name].value = value  # type: ignore[assignment]
    with pytest.raises(ConfigError) as caught:
        read_settings(robot, environ={BROKER_ENV: "mqtt://ignored:1"} if "broker" in change else {})
    text = str(caught.value)
    assert "\n" not in text and text.startswith("grid unit "), text
    assert message in text, text


def test_the_battery_and_the_chargers_come_from_the_world_file(scenario: Scenario) -> None:
    battery = BatterySpec(start_pct=40.0, move_pct=0.25, idle_pct_per_s=0.0, charge_pct_per_s=3.0)
    units = (replace(scenario.units[0], battery=battery), *scenario.units[1:])
    chargers = (ChargerSpec("C1", Cell(0, 9)), ChargerSpec("dock", Cell(9, 0)))
    powered = replace(scenario, units=units, chargers=chargers)
    scene = SceneDouble(world_text(powered), SharedTruth.from_scenario(powered))
    settings = read_settings(scene.robot("unit1"), environ={})
    assert settings.battery == battery
    assert settings.chargers == {Cell(0, 9), Cell(9, 0)}
    other = read_settings(scene.robot("unit2"), environ={})
    assert other.battery is None and other.chargers == settings.chargers
    unit = WebotsUnit(scene.robot("unit1"), settings)
    try:
        logic = unit.logic
        assert logic.battery is not None and logic.battery.pct == 40.0
        assert logic.chargers == settings.chargers
        factsheet = json.loads(unit.runner.core.on_connect(0.0)[1].payload)
        assert factsheet["model"] == MODEL and factsheet["energy"] == {
            "move_pct": 0.25,
            "idle_pct_per_s": 0.0,
            "charge_pct_per_s": 3.0,
        }
    finally:
        unit.webots.close()


def test_a_world_without_batteries_gives_units_that_never_run_down(make: Make) -> None:
    _, robot, _ = make()
    settings = read_settings(robot, environ={})
    assert settings.battery is None and settings.chargers == frozenset()
