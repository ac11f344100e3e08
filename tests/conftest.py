"""Shared fixtures: a real broker on free loopback ports (amqtt, or Mosquitto), and a topic root
per test."""

from __future__ import annotations

import gc
import os
import re
from collections.abc import Callable, Generator, Iterator
from pathlib import Path

import pytest

from gridfleet.protocol import Topics
from gridfleet.scenario import Scenario, load_scenario
from gridfleet.system.assembly import Assembly, SystemSpec
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.mosquitto import MosquittoBroker
from support.probe import MqttProbe

REPO = Path(__file__).resolve().parent.parent
MAPS = REPO / "maps"


# Which broker the `broker` and `fresh_broker` fixtures start: the embedded amqtt (default), or
# Debian's Mosquitto (`make test-mosquitto`). Tests that are about amqtt itself say so with the
# `amqtt_only` marker.
BROKER_KIND = os.environ.get("GRIDFLEET_TEST_BROKER", "amqtt")
if BROKER_KIND not in ("amqtt", "mosquitto"):
    raise pytest.UsageError(f"GRIDFLEET_TEST_BROKER={BROKER_KIND!r}: give amqtt or mosquitto")
BROKER_FIXTURES = {"broker", "fresh_broker"}


def _start_broker(tmp: pytest.TempPathFactory) -> BrokerThread | MosquittoBroker:
    if BROKER_KIND == "mosquitto":
        return MosquittoBroker(tmp.mktemp("mosquitto"))
    return BrokerThread()


@pytest.fixture(scope="session")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[BrokerThread]:
    """One broker for the session; tests keep apart through their own topic root."""
    with _start_broker(tmp_path_factory) as running:
        yield running  # type: ignore[misc]  # Mosquitto: the same interface, duck-typed


@pytest.fixture
def fresh_broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[BrokerThread]:
    """A broker of this test's own, for tests that stop or restart it."""
    with _start_broker(tmp_path_factory) as running:
        yield running  # type: ignore[misc]


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    """A failure's report is written with the garbage collector paused."""
    # On CPython 3.11 (gh-106905) an ast.parse run by a finaliser inside pytest's own ast.parse of
    # the failing source (a coroutine of a closed loop, collected then, formats its traceback)
    # raised "AST constructor recursion depth mismatch": an INTERNALERROR ended the whole run and
    # hid the failure it was reporting.
    enabled = gc.isenabled()
    gc.disable()
    try:
        return (yield)
    finally:
        if enabled:
            gc.enable()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """On Mosquitto: only the tests that talk to the suite's broker, and not the amqtt-only ones.

    The others (pure cores, parsers, systems with a broker of their own) run the same whatever
    broker the fixtures would start; `make test` runs them, once.
    """
    if BROKER_KIND != "mosquitto":
        return
    keep, drop = [], []
    for item in items:
        uses = set(getattr(item, "fixturenames", ())) & BROKER_FIXTURES
        (keep if uses and item.get_closest_marker("amqtt_only") is None else drop).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep


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


# Browser fixtures of the dashboard (`chromium`, `open_dashboard`) and a LAN of network
# namespaces (`test_lan`), usable by any test.
pytest_plugins = ["support.browser", "support.lan"]


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
