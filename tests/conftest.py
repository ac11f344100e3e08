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
# The clusters (`aedes`: aedes instances sharing a Redis; `rabbitmq`: a three-node RabbitMQ) are
# brokers of their own kind: each client a test makes starts on the next node of the list.
KNOWN_BROKER_KINDS = ("amqtt", "mosquitto", "aedes", "rabbitmq")
CLUSTER_KINDS = ("aedes", "rabbitmq")
BROKER_KINDS = tuple(os.environ.get("GRIDFLEET_TEST_BROKER", "amqtt").split(","))
if not BROKER_KINDS or any(k not in KNOWN_BROKER_KINDS for k in BROKER_KINDS):
    raise pytest.UsageError(
        f"GRIDFLEET_TEST_BROKER={','.join(BROKER_KINDS)!r}: give one or more of"
        f" {', '.join(KNOWN_BROKER_KINDS)}, comma-separated"
    )


# What RabbitMQ 3.10 cannot be asked, measured in tests/broker/test_rabbitmq_cluster.py and said
# in docs/brokers.md: these tests are skipped on it, with the reason, and run on every other kind.
RABBITMQ_RETAINED = (
    "RabbitMQ 3.10 keeps retained messages per node and never gives them to a wildcard "
    "subscription (rabbitmq-server #8096): a late reader on another node, or any `+`/`#` "
    "reader, gets none"
)
RABBITMQ_RESTART = (
    "a whole RabbitMQ 3.10 cluster restarted on its data takes no client for minutes (its MQTT "
    "client-id tracking waits for a Raft leader), so the suite's restart makes a new cluster, "
    "slower than these tests' bounds; a node's death and return are tested on it instead"
)
RABBITMQ_CANNOT = {
    "test_the_operator_reads_units_the_coordinator_and_the_stop": RABBITMQ_RETAINED,
    "test_clean_clears_a_root_and_leaves_the_others": RABBITMQ_RETAINED,
    "test_paho_clients_exchange_a_retained_message": RABBITMQ_RETAINED,
    "test_websocket_client_sees_what_a_tcp_client_retained": RABBITMQ_RETAINED,
    "test_late_client_sees_every_retained_topic_at_once": RABBITMQ_RETAINED,
    "test_server_keeps_the_latest_messages_for_a_late_client": RABBITMQ_RETAINED,
    "test_a_new_client_gets_only_the_retained_messages_it_subscribed_to": RABBITMQ_RETAINED,
    "test_only_the_retained_kinds_reach_a_late_subscriber": RABBITMQ_RETAINED,
    "test_a_warehouse_systems_day": RABBITMQ_RETAINED,  # the map view, retained
    "test_connection_online_then_offline_on_a_clean_stop": RABBITMQ_RETAINED,  # status, retained
    "test_a_send_failing_late_on_the_dropped_connection_leaves_the_new_one_alone": (
        RABBITMQ_RETAINED  # the coordinator's status, retained
    ),
    "test_a_vda_adapter_failing_on_states_is_reported_counted_alerted_and_shown": (
        RABBITMQ_RETAINED
    ),
    "test_a_lost_unit_is_removed_for_good_and_comes_back_only_as_new": RABBITMQ_RETAINED,
    "test_a_client_silent_for_one_and_a_half_keep_alives_is_gone_and_its_will_is_sent": (
        RABBITMQ_RETAINED  # the will, read back retained
    ),
    "test_a_units_host_cut_silently_is_broken_its_job_waits_and_it_resumes_in_place": (
        RABBITMQ_RETAINED
    ),
    # Its monitor reads the units' first states by a wildcard: given no retained one, it missed
    # the first when it subscribed after it (a fresh-clone run: first seen a move on).
    "test_01_a_unit_moves_in_the_simulated_space": RABBITMQ_RETAINED,
    "test_broker_restarts_on_the_same_ports": RABBITMQ_RESTART,
    "test_reconnects_and_resubscribes_after_a_broker_restart": RABBITMQ_RESTART,
    "test_press_while_broker_is_down_is_sent_after_reconnect": RABBITMQ_RESTART,
    "test_reconnects_after_broker_restart": RABBITMQ_RESTART,
    "test_stop_pressed_while_broker_is_down_is_sent_when_it_returns": RABBITMQ_RESTART,
    "test_units_reconnect_after_a_broker_restart": RABBITMQ_RESTART,
}


def _kind_of(item: pytest.Item) -> str | None:
    """The suite broker's kind `item` runs on; None when it uses none."""
    if "broker_kind" not in getattr(item, "fixturenames", ()):
        return None
    callspec = getattr(item, "callspec", None)
    params = {} if callspec is None else callspec.params
    return str(params.get("broker_kind", BROKER_KINDS[0]))


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
    if kind == "aedes":
        from support.aedes import AedesCluster

        return AedesCluster(tmp.mktemp("aedes"))  # type: ignore[return-value]  # duck-typed
    if kind == "rabbitmq":
        from support.rabbitmq import RabbitCluster

        return RabbitCluster(tmp.mktemp("rabbitmq"))  # type: ignore[return-value]  # duck-typed
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
    for item in items:
        why = RABBITMQ_CANNOT.get(getattr(item, "originalname", item.name))
        if why is not None and _kind_of(item) == "rabbitmq":
            item.add_marker(pytest.mark.skip(reason=why))
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
