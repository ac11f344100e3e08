"""The supervisor behind `gridfleet up`: prefixed logs, restarts, and nothing left running."""

from __future__ import annotations

import io
import os
import re
import sys

import pytest

from gridfleet.errors import ComponentError
from system.supervisor import ChildSpec, Supervisor

from support.wait import async_wait_for

SLEEPER = [sys.executable, "-c", "import time\nprint('ready', flush=True)\ntime.sleep(600)"]


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


async def test_children_are_prefixed_ready_and_all_stopped() -> None:
    out = io.StringIO()
    sup = Supervisor(out=out, stop_timeout=5)
    await sup.start(ChildSpec("first", SLEEPER, ready=re.compile("ready")))
    await sup.start(ChildSpec("second", SLEEPER, ready=re.compile("ready")))
    pids = sup.pids()
    assert len(pids) == 2 and all(alive(p) for p in pids)
    await sup.stop()
    assert not any(alive(p) for p in pids)
    text = out.getvalue()
    assert "[first      ] ready" in text and "[second     ] ready" in text
    # Last started stops first.
    assert text.index("[second     ] stopped") < text.index("[first      ] stopped")


async def test_a_dead_child_is_reported_and_restarted() -> None:
    out = io.StringIO()
    sup = Supervisor(out=out, restart_delay=0.01, max_restarts=2)
    await sup.start(ChildSpec("crashy", [sys.executable, "-c", "raise SystemExit(3)"]))
    await async_wait_for(sup.failed.is_set, timeout=20, what="the supervisor to give up")
    await sup.stop()
    text = out.getvalue()
    assert text.count("exited with code 3") == 3
    assert "restart 2 of 2" in text and "giving up" in text


async def test_a_child_that_ignores_sigterm_is_killed() -> None:
    stubborn = [
        sys.executable,
        "-c",
        "import signal, time\nsignal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "print('ready', flush=True)\ntime.sleep(600)",
    ]
    out = io.StringIO()
    sup = Supervisor(out=out, stop_timeout=0.5)
    await sup.start(ChildSpec("stubborn", stubborn, ready=re.compile("ready")))
    pid = sup.pids()[0]
    await sup.stop()
    assert not alive(pid)
    assert "killed" in out.getvalue()


async def test_a_child_that_never_gets_ready_is_an_error() -> None:
    sup = Supervisor(out=io.StringIO())
    with pytest.raises(ComponentError, match="did not become ready"):
        await sup.start(ChildSpec("mute", SLEEPER, ready=re.compile("never")), ready_timeout=0.5)
    await sup.stop()


async def test_a_child_that_dies_before_it_is_ready_fails_at_once_with_its_last_words() -> None:
    out = io.StringIO()
    sup = Supervisor(out=out, restart_delay=0.01)
    doomed = [
        sys.executable,
        "-c",
        "import sys; print('port 1883 is in use', flush=True); sys.exit(2)",
    ]
    with pytest.raises(ComponentError, match="broker did not start: port 1883 is in use"):
        await sup.start(
            ChildSpec("broker", doomed, ready=re.compile("listening")), ready_timeout=30
        )
    await sup.stop()
    assert "restarting" not in out.getvalue()  # it would only die again
