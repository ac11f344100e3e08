"""A free loopback port, for a server that must be started (or come back) on a port known first."""

from __future__ import annotations

import itertools
import os
import random
import re
import socket
from collections.abc import Iterator

# Under pytest-xdist each worker takes ports from a band of its own, below the kernel's ephemeral
# range (32768 and up, where port 0 binds and outgoing connections land), walking it with a
# counter: no two workers, and no two calls in one, are handed the same port. The OS's pick of
# port 0 may hand one worker the port another was given a moment earlier and has not bound yet
# (a CI run lost a dashboard's port that way). A run beside the workers (make test's soak, which
# restarts its broker on the port it was given) names a band of its own in PORT_BAND_ENV; a second
# run of workers beside the first (make test's lane on the broker clusters) names the first band
# of its own followed by "+" ("6+": worker gw1 takes band 7).
_BANDS_START, _BAND_SIZE, _BANDS = 20000, 1000, 12
PORT_BAND_ENV = "GRIDFLEET_PORT_BAND"
_band: Iterator[int] | None = None


def _band_number() -> int | None:
    """This process's band: the one PORT_BAND_ENV names, else its xdist worker's, else none."""
    named = os.environ.get(PORT_BAND_ENV, "")
    if named.isdigit():
        return int(named)
    worker = re.fullmatch(r"gw(\d+)", os.environ.get("PYTEST_XDIST_WORKER", ""))
    first = int(named[:-1]) if re.fullmatch(r"\d+\+", named) else 0
    return None if worker is None else first + int(worker[1])


def free_port() -> int:
    """A loopback port nobody listens on now (free until somebody binds it)."""
    global _band
    band = _band_number()
    if band is None:
        return _bind_test(0)
    if _band is None:
        first = _BANDS_START + band % _BANDS * _BAND_SIZE
        # A random start: a subprocess of the worker (same band) walks elsewhere in it.
        start = random.randrange(_BAND_SIZE)
        _band = itertools.cycle([first + (start + i) % _BAND_SIZE for i in range(_BAND_SIZE)])
    for port in itertools.islice(_band, _BAND_SIZE):
        if _bind_test(port):
            return port
    return _bind_test(0)  # the whole band in use: the OS's pick, as outside the tests


def _bind_test(port: int) -> int:
    """`port` (or the OS's pick for 0) if it can be bound now, else 0."""
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return 0
        return int(s.getsockname()[1])
