"""The job history (protocol.md §6.10): every change of every job, kept, paged and exported."""

from __future__ import annotations

import csv
import io
import json
import subprocess
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from gridfleet.coordinator.history import JobChanges, key_of
from gridfleet.coordinator.history_store import HistoryStore
from gridfleet.coordinator.jobs import Job
from gridfleet.coordinator.records import range_problem
from gridfleet.grid import Cell
from gridfleet.protocol import JobHistoryEntry, JobHistoryQuery
from gridfleet.protocol.messages import JobState
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.cli import gridfleet
from support.effects import header
from support.wait import wait_for

T0 = datetime(2026, 11, 26, 14, 0, tzinfo=UTC)
LIFE: list[tuple[JobState, str | None]] = [
    ("queued", None),
    ("assigned", "unit1"),
    ("to_pickup", "unit1"),
    ("loaded", "unit1"),
    ("to_dropoff", "unit1"),
    ("done", "unit1"),
]


def query(**fields: object) -> JobHistoryQuery:
    """A query from `t`, answered to `t`."""
    return JobHistoryQuery(header=header("t"), request_id="q", reply_to="t", **fields)  # type: ignore[arg-type]


def lived(job_id: str = "j1", start: datetime = T0) -> list[JobHistoryEntry]:
    """The entries of one job through its whole life, a second a change."""
    changes = JobChanges(lambda _: None)
    job = Job(job_id, Cell(1, 1), Cell(8, 8), 1.5, submitted_by="op")
    out = []
    for n, (state, unit) in enumerate(LIFE):
        job.state, job.unit = state, unit
        out += changes.entries([job], start + timedelta(seconds=n))
    return out


# ---- the pure core ---------------------------------------------------------------------------


def test_every_change_of_a_job_is_one_entry_with_its_time_and_age() -> None:
    entries = lived()
    assert [(e.state, e.unit, e.at, e.since_submitted_s) for e in entries] == [
        (state, unit, T0 + timedelta(seconds=n), float(n)) for n, (state, unit) in enumerate(LIFE)
    ]
    assert {(e.pickup, e.dropoff, e.mass_kg, e.submitted_by) for e in entries} == {
        (Cell(1, 1), Cell(8, 8), 1.5, "op")
    }


def test_a_wait_is_recorded_when_its_reason_changes_not_every_step() -> None:
    changes = JobChanges(lambda _: None)
    job = Job("j1", Cell(1, 1), Cell(8, 8), 7.0)
    assert len(changes.entries([job], T0)) == 1
    job.wait, job.wait_reason = "no_unit_free", "every unit that can carry 7.0 kg is busy (u)"
    first = changes.entries([job], T0 + timedelta(seconds=1))
    again = changes.entries([job], T0 + timedelta(seconds=2))  # the same wait: nothing new
    job.wait, job.wait_reason = "fleet_stopped", "the emergency stop is engaged"
    then = changes.entries([job], T0 + timedelta(seconds=3))
    assert [(e.wait, e.reason) for e in first] == [
        ("no_unit_free", "every unit that can carry 7.0 kg is busy (u)")
    ]
    assert again == []
    assert [(e.wait, e.reason, e.since_submitted_s) for e in then] == [
        ("fleet_stopped", "the emergency stop is engaged", 3.0)
    ]


def test_a_job_restored_after_a_restart_goes_on_from_its_stored_entries() -> None:
    stored = {"j1": (("assigned", "unit1", None), T0)}
    changes = JobChanges(stored.get)
    job = Job("j1", Cell(1, 1), Cell(8, 8), 1.5, state="assigned", unit="unit1")
    assert changes.entries([job], T0 + timedelta(seconds=30)) == []  # restored as it was
    job.state = "to_pickup"
    (entry,) = changes.entries([job], T0 + timedelta(seconds=31))
    assert (entry.state, entry.since_submitted_s) == ("to_pickup", 31.0)
    assert key_of(job) == ("to_pickup", "unit1", None)


@pytest.mark.parametrize(
    ("since", "until", "problem"),
    [
        (T0, T0 - timedelta(hours=1), "since 2026-11-26T14:00:00Z is not before until 2026-11-26T13:00:00Z"),
        (T0, T0, "since 2026-11-26T14:00:00Z is not before until 2026-11-26T14:00:00Z"),
        (T0 - timedelta(days=4000), None, "since 2015-12-14T14:00:00Z to until 2026-11-27T14:00:00Z spans more than ten years"),
        (T0 + timedelta(days=2), None, "since 2026-11-28T14:00:00Z is not before until 2026-11-27T14:00:00Z"),
    ],
)  # fmt: skip
def test_a_bad_range_is_refused_in_one_line(
    since: datetime, until: datetime | None, problem: str
) -> None:
    now = T0 + timedelta(days=1)
    assert range_problem(since, until, now) == problem


def test_a_good_range_is_answered_and_a_time_without_a_zone_is_utc() -> None:
    # The records' one rule (records.range_problem), the audit's too: every timestamp is UTC (§1).
    assert range_problem(T0, None, T0 + timedelta(seconds=1)) is None
    assert range_problem(T0.replace(tzinfo=None), None, T0 + timedelta(seconds=1)) is None
    naive = T0.replace(tzinfo=None)
    assert range_problem(T0, naive, T0) == (
        "since 2026-11-26T14:00:00Z is not before until 2026-11-26T14:00:00Z"
    )


# ---- the store ----------------------------------------------------------------------------


@pytest.fixture
def store(tmp_path: Path) -> HistoryStore:
    """A history store in a fresh database."""
    return HistoryStore(tmp_path / "jobs.db")


def pages(store: HistoryStore, limit: int, **fields: object) -> list[list[str]]:
    """Every page of a query, as `job:state` lists."""
    out, cursor = [], None
    while True:
        entries, cursor = store.query(
            query(limit=limit, cursor=cursor, **fields), T0 + timedelta(days=1)
        )
        out.append([f"{e.job}:{e.state}" for e in entries])
        if cursor is None:
            return out


def test_pages_go_on_exactly_where_the_last_ended_also_between_entries_of_one_time(
    store: HistoryStore,
) -> None:
    store.add(lived("a"), T0)
    store.add(lived("b"), T0)  # the same times as a's: ordered by time, then as stored
    got = pages(store, 4, since=T0)
    flat = [x for page in got for x in page]
    assert [len(p) for p in got] == [4, 4, 4]
    assert flat == [f"{j}:{s}" for n in range(6) for j, s in (("a", LIFE[n][0]), ("b", LIFE[n][0]))]


def test_filters_by_unit_job_state_and_time(store: HistoryStore) -> None:
    store.add(lived("a"), T0)
    other = [
        e if e.unit is None else e.model_copy(update={"unit": "unit2"})
        for e in lived("b", T0 + timedelta(hours=1))
    ]
    store.add(other, T0)
    assert pages(store, 100, since=T0, unit="unit2") == [[f"b:{s}" for s, u in LIFE if u]]
    assert pages(store, 100, since=T0, job_id="a") == [[f"a:{s}" for s, _ in LIFE]]
    assert pages(store, 100, since=T0, state="done") == [["a:done", "b:done"]]
    hour = T0 + timedelta(hours=1)
    assert pages(store, 100, since=T0, until=hour) == [[f"a:{s}" for s, _ in LIFE]]
    assert pages(store, 100, since=hour + timedelta(seconds=5)) == [["b:done"]]


def test_the_history_outlives_a_restart_and_old_entries_go_after_the_retention(
    tmp_path: Path,
) -> None:
    path = tmp_path / "jobs.db"
    first = HistoryStore(path, retention_days=30)
    first.add(lived("old", T0 - timedelta(days=40)), T0 - timedelta(days=40))
    first.add(lived("new", T0), T0)
    assert first.last("new") == (("done", "unit1", None), T0)
    first.close()
    again = HistoryStore(path, retention_days=30)  # a restart, today: the old job is past 30 days
    assert pages(again, 100, since=T0 - timedelta(days=60)) == [[f"new:{s}" for s, _ in LIFE]]
    assert again.last("old") is None
    with pytest.raises(ValueError, match="history retention 0 days: give more than 0"):
        HistoryStore(path, retention_days=0)


def test_a_cursor_whose_entry_was_pruned_starts_from_since(store: HistoryStore) -> None:
    store.add(lived("a"), T0)
    entries, cursor = store.query(query(since=T0, limit=1), T0 + timedelta(days=1))
    assert cursor is not None and len(entries) == 1
    store.retention = timedelta(seconds=1)
    store.prune(T0 + timedelta(days=1))
    store.add(lived("b", T0 + timedelta(days=1)), T0 + timedelta(days=1))
    after, _ = store.query(query(since=T0, cursor=cursor), T0 + timedelta(days=2))
    assert [e.job for e in after] == ["b"] * len(LIFE)


# ---- the whole system, from the command line ------------------------------------------------


def gridfleet_job(broker: BrokerThread, root: str, *args: str) -> subprocess.CompletedProcess[str]:
    """Run `gridfleet job ARGS` against the session broker, in a process of its own."""
    return gridfleet("job", *args, "--broker", broker.url, "--root", root, timeout=90)


@pytest.mark.slow  # the whole system, end to end
def test_a_job_done_by_the_fleet_is_in_the_history_as_csv_json_and_table(
    broker: BrokerThread,
    root: str,
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    playfield: Path,
) -> None:
    run_system(playfield)
    since = datetime.now(UTC) - timedelta(seconds=1)
    out = gridfleet_job(broker, root, "submit", "--pickup", "1,8", "--dropoff", "8,8", "--mass", "1.5", "--id", "crate")  # fmt: skip
    assert out.returncode == 0, out.stderr
    wait_for(
        lambda: "done" in gridfleet_job(broker, root, "list").stdout,
        timeout=90,
        interval=0.5,
        what="crate done",
    )
    got = gridfleet_job(
        broker, root, "history", "--since", since.isoformat(), "--job", "crate", "--csv"
    )
    assert got.returncode == 0, got.stderr
    rows = list(csv.DictReader(io.StringIO(got.stdout)))
    states = [r["state"] for r in rows]
    # Each step of its life once, in order (a unit can lose it and get it back on a loaded
    # machine: then the cycle repeats, but it always starts queued and ends done).
    assert states[0] == "queued" and states[-1] == "done", states
    # (`assigned` is there only when the unit did not hear of it in the same step: protocol.md.)
    for state in ("to_pickup", "to_dropoff"):
        assert state in states, states
    times = [datetime.fromisoformat(r["at"]) for r in rows]
    assert times == sorted(times) and since <= times[0] <= times[-1] <= datetime.now(UTC)
    ages = [float(r["since_submitted_s"]) for r in rows]
    assert ages[0] == 0 and ages == sorted(ages)
    assert {
        (r["pickup_x"], r["pickup_y"], r["dropoff_x"], r["dropoff_y"], r["mass_kg"]) for r in rows
    } == {("1", "8", "8", "8", "1.5")}
    done = rows[-1]
    assert done["unit"] and done["unit"] == rows[states.index("to_dropoff")]["unit"]
    as_json = gridfleet_job(
        broker, root, "history", "--since", since.isoformat(), "--job", "crate", "--json"
    )
    assert [e["state"] for e in json.loads(as_json.stdout)] == states
    unit = done["unit"]
    by_unit = gridfleet_job(
        broker, root, "history", "--since", "10m", "--unit", unit, "--state", "done"
    )
    assert by_unit.returncode == 0, by_unit.stderr
    lines = by_unit.stdout.splitlines()
    assert len(lines) == 3 and lines[-1] == "1 change" and "crate" in lines[1] and unit in lines[1]


@pytest.mark.slow
def test_a_bad_range_or_time_is_refused_in_one_line_and_changes_nothing(
    broker: BrokerThread,
    root: str,
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    playfield: Path,
) -> None:
    run_system(playfield)
    backwards = gridfleet_job(broker, root, "history", "--since", "2026-11-27T10:00Z", "--until", "2026-11-26T10:00Z")  # fmt: skip
    assert (backwards.returncode, backwards.stderr) == (
        1,
        "refused: since 2026-11-27T10:00:00Z is not before until 2026-11-26T10:00:00Z\n",
    )
    garbage = gridfleet_job(broker, root, "history", "--since", "yesterday-ish")
    assert garbage.returncode == 2
    assert (
        garbage.stderr.strip()
        .splitlines()[-1]
        .endswith(
            "argument --since: 'yesterday-ish' is not a time: give an ISO 8601 time or date, "
            "local unless it names its zone (2026-11-26T14:02, 2026-11-26, 2026-11-26T14:02Z), "
            "now, or a span back from now (90s, 30m, 24h, 7d)"
        )
    )
