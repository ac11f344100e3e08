"""The tests' `gridfleet` runner (support/cli.py): what a bare `python -m gridfleet` does."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from gridfleet.system.broker_thread import BrokerThread

from support.cli import gridfleet
from support.paths import REPO


def bare(*args: str, cwd: Path, env: dict[str, str] | None = None) -> tuple[int, str, str]:
    done = subprocess.run(
        [sys.executable, "-m", "gridfleet", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=cwd,
        env=env,
        stdin=subprocess.DEVNULL,
    )
    return done.returncode, done.stdout, done.stderr


@pytest.mark.parametrize(
    ("args", "folder"),
    [
        (["--version"], "repo"),
        (["fly"], "repo"),
        (["coordinator", "--map", "maps/playfield.map", "--window", "0"], "repo"),
        (["coordinator", "--map", "maps/playfield.map", "--window", "0"], "elsewhere"),  # no map
        (["webots-world", "maps/playfield.toml"], "repo"),  # a world on stdout
    ],
    ids=["version", "unknown-command", "bad-window", "map-not-there", "output"],
)
def test_a_command_says_and_ends_as_in_a_bare_interpreter(
    args: list[str], folder: str, tmp_path: Path
) -> None:
    cwd = REPO if folder == "repo" else tmp_path
    done = gridfleet(*args, cwd=cwd)
    assert (done.returncode, done.stdout, done.stderr) == bare(*args, cwd=cwd)
    assert done.args == ["gridfleet", *args]


def test_the_environment_is_the_one_given() -> None:
    # A supervisor named in the environment that is not the parent: the command ends itself
    # (gridfleet/lifeline.py), by SIGTERM.
    env = {**os.environ, "GRIDFLEET_SUPERVISOR_PID": "1"}
    done = gridfleet("--version", env=env)
    assert (done.returncode, done.stdout, done.stderr) == bare("--version", cwd=REPO, env=env)
    assert done.returncode == -15
    assert gridfleet("--version").returncode == 0


def test_a_command_past_its_timeout_is_ended(broker: BrokerThread, root: str) -> None:
    # `gridfleet status` redraws until Ctrl-C.
    began = time.monotonic()
    with pytest.raises(subprocess.TimeoutExpired):
        gridfleet("status", "--broker", broker.url, "--root", root, timeout=1)
    assert time.monotonic() - began < 30
    done = gridfleet("--version")  # the runner is still there for the next one
    assert done.returncode == 0 and done.stdout.startswith("gridfleet ")


def test_commands_asked_for_at_once_each_get_their_own_answer(tmp_path: Path) -> None:
    answers: dict[int, subprocess.CompletedProcess[str]] = {}

    def ask(n: int) -> None:
        answers[n] = gridfleet(
            "coordinator", "--map", "maps/playfield.map", "--window", str(40 + n), cwd=REPO
        )

    threads = [threading.Thread(target=ask, args=(n,)) for n in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    assert sorted(answers) == [0, 1, 2, 3]
    for n, done in answers.items():
        assert done.returncode == 2
        assert f"--window {40 + n}: give 1 to 32 squares" in done.stderr
