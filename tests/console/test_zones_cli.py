"""`gridfleet job close-zone`, `open-zone` and `zones`, and `gridfleet status`, against a real
broker and coordinator: a zone closed and listed, refusals in the coordinator's words with exit
1, bad arguments refused before anything is sent, and the status listing the zones closed."""

from __future__ import annotations

import re
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, coordinator_thread

from support.cli import gridfleet

Run = Callable[..., subprocess.CompletedProcess[str]]


@pytest.fixture
def cli(broker: BrokerThread, root: str) -> Run:
    """Run `gridfleet ARGS --broker URL --root R`."""

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return gridfleet(*args, "--broker", broker.url, "--root", root)

    return run


@pytest.fixture
def coordinator(
    broker: BrokerThread, root: str, tmp_path: Path, playfield: Path
) -> Iterator[ServiceThread[object]]:
    """The real coordinator of the playfield, no units."""
    scenario = load_scenario(playfield)
    with coordinator_thread(
        scenario, broker.url, root=root, step_s=0.05, db_path=tmp_path / "db"
    ) as running:
        yield running  # type: ignore[misc]


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
@pytest.mark.usefixtures("coordinator")
def test_a_zone_is_closed_listed_refused_again_otherwise_and_opened(cli: Run) -> None:
    none = cli("job", "zones")
    assert (none.returncode, none.stdout, none.stderr) == (0, "no zone is closed\n", "")
    closed = cli("job", "close-zone", "aisle-4", "5,4", "3,1", "--reason", "wet floor")
    assert (closed.returncode, closed.stdout, closed.stderr) == (
        0,
        "accepted: zone aisle-4 closed: [3, 1] to [5, 4], 12 squares\n",
        "",
    )
    listed = cli("job", "zones")
    assert listed.returncode == 0, listed.stderr
    head, row, count = listed.stdout.splitlines()
    assert head.split() == [
        "zone", "from", "to", "squares", "closed", "by", "closed", "at", "(UTC)", "why",
    ]  # fmt: skip
    # Closed by the command's own client id, at a UTC time to the second.
    pattern = r"aisle-4 +\[3, 1\] +\[5, 4\] +12  cli-[0-9a-f]{6} +\d{4}-\d\d-\d\d \d\d:\d\d:\d\d +wet floor"
    assert re.fullmatch(pattern, row), row
    assert count == "1 zone closed"
    again = cli("job", "close-zone", "aisle-4", "3,1", "5,4", "--reason", "spill")
    assert (again.returncode, again.stdout) == (
        1,
        "refused: zone aisle-4 is already closed (wet floor): open it first\n",
    )
    status = cli("status", "--once")
    assert status.returncode == 0, status.stderr
    lines = status.stdout.splitlines()
    at = lines.index("zones closed: 1")
    assert lines[at + 1].split() == ["zone", "squares", "closed", "by", "why"]
    assert lines[at + 2].split()[:4] == ["aisle-4", "3,1", "to", "5,4"]
    assert lines[at + 2].endswith("wet floor")
    opened = cli("job", "open-zone", "aisle-4")
    assert (opened.returncode, opened.stdout) == (
        0,
        "accepted: zone aisle-4 opened ([3, 1] to [5, 4], closed: wet floor)\n",
    )
    unknown = cli("job", "open-zone", "aisle-4")
    assert (unknown.returncode, unknown.stdout) == (
        1,
        "refused: zone aisle-4 is not closed (closed: none is)\n",
    )
    assert "zones closed" not in cli("status", "--once").stdout


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["close-zone", "aisle-4", "3,1", "5,4"], "the following arguments are required: --reason"),
        (["close-zone", "aisle-4", "3,1", "5,4", "--reason", " "], "give a reason"),
        (["close-zone", "aisle 4", "3,1", "5,4", "--reason", "x"], "zone name"),
        (["close-zone", "aisle-4", "3;1", "5,4", "--reason", "x"], "X1,Y1"),
        (["close-zone", "aisle-4", "3,1", "5,4", "--reason", "x" * 501], "at most 500"),
        (["open-zone"], "the following arguments are required: name"),
    ],
)
def test_bad_arguments_are_refused_before_anything_is_sent(
    cli: Run, args: list[str], says: str
) -> None:
    out = cli("job", *args)
    assert out.returncode == 2 and says in out.stderr, out.stderr
