"""A real aedes cluster for tests: the shipped one (gridfleet.broker.aedes_cluster: a Redis and
three aedes instances sharing it, on free loopback ports), in the test's own folder; what it lacks
to start (redis-server, the launcher's node_modules) fails the test with the line that says so."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from gridfleet.accounts import Accounts
from gridfleet.broker import aedes_cluster
from gridfleet.broker.aedes import write_accounts_json
from gridfleet.broker.cluster_nodes import ClusterError
from gridfleet.protocol import Topics

HEARTBEAT_MS = aedes_cluster.HEARTBEAT_MS
NODE = aedes_cluster.NODE
REDIS = aedes_cluster.REDIS


class AedesCluster(aedes_cluster.AedesCluster):
    """The shipped cluster as the suite's broker (GRIDFLEET_TEST_BROKER=aedes); a node that
    cannot start fails the test with why."""

    def start(self, timeout: float = 30.0) -> None:
        """Start Redis, then every instance (the test fails if one cannot)."""
        try:
            super().start(timeout)
        except ClusterError as exc:
            pytest.fail(str(exc))

    def start_node(self, i: int, timeout: float = 20.0) -> None:
        """Start instance `i` (again) on its own ports (the test fails if it cannot)."""
        try:
            super().start_node(i, timeout)
        except ClusterError as exc:
            pytest.fail(str(exc))

    def __enter__(self) -> AedesCluster:
        self.start()
        return self


@contextmanager
def aedes_with_accounts(
    accounts: Accounts, topics: Topics, directory: Path, nodes: int = 3
) -> Iterator[AedesCluster]:
    """An aedes cluster enforcing the file 'gridfleet accounts aedes' writes; its URL list is
    `.url` (no login)."""
    written = write_accounts_json(accounts, topics, directory)
    with AedesCluster(directory, nodes, accounts_file=written) as cluster:
        yield cluster


def own_processes_gone(pids: list[int]) -> bool:
    """Whether none of `pids` is still a process."""
    for pid in pids:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            continue
        return False
    return True
