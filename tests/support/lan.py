"""The test LAN fixture: network namespaces on one bridge (gridfleet.bench.lan), per test."""

from __future__ import annotations

import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from gridfleet.bench.lan import Host, Lan, can_make_lans, lan

from support.paths import REPO

__all__ = ["LAN_SCENARIO", "Lan", "Processes", "test_lan"]

# The LAN tests' fleet: two units on the playfield, one of them too weak for heavy items.
LAN_SCENARIO = f"""
name = "lan"
map = "{REPO / "maps" / "playfield.map"}"
[[units]]
id = "unit1"
start = [0, 0]
capacity = 5.0
[[units]]
id = "unit2"
start = [9, 0]
capacity = 1.0
"""


@pytest.fixture
def test_lan() -> Iterator[Lan]:
    """A LAN for the test (skipped in one line on a machine that cannot make one)."""
    why_not = can_make_lans()
    if why_not is not None:
        pytest.skip(f"no test LAN: {why_not}")
    with lan() as made:
        yield made


class Processes:
    """Components started for a test, each logging to a file, all stopped at its end."""

    def __init__(self, logs: Path, lan: Lan) -> None:
        self.logs = logs
        self.lan = lan
        self.running: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, argv: list[str], host: Host | None = None) -> None:
        """Run `argv` on `host` (else on the broker's), its output into `<name>.log`."""
        command = (host or self.lan.here).command(argv)
        with (self.logs / f"{name}.log").open("ab") as log:
            self.running[name] = subprocess.Popen(
                command, stdout=log, stderr=subprocess.STDOUT, cwd=REPO
            )

    def stop(self) -> None:
        """SIGTERM to each, SIGKILL to any still running after 10 s."""
        for proc in self.running.values():
            proc.send_signal(signal.SIGTERM)
        for proc in self.running.values():
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)

    def tails(self) -> str:
        """The last lines each component logged (for a failure's message)."""
        return "\n".join(
            f"--- {path.name}\n{path.read_text(errors='replace')[-3000:]}"
            for path in sorted(self.logs.glob("*.log"))
        )
