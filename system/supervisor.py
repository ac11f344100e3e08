"""Runs components as child processes: prefixed logs, restart on death, ordered clean shutdown.

A component that keeps dying is restarted for ever, with a growing (capped) delay, and reported
each time; it never takes the healthy ones down with it.
"""

from __future__ import annotations

import asyncio
import logging
import os
import re
import signal
import sys
import time
from asyncio import FIRST_COMPLETED
from dataclasses import dataclass, field
from typing import TextIO

from gridfleet.errors import ComponentError
from gridfleet.lifeline import PARENT_ENV
from gridfleet.tasks import stop_on_signals

log = logging.getLogger("gridfleet.up")


@dataclass
class ChildSpec:
    """One component: its command line and, optionally, a line that says it is ready."""

    name: str
    argv: list[str]
    ready: re.Pattern[str] | None = None
    restart: bool = True
    env: dict[str, str] = field(default_factory=dict)


@dataclass
class Child:
    """A running component and what the supervisor knows of it."""

    spec: ChildSpec
    process: asyncio.subprocess.Process | None = None
    ready_match: re.Match[str] | None = None
    ready_event: asyncio.Event = field(default_factory=asyncio.Event)
    restarts: int = 0  # deaths so far, over the whole run
    streak: int = 0  # deaths in a row, each after a short run: the restart delay grows with it
    started_at: float = 0.0
    last_line: str = ""
    gone: asyncio.Event = field(default_factory=asyncio.Event)  # exited and not restarted


class Supervisor:
    """Starts children in order, prefixes their output, restarts the dead, stops all in reverse.

    A dead child is restarted after `restart_delay`, doubled at each death in a row up to
    `max_restart_delay`; a child that ran `stable_after` seconds before dying starts over at
    `restart_delay`. Giving up is never an option: the others keep running meanwhile.
    """

    def __init__(
        self,
        out: TextIO | None = None,
        restart_delay: float = 1.0,
        max_restart_delay: float = 30.0,
        stable_after: float = 60.0,
        stop_timeout: float = 10.0,
    ) -> None:
        self.out = out or sys.stdout
        self.restart_delay = restart_delay
        self.max_restart_delay = max_restart_delay
        self.stable_after = stable_after
        self.stop_timeout = stop_timeout
        self.children: list[Child] = []
        self._stopping = False
        self._watchers: list[asyncio.Task[None]] = []
        self.output_lost = asyncio.Event()  # our output's reader is gone: time to stop

    def say(self, name: str, line: str) -> None:
        """Print one line with the component's name in front."""
        try:
            self.out.write(f"[{name:<11}] {line}\n")
            self.out.flush()
        except (BrokenPipeError, ValueError):
            # Nobody reads us any more (`gridfleet up | head`, a closed terminal): carry on
            # without output, and let whoever waits on `output_lost` stop everything.
            if self.out is sys.stdout:
                # What is still buffered would fail again at exit: fd 1 goes nowhere from now on.
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, sys.stdout.fileno())
                os.close(null)
            else:
                self.out = open(os.devnull, "w")  # noqa: SIM115 - for the rest of this process
            self.output_lost.set()

    async def start(self, spec: ChildSpec, ready_timeout: float = 60.0) -> Child:
        """Start a child; when it has a ready pattern, wait until its output matches."""
        child = Child(spec)
        self.children.append(child)
        await self._spawn(child)
        self._watchers.append(asyncio.create_task(self._watch(child)))
        if spec.ready is not None:
            waits = [asyncio.ensure_future(e.wait()) for e in (child.ready_event, child.gone)]
            try:
                await asyncio.wait(waits, timeout=ready_timeout, return_when=FIRST_COMPLETED)
            finally:
                for w in waits:
                    w.cancel()
            if child.gone.is_set():
                # Dying before it ever got ready is a setting (a busy port), not bad luck: it
                # would only die again, so say why now instead of restarting it.
                raise ComponentError(f"{spec.name} did not start: {child.last_line or 'no output'}")
            if not child.ready_event.is_set():
                raise ComponentError(f"{spec.name} did not become ready in {ready_timeout:.0f} s")
        return child

    async def _spawn(self, child: Child) -> None:
        env = {
            **os.environ,
            "PYTHONUNBUFFERED": "1",
            PARENT_ENV: str(os.getpid()),
            **child.spec.env,
        }
        # A session of its own: a terminal's Ctrl-C reaches only the supervisor, which then stops
        # the children in a safe order (units first, broker last).
        child.process = await asyncio.create_subprocess_exec(
            *child.spec.argv,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.STDOUT,
            stdin=asyncio.subprocess.DEVNULL,
            env=env,
            start_new_session=True,
        )
        child.started_at = time.monotonic()
        child.last_line = ""  # last words are this run's
        self.say(child.spec.name, f"started (pid {child.process.pid})")

    async def _pump(self, child: Child) -> None:
        proc = child.process
        assert proc is not None and proc.stdout is not None
        while True:
            raw = await proc.stdout.readline()
            if not raw:
                return
            line = raw.decode("utf-8", "replace").rstrip()
            self.say(child.spec.name, line)
            if line.strip():
                child.last_line = line.strip()
            if child.spec.ready is not None and not child.ready_event.is_set():
                match = child.spec.ready.search(line)
                if match:
                    child.ready_match = match
                    child.ready_event.set()

    async def _watch(self, child: Child) -> None:
        while True:
            await self._pump(child)
            assert child.process is not None
            code = await child.process.wait()
            if self._stopping:
                return
            # ready_match outlives restarts: it says whether the child was ever ready.
            never_ready = child.spec.ready is not None and child.ready_match is None
            if not child.spec.restart or never_ready:
                self.say(child.spec.name, f"exited with code {code}")
                child.gone.set()
                return
            child.restarts += 1
            ran = time.monotonic() - child.started_at
            child.streak = 1 if ran >= self.stable_after else child.streak + 1
            delay = min(self.restart_delay * 2 ** (child.streak - 1), self.max_restart_delay)
            times = "once" if child.restarts == 1 else f"{child.restarts} times"
            self.say(
                child.spec.name,
                f"DIED: exited with code {code} after {ran:.1f} s, {times} so far; "
                f"last words: {child.last_line or '(no output)'}; restarting in {delay:g} s",
            )
            await asyncio.sleep(delay)
            if self._stopping:
                return
            child.ready_event.clear()
            await self._spawn(child)

    async def stop(self) -> None:
        """Stop every child, last started first: SIGTERM, then SIGKILL after the timeout."""
        self._stopping = True
        for child in reversed(self.children):
            proc = child.process
            if proc is None or proc.returncode is not None:
                continue
            proc.send_signal(signal.SIGTERM)
            try:
                await asyncio.wait_for(proc.wait(), self.stop_timeout)
                self.say(child.spec.name, f"stopped (code {proc.returncode})")
            except TimeoutError:
                proc.kill()
                await proc.wait()
                self.say(child.spec.name, "did not stop in time; killed")
        for task in self._watchers:
            task.cancel()
        await asyncio.gather(*self._watchers, return_exceptions=True)
        for child in self.children:  # restarted while the others were being stopped
            proc = child.process
            if proc is not None and proc.returncode is None:
                proc.kill()
                await proc.wait()
                self.say(child.spec.name, "killed (it was restarting)")

    def pids(self) -> list[int]:
        """Process ids of the children now running."""
        return [
            c.process.pid
            for c in self.children
            if c.process is not None and c.process.returncode is None
        ]


async def run_until_signal(supervisor: Supervisor, stop: asyncio.Event | None = None) -> int:
    """Wait for SIGINT, SIGTERM or SIGHUP (`stop`, when the caller armed them already), or for
    our output to be closed, then stop everything (a child that keeps dying is no reason)."""
    stop = stop or stop_on_signals()
    waits = [asyncio.ensure_future(e.wait()) for e in (stop, supervisor.output_lost)]
    try:
        await asyncio.wait(waits, return_when=FIRST_COMPLETED)
    finally:
        for w in waits:
            w.cancel()
    await supervisor.stop()
    return 0
