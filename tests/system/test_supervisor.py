"""The supervisor behind `gridfleet up`: prefixed logs, restarts, and nothing left running."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
import time

import pytest

from gridfleet.errors import ComponentError
from gridfleet.system.supervisor import ChildSpec, Supervisor

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


class TimedOut(io.StringIO):
    """Output that also notes when each line came, to check the delays between restarts."""

    def __init__(self) -> None:
        super().__init__()
        self.lines: list[tuple[float, str]] = []

    def write(self, text: str) -> int:
        self.lines.extend((time.monotonic(), line) for line in text.splitlines())
        return super().write(text)

    def times(self, fragment: str) -> list[float]:
        return [t for t, line in self.lines if fragment in line]


CRASHER = [sys.executable, "-c", "print('boom: bad state', flush=True)\nraise SystemExit(3)"]


async def test_a_child_that_keeps_dying_is_restarted_with_growing_delays_and_reported() -> None:
    out = TimedOut()
    sup = Supervisor(out=out, restart_delay=0.02, max_restart_delay=0.08, stop_timeout=5)
    healthy = await sup.start(ChildSpec("healthy", SLEEPER, ready=re.compile("ready")))
    assert healthy.process is not None
    pid = healthy.process.pid
    crashy = await sup.start(ChildSpec("crashy", CRASHER))
    try:
        await async_wait_for(
            lambda: crashy.restarts >= 6, timeout=30, what="the crashing child to die 6 times"
        )
        assert healthy.process.pid == pid and healthy.process.returncode is None and alive(pid)
        assert sup.pids()[0] == pid and not healthy.gone.is_set() and not crashy.gone.is_set()
    finally:
        await sup.stop()
    text = out.getvalue()
    assert "giving up" not in text and "[healthy    ] started" in text
    assert text.count("[healthy    ] started") == 1  # never restarted, never stopped meanwhile
    deaths = re.findall(
        r"^\[crashy     \] DIED: exited with code 3 after [\d.]+ s, (.+?) so far; "
        r"last words: boom: bad state; restarting in ([\d.]+) s$",
        text,
        re.M,
    )
    assert len(deaths) >= 6, text
    assert [n for n, _ in deaths[:4]] == ["once", "2 times", "3 times", "4 times"]
    # Doubled at each death in a row, up to the cap.
    assert [float(d) for _, d in deaths[:6]] == [0.02, 0.04, 0.08, 0.08, 0.08, 0.08]
    # And really waited: each start comes at least the announced delay after the death before.
    died, started = out.times("[crashy     ] DIED"), out.times("[crashy     ] started")
    for i, (_, delay) in enumerate(deaths[:5]):
        assert started[i + 1] - died[i] >= float(delay) * 0.9
    assert "[healthy    ] stopped" in text


async def test_a_child_that_ran_long_enough_starts_over_at_the_shortest_delay() -> None:
    out = io.StringIO()
    sup = Supervisor(out=out, restart_delay=0.02, max_restart_delay=1, stable_after=0)
    crashy = await sup.start(ChildSpec("crashy", CRASHER))
    try:
        await async_wait_for(lambda: crashy.restarts >= 3, timeout=20, what="3 deaths")
    finally:
        await sup.stop()
    delays = re.findall(r"restarting in ([\d.]+) s", out.getvalue())
    assert len(delays) >= 3 and set(delays) == {"0.02"}


async def test_a_one_shot_child_is_not_restarted() -> None:
    out = io.StringIO()
    sup = Supervisor(out=out, restart_delay=0.01)
    once = await sup.start(
        ChildSpec("once", [sys.executable, "-c", "print('done')"], restart=False)
    )
    await async_wait_for(once.gone.is_set, timeout=20, what="the one-shot child to exit")
    await sup.stop()
    text = out.getvalue()
    assert "[once       ] exited with code 0" in text and text.count("started") == 1
    assert "restarting" not in text and "DIED" not in text


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


def test_a_child_arms_its_parent_death_signal_once_and_hides_it_from_its_own_children() -> None:
    # In a process of its own: the armed signal stays with the process that asked for it.
    code = (
        "import os; from gridfleet.lifeline import PARENT_ENV, die_with_parent\n"
        "env = {PARENT_ENV: str(os.getppid())}\n"
        "print(die_with_parent(env), PARENT_ENV in env, die_with_parent({}))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["True", "False", "False"]
