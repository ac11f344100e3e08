"""The test harness that runs the real coordinator and units in threads."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

import pytest

from gridfleet.grid import Cell
from gridfleet.protocol import Topics
from gridfleet.system.threads import ServiceThread, world_of

from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.wait import wait_for


def test_system_runs_a_goal_and_stops_cleanly(
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
    playfield: Path,
) -> None:
    _, fleet = run_system(playfield)
    world = world_of(fleet)
    operator = OperatorPeer(probe_factory(), topics, "tester")
    assert operator.set_goal("unit2", Cell(8, 8)).accepted
    wait_for(lambda: world.positions["unit2"] == (8, 8), timeout=30, what="unit2 at its goal")
    assert world.collisions == 0


class _Broken:
    """A service that fails while starting."""

    def __init__(self) -> None:
        self.ready = asyncio.Event()

    async def run(self, shutdown: asyncio.Event) -> None:
        raise ValueError("no such broker")


def test_a_service_that_dies_while_starting_raises_its_error() -> None:
    with pytest.raises(ValueError, match="no such broker"):
        ServiceThread(_Broken, "broken").start(timeout=5)
