"""`gridfleet job places` and `gridfleet job submit --pickup NAME --dropoff NAME` against a real
broker and coordinator: the places listed from `fleet/map`, a job by names queued at their
squares (and done by the real units), each bad name refused in the coordinator's words."""

from __future__ import annotations

import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, coordinator_thread

from support.cli import gridfleet
from support.wait import wait_for

Job = Callable[..., subprocess.CompletedProcess[str]]
PLAYFIELD_PLACES = """\
place                    square       kinds
A1                       [1, 1]       pickup
A2                       [8, 1]       pickup
A3                       [5, 0]       pickup
A4                       [0, 5]       pickup
P1                       [8, 8]       dropoff
P2                       [1, 8]       dropoff
P3                       [5, 9]       dropoff
P4                       [9, 4]       dropoff
8 places
"""


@pytest.fixture
def job(broker: BrokerThread, root: str) -> Job:
    """Run `gridfleet job ARGS --broker URL --root R`."""

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return gridfleet("job", *args, "--broker", broker.url, "--root", root)

    return run


@pytest.fixture
def coordinator(broker: BrokerThread, root: str, tmp_path: Path, playfield: Path) -> Iterator[None]:
    """The real coordinator of the playfield (its places), no units."""
    scenario = load_scenario(playfield)
    with coordinator_thread(scenario, broker.url, root=root, step_s=0.05, db_path=tmp_path / "db"):
        yield


def listed(job: Job, name: str) -> str:
    """The `job list` line of job `name` ('' while it is not listed)."""
    lines = job("list").stdout.splitlines()
    return next((line for line in lines if line.startswith(f"{name} ")), "")


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
@pytest.mark.usefixtures("coordinator")
def test_the_places_are_listed_from_the_map(job: Job) -> None:
    out = job("places")
    assert (out.returncode, out.stdout, out.stderr) == (0, PLAYFIELD_PLACES, "")
    drops = job("places", "--kind", "dropoff")
    assert drops.returncode == 0
    assert [line.split()[0] for line in drops.stdout.splitlines()] == [
        "place", "P1", "P2", "P3", "P4", "4",
    ]  # fmt: skip
    none = job("places", "--kind", "charger")
    assert (none.returncode, none.stdout) == (
        0,
        "the map 'playfield' has no places of kind charger (a scenario names them: [[places]])\n",
    )


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
@pytest.mark.usefixtures("coordinator")
def test_a_job_by_place_names_is_queued_at_their_squares_and_listed_by_them(job: Job) -> None:
    out = job("submit", "--pickup", "A3", "--dropoff", "P2", "--mass", "1.5", "--id", "tote")
    assert (out.returncode, out.stdout, out.stderr) == (0, "accepted: job tote\n", "")
    line = wait_for(lambda: listed(job, "tote"), timeout=20, interval=0.3, what="tote listed")
    assert "A3 [5, 0] -> P2 [1, 8]" in line, line
    mixed = job("submit", "--pickup", "1,1", "--dropoff", "P2", "--mass", "1", "--id", "crate")
    assert mixed.returncode == 0, mixed.stdout + mixed.stderr
    line = wait_for(lambda: listed(job, "crate"), timeout=20, interval=0.3, what="crate listed")
    assert "[1, 1] -> P2 [1, 8]" in line and "A1" not in line, "X,Y stays a square"


@pytest.mark.usefixtures("coordinator")
@pytest.mark.parametrize(
    ("pickup", "dropoff", "words"),
    [
        (
            "Q9",
            "P2",
            "refused: unknown place 'Q9': the places are A1, A2, A3, A4, P1, P2, P3, P4\n",
        ),
        ("P2", "P1", "refused: place P2 is not a pickup (it is: dropoff)\n"),
        ("A3", "A4", "refused: place A4 is not a dropoff (it is: pickup)\n"),
    ],
    ids=["unknown", "not a pickup", "not a dropoff"],
)
@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
def test_a_bad_place_is_refused_in_the_coordinators_words_and_queues_nothing(
    job: Job, pickup: str, dropoff: str, words: str
) -> None:
    out = job("submit", "--pickup", pickup, "--dropoff", dropoff, "--mass", "1", "--id", "bad")
    assert (out.returncode, out.stdout) == (1, words)
    assert listed(job, "bad") == ""


def test_a_name_that_is_no_id_is_refused_before_anything_is_sent(job: Job) -> None:
    out = job("submit", "--pickup", "A 3", "--dropoff", "P2", "--mass", "1")
    assert out.returncode == 2 and "Traceback" not in out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert last == (
        "gridfleet job submit: error: argument --pickup: 'A 3' is not a square X,Y nor a "
        "place's name (an id: 1-64 letters, digits, '_', '.', '-', starting with a letter or digit)"
    )


def test_places_without_a_coordinator_says_so(job: Job) -> None:
    out = job("places", "--timeout", "1")
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.startswith("gridfleet job: error: no map on ")
    assert out.stderr.rstrip().endswith("within 1 s: is the coordinator running?")


@pytest.mark.slow  # the whole system, end to end: make test, not test-fast
def test_a_job_by_place_names_is_done_by_the_real_units(
    job: Job,
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    playfield: Path,
) -> None:
    run_system(playfield)
    out = job("submit", "--pickup", "A1", "--dropoff", "P4", "--mass", "1", "--id", "tote")
    assert (out.returncode, out.stdout) == (0, "accepted: job tote\n"), out.stderr

    def done() -> str:
        line = listed(job, "tote")
        return line if " done " in line else ""

    line = wait_for(done, timeout=90, interval=0.5, what="tote done")
    assert "A1 [1, 1] -> P4 [9, 4]" in line
