"""A mirror in a Webots world (through the test double) follows a unit that runs elsewhere."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Iterator

import pytest

from gridfleet.grid import Cell, Direction
from gridfleet.protocol import HeaderStamper, Topics, encode
from gridfleet.robots.unit import UnitLogic
from gridfleet.robots.webots.mirror import MirrorUnit
from gridfleet.robots.webots.settings import read_settings
from gridfleet.robots.webots.world_file import WorldOptions, world_text
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.paths import MAPS
from support.probe import MqttProbe
from support.wait import wait_for
from support.webots_double import SceneDouble, SharedTruth, SupervisorDouble

PLAYFIELD = MAPS / "playfield.toml"


@pytest.fixture
def mirrored(broker: BrokerThread, root: str) -> Iterator[tuple[SupervisorDouble, ServiceThread]]:
    """unit2's mirror in a world that runs unit1 only, following unit2's state on the broker."""
    scenario = load_scenario(PLAYFIELD)
    options = WorldOptions(units=["unit1"], brokers={"unit2": broker.url}, root=root)
    scene = SceneDouble(world_text(scenario, options), SharedTruth.from_scenario(scenario))
    robot = scene.robot("unit2")
    settings = read_settings(robot, environ={})
    assert settings.mirror
    with ServiceThread(lambda: MirrorUnit(robot, settings), "mirror") as mirror:
        yield robot, mirror


def state_of(unit: str, at: Cell, heading: Direction | None, estop: bool = False) -> bytes:
    """The state a unit at `at` heading `heading` publishes."""
    logic = UnitLogic(unit, load_scenario(PLAYFIELD).grid, at, 5.0, 0.1)
    logic.direction, logic.estop = heading, estop
    return encode(logic.report(HeaderStamper(unit)("state")))


def test_the_mirror_stands_and_lights_where_the_units_state_says(
    mirrored: tuple[SupervisorDouble, ServiceThread],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
) -> None:
    robot, mirror = mirrored
    probe = probe_factory()
    topic = topics.unit("state", "unit2")
    service: MirrorUnit = mirror.service  # type: ignore[assignment]
    assert robot.square() == Cell(9, 0)  # its start in the world file
    probe.publish(topic, state_of("unit2", Cell(8, 0), Direction.S), qos=1)
    wait_for(lambda: robot.square() == Cell(8, 0), timeout=10, what="the mirror moved")
    wait_for(lambda: robot.lit() == frozenset("S"), timeout=10, what="its LED S lit")
    probe.publish(topic, b"{not a state", qos=1)
    probe.publish(topic, state_of("unit2", Cell(8, 1), None, estop=True), qos=1)
    wait_for(lambda: robot.square() == Cell(8, 1), timeout=10, what="the mirror moved again")
    wait_for(lambda: robot.lit() == frozenset("NESW"), timeout=10, what="all four: stopped")
    assert mirror.call(lambda: service.states) == 2  # the bad payload changed nothing
    assert [(a.start, a.end) for a in robot.applied] == [
        (Cell(9, 0), Cell(8, 0)),
        (Cell(8, 0), Cell(8, 1)),
    ]
    # A mirror says nothing: no retained `connection` (every unit's first word) came with the
    # subscription, before a marker published after it.
    probe.subscribe(topics.all_units("connection"))
    probe.publish(topics.unit("connection", "marker"), b"{}", qos=1)
    probe.wait(topics.unit("connection", "marker"))
    assert probe.received(topics.unit("connection", "unit2")) == []


def test_a_state_after_webots_ended_the_controller_moves_nothing_and_calls_webots_no_more() -> None:
    # A state can arrive between the step that returned -1 and the mirror's stop.
    scenario = load_scenario(PLAYFIELD)
    truth = SharedTruth.from_scenario(scenario)
    assert isinstance(truth, SharedTruth)
    scene = SceneDouble(world_text(scenario, WorldOptions(units=["unit1"])), truth)
    robot = scene.robot("unit2")
    mirror = MirrorUnit(robot, read_settings(robot, environ={}))
    try:
        scene.ended.set()
        assert not mirror.webots.call(mirror.world.advance)
        state = state_of("unit2", Cell(8, 0), Direction.S)
        asyncio.run(mirror._follow(mirror.topic, state))
    finally:
        mirror.webots.close()
    assert robot.exited and robot.calls_after_end == []
    assert (robot.square(), robot.applied, robot.lit()) == (Cell(9, 0), [], frozenset())
