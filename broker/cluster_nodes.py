"""What the broker clusters (`aedes_cluster`, `rabbitmq_cluster`) share: waiting with a deadline
for a node to come up, whether a port listens, ending a process, and their one error."""

from __future__ import annotations

import itertools
import signal
import socket
import subprocess
import time
from collections.abc import Callable

from gridfleet.errors import GridfleetError
from gridfleet.ports import free_port


class ClusterError(GridfleetError):
    """A cluster's node did not start, or what runs it is not installed."""


def wait_until(
    predicate: Callable[[], object],
    timeout: float,
    what: str,
    interval: float = 0.01,
    context: Callable[[], object] | None = None,
) -> None:
    """Poll `predicate` until it is truthy; ClusterError naming `what` (and what `context` says
    then) after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            said = "" if context is None else f": {context()}"
            raise ClusterError(f"timed out after {timeout} s waiting for {what}{said}")
        time.sleep(interval)  # polling a process or a port, with a deadline


def listening(port: int) -> bool:
    """Whether something accepts connections on loopback `port`."""
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def end(proc: subprocess.Popen[bytes], timeout: float = 5.0) -> None:
    """Terminate `proc` (its SIGSTOP lifted first), killing it when it does not end in time."""
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGCONT)
    proc.terminate()
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout)


class NodeList:
    """Each node's TCP and websocket port, and the URL lists clients are given: every node's,
    beginning at the next node on each read, so the clients made one after another start on
    different nodes (as at a site) and each can move to the others."""

    WS_PATH = ""  # the websocket listener's path ("/ws": RabbitMQ's web MQTT plugin)

    def __init__(self, nodes: int) -> None:
        self.ports = [free_port() for _ in range(nodes)]
        self.ws_ports = [free_port() for _ in range(nodes)]
        self._turn = itertools.count()
        self._ws_turn = itertools.count()

    @property
    def node_urls(self) -> list[str]:
        """Each node's TCP URL, in order."""
        return [f"mqtt://127.0.0.1:{p}" for p in self.ports]

    @property
    def node_ws_urls(self) -> list[str]:
        """Each node's websocket URL, in order."""
        return [f"ws://127.0.0.1:{p}{self.WS_PATH}" for p in self.ws_ports]

    @staticmethod
    def _rotated(urls: list[str], start: int) -> str:
        """`urls` from index `start` on, wrapping round, comma-separated."""
        start %= len(urls)
        return ",".join(urls[start:] + urls[:start])

    @property
    def url(self) -> str:
        """Every node's TCP URL, beginning at the next node on each read."""
        return self._rotated(self.node_urls, next(self._turn))

    @property
    def ws_url(self) -> str:
        """Every node's websocket URL (the page's list), beginning at the next on each read."""
        return self._rotated(self.node_ws_urls, next(self._ws_turn))

    @property
    def port(self) -> int:
        """The first node's TCP port."""
        return self.ports[0]

    @property
    def ws_port(self) -> int:
        """The first node's websocket port."""
        return self.ws_ports[0]
