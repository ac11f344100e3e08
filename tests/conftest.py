"""Shared fixtures: a real broker on free loopback ports (amqtt, or Mosquitto), and a topic root
per test."""

from __future__ import annotations

import gc
import os
import re
import zlib
from collections.abc import Callable, Generator, Iterator
from pathlib import Path

import pytest

from gridfleet.protocol import Topics
from gridfleet.scenario import Scenario, load_scenario
from gridfleet.system.assembly import Assembly, SystemSpec
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.mosquitto import MosquittoBroker
from support.paths import MAPS
from support.probe import MqttProbe

# Which brokers the `broker` and `fresh_broker` fixtures start: the embedded amqtt (the default),
# Debian's Mosquitto, or both, comma-separated (`make test` asks for both, `make test-mosquitto`
# for Mosquitto alone). Asked for both, a test whose verdict depends on what the broker itself does
# (accounts and their rules, TLS, wills and keep-alives, retained messages, limits, links cut) says
# so with the `every_broker` marker and runs on each; any other test runs on one of them, the same
# one every run. Tests that are about amqtt itself say so with the `amqtt_only` marker.
BROKER_KINDS = tuple(os.environ.get("GRIDFLEET_TEST_BROKER", "amqtt").split(","))
if not BROKER_KINDS or any(k not in ("amqtt", "mosquitto") for k in BROKER_KINDS):
    raise pytest.UsageError(
        f"GRIDFLEET_TEST_BROKER={','.join(BROKER_KINDS)!r}: give amqtt, mosquitto or amqtt,mosquitto"
    )


def _kinds_for(definition: pytest.Item) -> tuple[str, ...]:
    """The brokers a test that uses the suite's broker runs on."""
    if definition.get_closest_marker("amqtt_only") is not None:
        return tuple(k for k in BROKER_KINDS if k == "amqtt")
    if definition.get_closest_marker("every_broker") is not None:
        return BROKER_KINDS
    # The fleet's own behaviour over MQTT: running it again on the other broker mostly repeats
    # it, and the suite is bound by the machine's two cores. Its name picks the broker (not a
    # random draw: a failure comes back on the same one), which spreads them about evenly. The name
    # is the one it had before the test modules went into their component's folder
    # (`tests/test_x.py::test_y`), so each test kept its broker.
    name = re.sub(r"^tests/[^/]+/", "tests/", definition.nodeid.split("[", 1)[0])
    return (BROKER_KINDS[zlib.crc32(name.encode()) % len(BROKER_KINDS)],)


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """A test that uses the suite's broker runs once on each of its brokers (`_kinds_for`), its
    id saying which (`[amqtt]`, `[mosquitto]`); asked for one broker, its id stays as it is."""
    if "broker_kind" not in metafunc.fixturenames:
        return  # no suite broker (a module may have a `broker` fixture of its own)
    kinds = _kinds_for(metafunc.definition)
    if len(BROKER_KINDS) > 1 and kinds:  # an amqtt-only test too, so its kind is never a default
        # Session scope: pytest keeps each broker's tests together, so a test worker starts each
        # session broker about once, not once a test.
        metafunc.parametrize("broker_kind", kinds, indirect=True, scope="session")


@pytest.fixture(scope="session")
def broker_kind(request: pytest.FixtureRequest) -> str:
    """The kind of broker this test's `broker` or `fresh_broker` is."""
    return str(getattr(request, "param", BROKER_KINDS[0]))


def _start_broker(tmp: pytest.TempPathFactory, kind: str) -> BrokerThread | MosquittoBroker:
    if kind == "mosquitto":
        return MosquittoBroker(tmp.mktemp("mosquitto"))
    return BrokerThread()


@pytest.fixture(scope="session")
def broker(tmp_path_factory: pytest.TempPathFactory, broker_kind: str) -> Iterator[BrokerThread]:
    """One broker of each kind for the session; tests keep apart through their own topic root."""
    with _start_broker(tmp_path_factory, broker_kind) as running:
        yield running  # type: ignore[misc]  # Mosquitto: the same interface, duck-typed


@pytest.fixture
def fresh_broker(
    tmp_path_factory: pytest.TempPathFactory, broker_kind: str
) -> Iterator[BrokerThread]:
    """A broker of this test's own, for tests that stop or restart it."""
    with _start_broker(tmp_path_factory, broker_kind) as running:
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
    """The `waits_first` tests first; without amqtt among the brokers, only the tests that talk
    to the suite's broker, and not the amqtt-only ones.

    The others (pure cores, parsers, systems with a broker of their own) run the same whatever
    broker the fixtures would start; a run with amqtt among its brokers runs them, once.
    """
    # First in line (stable, so every worker collects the same order): pytest-xdist hands each
    # worker a block of the collection and steals from a block's end, so these run one after
    # another in the first worker's block while the others take what needs the cores. Last in
    # line, they ran on alone for 30 s after the rest had finished.
    items.sort(key=lambda item: item.get_closest_marker("waits_first") is None)
    if "amqtt" in BROKER_KINDS:
        return
    keep, drop = [], []
    for item in items:
        uses = "broker_kind" in getattr(item, "fixturenames", ())
        (keep if uses and _kinds_for(item) else drop).append(item)
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
