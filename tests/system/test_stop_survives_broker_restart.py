"""A latched stop is back on a restarted broker that kept nothing, within a step of the coordinator's
return: it re-asserts the latch when no retained one arrives (protocol.md §5.1); on amqtt and on
Mosquitto, each without persistence."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path

import pytest

from gridfleet.config import broker_urls
from gridfleet.ports import free_port
from gridfleet.protocol import Topics, decode_estop
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, coordinator_thread

from support.mosquitto import running_mosquitto
from support.paths import MAPS
from support.probe import MqttProbe, retained_latch
from support.wait import wait_for

pytestmark = pytest.mark.every_broker  # a broker restarted with nothing kept

PLAYFIELD = MAPS / "playfield.toml"
ROOT = "restart"
T = Topics(ROOT)
STEP_S = 0.1

# A broker that can be stopped and started again on the same port: (url, restart).
Restartable = tuple[str, Callable[[], None]]


@pytest.fixture
def amqtt() -> Iterator[Restartable]:
    with BrokerThread() as broker:
        yield broker.url, broker.restart


@pytest.fixture
def mosquitto(tmp_path: Path) -> Iterator[Restartable]:
    port = free_port()

    def conf(p: int) -> str:
        return f"allow_anonymous true\npersistence false\nlistener {p} 127.0.0.1\n"

    running: list[AbstractContextManager[int]] = [running_mosquitto(tmp_path, conf, port)]
    running[0].__enter__()

    def restart() -> None:
        running[0].__exit__(None, None, None)
        running[0] = running_mosquitto(tmp_path, conf, port)
        running[0].__enter__()

    try:
        yield f"mqtt://127.0.0.1:{port}", restart
    finally:
        running[0].__exit__(None, None, None)


@pytest.fixture
def rabbitmq(tmp_path: Path) -> Iterator[Restartable]:
    """A three-node RabbitMQ cluster; its restart is a new cluster that kept nothing."""
    from support.rabbitmq import SBIN, RabbitCluster

    if not (SBIN / "rabbitmq-server").exists():
        pytest.skip("no rabbitmq-server 3.10.8")
    with RabbitCluster(tmp_path / "rabbitmq") as cluster:
        yield cluster.url, cluster.restart


# `kind`, not `broker`: the suite's broker fixture is `broker`, and a test named as using it runs
# again on Mosquitto (conftest.py); this one starts both brokers of its own, once is enough.
@pytest.mark.parametrize(
    "kind",
    [
        "amqtt",
        "mosquitto",
        # A RabbitMQ cluster forms in 25-40 s, twice here (start, restart).
        pytest.param("rabbitmq", marks=[pytest.mark.timeout(180), pytest.mark.slow]),
    ],
)
def test_the_latched_stop_is_back_on_a_broker_that_restarted_empty(
    kind: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    url, restart = request.getfixturevalue(kind)
    coordinator: ServiceThread = coordinator_thread(
        load_scenario(PLAYFIELD), url, root=ROOT, step_s=STEP_S, db_path=tmp_path / "jobs.db"
    ).start(30)
    try:
        with MqttProbe(url) as operator:
            operator.publish(T.fleet("estop"), b"engaged|operator|soak", qos=1, retain=True)
            core = coordinator.service.core
            wait_for(lambda: coordinator.call(lambda: core.estop), what="the coordinator stopped")
        restart()
        assert retained_latch(url, T) in (
            None,
            b"engaged|operator|soak",
        )  # the broker may be empty now
        # On any node of the list: a cluster's retained messages may be node-local (RabbitMQ's
        # are), and the coordinator re-asserts on the node it came back on, any of its list.
        # Nothing but the coordinator writes the latch here, on a broker that kept nothing.
        nodes = broker_urls(url)
        engaged = wait_for(
            lambda: next(filter(None, (retained_latch(node, T) for node in nodes)), None),
            20,
            what="the latch back on the broker",
        )
        assert decode_estop(engaged).engaged and decode_estop(engaged).by == "operator"
    finally:
        coordinator.stop(30)
