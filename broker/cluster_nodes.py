"""What the broker clusters (`aedes_cluster`, `rabbitmq_cluster`) share: waiting with a deadline
for a node to come up, whether a port listens, ending a process, and their one error."""

from __future__ import annotations

import signal
import socket
import subprocess
import time
from collections.abc import Callable

from gridfleet.errors import GridfleetError


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
