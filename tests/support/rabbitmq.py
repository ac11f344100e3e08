"""A real three-node RabbitMQ 3.10 cluster for tests: the shipped one
(gridfleet.broker.rabbitmq_cluster: Debian's rabbitmq-server with its MQTT plugins, every node on
free loopback ports, its own epmd and cookie), in the test's own folder; a node that cannot start
fails the test with the line that says why."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from gridfleet.accounts import Accounts
from gridfleet.broker import rabbitmq_cluster
from gridfleet.broker.cluster_nodes import ClusterError
from gridfleet.broker.rabbitmq import write_definitions
from gridfleet.protocol import Topics

EPMD = rabbitmq_cluster.EPMD
SBIN = rabbitmq_cluster.SBIN
START_TIMEOUT_S = rabbitmq_cluster.START_TIMEOUT_S


class RabbitCluster(rabbitmq_cluster.RabbitCluster):
    """The shipped cluster as the suite's broker (GRIDFLEET_TEST_BROKER=rabbitmq); a node that
    cannot start fails the test with why."""

    def start(self, timeout: float = START_TIMEOUT_S) -> None:
        """Start a new cluster (the test fails if a node cannot start)."""
        try:
            super().start(timeout)
        except ClusterError as exc:
            pytest.fail(str(exc))

    def start_node(self, i: int, timeout: float = START_TIMEOUT_S) -> None:
        """Start node `i` (again); it rejoins the cluster (the test fails if it cannot)."""
        try:
            super().start_node(i, timeout)
        except ClusterError as exc:
            pytest.fail(str(exc))

    def __enter__(self) -> RabbitCluster:
        self.start()
        return self


@contextmanager
def rabbitmq_with_accounts(
    accounts: Accounts, topics: Topics, directory: Path
) -> Iterator[RabbitCluster]:
    """A RabbitMQ cluster with the definitions 'gridfleet accounts rabbitmq' writes: anonymous
    clients refused, each account's topics as the embedded broker's rules say."""
    if not (SBIN / "rabbitmq-server").exists():
        pytest.fail("rabbitmq-server 3.10.8 is not installed: make test installs it (apt-get)")
    definitions = write_definitions(accounts, topics, directory / "accounts")
    checker = accounts.get("coordinator") if "coordinator" in accounts.accounts else None
    if checker is None:
        checker = next(iter(accounts.accounts.values()))
    with RabbitCluster(
        directory / "cluster", definitions=definitions, login=(checker.name, checker.password)
    ) as cluster:
        yield cluster
