"""A Webots grid unit in the fleet: the controller's code, driven through the test double of
Webots' API, over the real broker with the real coordinator, beside headless simulated units.

The Webots unit and the headless ones stand in one ground truth (`SharedTruth`, a WorldSim that
counts collisions): the double measures the unit's sensors in it and moves the unit in it when
its translation is set. The unit's settings come from the world file the generator writes.
"""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.grid import Cell, Direction
from gridfleet.ports import free_port
from gridfleet.protocol import Connection, Factsheet, Topics, decode
from gridfleet.robots.fleet import Fleet
from gridfleet.robots.webots.host import MODEL, WebotsUnit
from gridfleet.robots.webots.main import run_controller
from gridfleet.robots.webots.settings import read_settings
from gridfleet.robots.webots.world_file import WorldOptions, world_text
from gridfleet.scenario import Scenario, load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, coordinator_thread

from support.operator_peer import OperatorPeer
from support.paths import REPO
from support.probe import MqttProbe
from support.wait import wait_for
from support.webots_double import SceneDouble, SharedTruth, SupervisorDouble

CONTROLLER = REPO / "robots" / "webots" / "controllers" / "gridfleet_unit" / "gridfleet_unit.py"
STEP = 0.1
WEBOTS_UNIT = "unit4"  # capacity 20 kg: the only unit that can carry 15 kg
HEADLESS = ["unit1", "unit2", "unit3"]


class WebotsBesideHeadless:
    """The Webots unit and the scenario's other units as headless ones, in one event loop."""

    def __init__(
        self, scenario: Scenario, url: str, root: str, truth: SharedTruth, robot: SupervisorDouble
    ) -> None:
        self.fleet = Fleet(scenario, url, root=root, units=HEADLESS, step=STEP, world=truth)
        self.webots = WebotsUnit(robot, read_settings(robot, environ={}))
        self.ready = asyncio.Event()

    async def run(self, shutdown: asyncio.Event) -> None:
        async def watch() -> None:
            await self.fleet.ready.wait()
            await self.webots.ready.wait()
            self.ready.set()

        watcher = asyncio.create_task(watch())
        try:
            await asyncio.gather(self.fleet.run(shutdown), self.webots.run(shutdown))
        finally:
            watcher.cancel()


@pytest.fixture
def playfield_scene(broker: BrokerThread, root: str) -> tuple[Scenario, SceneDouble]:
    """The playfield's world as the generator writes it for this broker and root."""
    scenario = load_scenario(REPO / "maps" / "playfield.toml")
    options = WorldOptions(brokers={WEBOTS_UNIT: broker.url}, root=root, step_s=STEP)
    truth = SharedTruth.from_scenario(scenario)
    return scenario, SceneDouble(world_text(scenario, options), truth)


@pytest.fixture
def running(
    broker: BrokerThread,
    root: str,
    tmp_path: Path,
    playfield_scene: tuple[Scenario, SceneDouble],
) -> Iterator[tuple[ServiceThread, ServiceThread]]:
    """The coordinator, and the Webots unit beside three headless units, each in its thread."""
    scenario, scene = playfield_scene
    robot = scene.robot(WEBOTS_UNIT)

    def make() -> WebotsBesideHeadless:
        return WebotsBesideHeadless(scenario, broker.url, root, scene.truth, robot)

    coordinator = coordinator_thread(
        scenario, broker.url, root=root, step_s=STEP, db_path=tmp_path / "jobs.db"
    )
    units = ServiceThread(make, "units")
    with contextlib.ExitStack() as stack:
        stack.enter_context(coordinator)
        stack.enter_context(units)
        yield coordinator, units


@pytest.fixture
def operator(probe_factory: Callable[..., MqttProbe], topics: Topics) -> OperatorPeer:
    return OperatorPeer(probe_factory(), topics, "tester")


@pytest.mark.timeout(120)
def test_the_webots_unit_finishes_a_job_beside_headless_units_without_collisions(
    running: tuple[ServiceThread, ServiceThread],
    playfield_scene: tuple[Scenario, SceneDouble],
    operator: OperatorPeer,
    topics: Topics,
) -> None:
    coordinator, units = running
    _scenario, scene = playfield_scene
    robot = scene.robot(WEBOTS_UNIT)
    world = coordinator.service.world
    wait_for(
        lambda: coordinator.call(
            lambda: len(world.units) == 4 and all(u.state is not None for u in world.units.values())
        ),
        timeout=15,
        what="the coordinator knows all four units",
    )
    operator.probe.subscribe(topics.unit("factsheet", WEBOTS_UNIT))
    seen = operator.probe.wait(topics.unit("factsheet", WEBOTS_UNIT))
    assert decode(Factsheet, seen.payload).model == MODEL == "gridfleet-webots"

    # The heavy job only the Webots unit can carry; its pickup is beside the hidden obstacle
    # (7, 2), which its north sensor must find. Two light jobs keep the headless units busy.
    assert operator.submit_job(Cell(7, 3), Cell(2, 8), 15.0, job_id="heavy").accepted
    assert operator.submit_job(Cell(1, 1), Cell(8, 8), 1.5, job_id="light-1").accepted
    assert operator.submit_job(Cell(8, 1), Cell(1, 8), 4.0, job_id="light-2").accepted
    ids = ["heavy", "light-1", "light-2"]
    try:
        wait_for(lambda: operator.all_final(ids), timeout=60, what="the three jobs final")
    except AssertionError as exc:
        last = {u: operator.last_state(u) for u in [*HEADLESS, WEBOTS_UNIT]}
        where = {u: s and (list(s.position), s.status, s.wait_reason) for u, s in last.items()}
        jobs_now = {j: operator.job_state(j) for j in ids}
        raise AssertionError(f"{exc}: jobs {jobs_now}, units {where}") from exc
    jobs = operator.listed_jobs()
    assert {i: jobs[i].state for i in ids} == dict.fromkeys(ids, "done"), jobs
    assert jobs["heavy"].unit == WEBOTS_UNIT
    assert "heavy" in {s.job_id for s in operator.states(WEBOTS_UNIT)}

    service: WebotsBesideHeadless = units.service  # type: ignore[assignment]
    webots = service.webots
    # It moved by translation, one square at a time, each move the way its LEDs showed.
    assert len(robot.applied) >= 10
    for made in robot.applied:
        direction = Direction.between(made.start, made.end)
        assert direction is not None, made
        assert made.lit == frozenset(direction.value), made
    assert scene.jumps == []
    # Its sensors found the hidden obstacle, and it stands where Webots has it.
    assert units.call(lambda: Cell(7, 2) in webots.logic.known_obstacles)
    assert units.call(lambda: webots.logic.position == robot.square())
    # Zero collisions in the ground truth that every unit moved in, and none seen by Webots.
    assert scene.truth.collisions == 0, scene.truth.log
    assert scene.truth.prevented == 0
    assert units.call(lambda: webots.world.collisions) == 0
    assert robot.steps > len(robot.applied)  # Webots was stepped between the moves too


@pytest.mark.timeout(90)
def test_webots_ending_the_controller_as_the_unit_moves_it_says_offline_and_calls_webots_no_more(
    running: tuple[ServiceThread[CoordinatorShell], ServiceThread[WebotsBesideHeadless]],
    playfield_scene: tuple[Scenario, SceneDouble],
    operator: OperatorPeer,
    topics: Topics,
) -> None:
    coordinator, _units = running
    _scenario, scene = playfield_scene
    robot = scene.robot(WEBOTS_UNIT)
    world = coordinator.service.world
    wait_for(
        lambda: coordinator.call(lambda: WEBOTS_UNIT in world.units),
        timeout=15,
        what="the coordinator knows the Webots unit",
    )
    connection = topics.unit("connection", WEBOTS_UNIT)
    operator.probe.wait(connection, lambda m: decode(Connection, m.payload).state == "online")
    # Webots quits in the step that would make the unit's first move.
    scene.end_on_move = True
    assert operator.set_goal(WEBOTS_UNIT, Cell(9, 6)).accepted
    operator.probe.wait(
        connection, lambda m: decode(Connection, m.payload).state == "offline", timeout=30
    )
    assert robot.exited and robot.calls_after_end == []
    assert robot.applied == [] and robot.square() == Cell(9, 9)  # the move was never made
    states = [
        s.state
        for s in (decode(Connection, m.payload) for m in operator.probe.received(connection))
    ]
    assert "broken" not in states, states  # the goodbye, not the broker's last will


def test_webots_ending_the_controller_ends_it_cleanly_even_without_a_broker(
    playfield_scene: tuple[Scenario, SceneDouble], capsys: pytest.CaptureFixture[str]
) -> None:
    _scenario, scene = playfield_scene
    robot = scene.robot("unit1")
    robot.node.fields["broker"].value = (f"mqtt://127.0.0.1:{free_port()}",)  # nothing listens
    scene.end_at_step = 8
    assert run_controller(robot) == 0
    assert scene.ended.is_set() and robot.steps == 7
    assert robot.exited and robot.calls_after_end == []
    assert robot.applied == []  # never connected: it held still


def test_a_bad_field_stops_the_controller_with_one_line(
    playfield_scene: tuple[Scenario, SceneDouble], capsys: pytest.CaptureFixture[str]
) -> None:
    _, scene = playfield_scene
    robot = scene.robot("unit2")
    robot.node.fields["capacity"].value = (-1.0,)
    assert run_controller(robot) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "gridfleet_unit unit2: error: grid unit 'unit2': field 'capacity': -1.0 kg; give a number > 0"
    ]
    assert robot.steps == 0


def test_the_controller_script_outside_webots_says_so_in_one_line() -> None:
    assert CONTROLLER.stem == CONTROLLER.parent.name  # Webots finds it by its folder's name
    done = subprocess.run(
        [sys.executable, str(CONTROLLER)], capture_output=True, text=True, timeout=60, cwd="/"
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "gridfleet_unit: error: no Webots controller module; Webots runs this controller "
        "(robots/webots/README.md)"
    ]


def test_the_controller_in_a_python_without_gridfleet_names_that_python(tmp_path: Path) -> None:
    # Webots runs the Python set in its preferences: one without gridfleet installed is said so.
    bare = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(bare)], check=True)
    python = bare / "bin" / "python"
    done = subprocess.run(
        [str(python), str(CONTROLLER)], capture_output=True, text=True, timeout=60, cwd="/"
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"gridfleet_unit: error: gridfleet is not installed in the Python Webots runs ({python}); "
        "set Webots' Python command to gridfleet's virtual environment (robots/webots/README.md)"
    ]
