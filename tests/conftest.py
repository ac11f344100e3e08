"""Shared fixtures: a real amqtt broker on free loopback ports, and a topic root per test."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from gridfleet.protocol import Topics
from gridfleet.scenario import Scenario, load_scenario
from system.assembly import Assembly, SystemSpec
from system.broker_thread import BrokerThread
from system.threads import ServiceThread

from support.probe import MqttProbe

REPO = Path(__file__).resolve().parent.parent
MAPS = REPO / "maps"


@pytest.fixture(scope="session")
def broker() -> Iterator[BrokerThread]:
    """One embedded broker for the session; tests keep apart through their own topic root."""
    with BrokerThread() as running:
        yield running


@pytest.fixture
def fresh_broker() -> Iterator[BrokerThread]:
    """A broker of this test's own, for tests that stop or restart it."""
    with BrokerThread() as running:
        yield running


@pytest.fixture
def root(request: pytest.FixtureRequest) -> str:
    """A topic root unique to this test, so tests sharing the broker never see each other."""
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", request.node.name)[:48]
    return f"t/{name}-{id(request.node) % 100000}"


@pytest.fixture
def topics(root: str) -> Topics:
    """Topic names under this test's root."""
    return Topics(root)


@pytest.fixture
def probe_factory(broker: BrokerThread) -> Iterator[Callable[..., MqttProbe]]:
    """Make connected MqttProbes on the session broker; all closed after the test."""
    made: list[MqttProbe] = []

    def make(url: str | None = None, client_id: str | None = None) -> MqttProbe:
        probe = MqttProbe(url or broker.url, client_id).connect()
        made.append(probe)
        return probe

    yield make
    for p in made:
        p.close()


@pytest.fixture
def playfield() -> Path:
    """The course's playfield scenario."""
    return MAPS / "playfield.toml"


# Browser fixtures of the dashboard (`chromium`, `open_dashboard`), usable by any test.
pytest_plugins = ["support.browser"]


@pytest.fixture
def run_system(
    broker: BrokerThread, root: str, tmp_path: Path
) -> Iterator[Callable[..., tuple[ServiceThread, ServiceThread]]]:
    """Factory: the real coordinator and units of a scenario on the session broker, in threads."""
    running: list[Assembly] = []

    def start(
        scenario: Path | Scenario, step_s: float = 0.05
    ) -> tuple[ServiceThread, ServiceThread]:
        loaded = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        spec = SystemSpec(
            loaded, broker=broker.url, root=root, step_s=step_s, db_path=tmp_path / "jobs.db"
        )
        assembly = Assembly(spec, "threads")
        running.append(assembly)
        system = assembly.start_threads()
        return system.coordinator, system.fleet

    yield start
    for assembly in reversed(running):
        assembly.stop()
