"""`gridfleet bench history`: the job history's store with a year of jobs: how fast it answers.

A store is filled with `--days` days of `--jobs-per-day` jobs, each with a typical life (queued,
a wait, under way, picked, delivered: six entries), spread over `--units` units, and then the
queries a person and the page make are timed, each `--repeat` times, alternating, and reported
as medians: the page's day chart (a day's `done` entries), a whole day exported page by page,
one unit's week, one job's life, the lookup a restart makes for each restored job, and the
hourly pruning of a day's entries.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

from gridfleet.coordinator.history_store import HistoryStore
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import Header, JobHistoryEntry, JobHistoryQuery
from gridfleet.protocol.messages import JobState, WaitCode

# A job's life: (state, unit or not, wait, seconds after submission).
LIFE: tuple[tuple[JobState, bool, WaitCode | None, float], ...] = (
    ("queued", False, None, 0.0),
    ("queued", False, "no_unit_free", 2.0),
    ("to_pickup", True, None, 30.0),
    ("loaded", True, None, 55.0),
    ("to_dropoff", True, None, 56.0),
    ("done", True, None, 90.0),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet bench history`."""
    parser.add_argument("--days", type=int, default=365, help="days of history (default 365)")
    parser.add_argument("--jobs-per-day", type=int, default=1000, help="jobs a day (default 1000)")
    parser.add_argument("--units", type=int, default=20, help="units doing them (default 20)")
    parser.add_argument("--repeat", type=int, default=5, help="times each query (default 5)")
    parser.add_argument("--db", type=Path, help="database file (default: a temporary one)")
    parser.add_argument("--json", action="store_true", help="print JSON")


def lives(days: int, per_day: int, units: int, now: datetime) -> Iterator[list[JobHistoryEntry]]:
    """Each day's entries, oldest day first, jobs spread evenly over the day."""
    gap = 86400.0 / per_day
    for day in range(days, 0, -1):
        start = now - timedelta(days=day)
        out = []
        for n in range(per_day):
            job = f"job-{(days - day) * per_day + n + 1}"
            unit = f"unit{n % units + 1}"
            submitted = start + timedelta(seconds=n * gap)
            for state, held, wait, after in LIFE:
                out.append(
                    JobHistoryEntry(
                        at=submitted + timedelta(seconds=after),
                        job=job,
                        state=state,
                        unit=unit if held else None,
                        wait=wait,
                        reason="every unit that can carry 7.0 kg is busy" if wait else None,
                        since_submitted_s=after,
                        pickup=Cell(n % 30, 3),
                        dropoff=Cell(4, n % 30),
                        mass_kg=7.0,
                        submitted_by="dashboard",
                    )
                )
        yield sorted(out, key=lambda e: e.at)


def _query(**fields: object) -> JobHistoryQuery:
    header = Header(seq=0, timestamp=datetime.now(UTC), sender="bench")
    return JobHistoryQuery(header=header, request_id="b", reply_to="bench", **fields)  # type: ignore[arg-type]


def _all_pages(store: HistoryStore, now: datetime, **fields: object) -> int:
    count, cursor = 0, None
    while True:
        entries, cursor = store.query(_query(cursor=cursor, **fields), now)
        count += len(entries)
        if cursor is None:
            return count


def run_bench(days: int, per_day: int, units: int, repeat: int, db: Path) -> dict[str, object]:
    """Fill the store at `db`, time the queries; the figures as plain data."""
    now = datetime.now(UTC)
    store = HistoryStore(db, retention_days=days + 2)
    began = time.perf_counter()
    rows = 0
    for entries in lives(days, per_day, units, now):
        store.add(entries, now)
        rows += len(entries)
    fill_s = time.perf_counter() - began
    store.close()
    began = time.perf_counter()
    store = HistoryStore(db, retention_days=days + 2)  # as a restart opens it
    open_s = time.perf_counter() - began
    yesterday = now - timedelta(days=1)
    week = now - timedelta(days=7)
    last_job = f"job-{days * per_day}"
    queries: dict[str, Callable[[], int]] = {
        "day_chart_done": lambda: _all_pages(store, now, since=yesterday, state="done", limit=1000),
        "day_export_all_pages": lambda: _all_pages(store, now, since=yesterday, limit=200),
        "unit_week": lambda: _all_pages(store, now, since=week, unit="unit1", limit=1000),
        "one_job_year": lambda: _all_pages(store, now, since=now - timedelta(days=days + 1), job_id=last_job),
        "restart_lookup": lambda: int(store.last(last_job) is not None),
    }  # fmt: skip
    times: dict[str, list[float]] = {name: [] for name in queries}
    found: dict[str, int] = {}
    for _ in range(repeat):  # alternating: each round runs every query once
        for name, ask in queries.items():
            began = time.perf_counter()
            found[name] = ask()
            times[name].append(time.perf_counter() - began)
    # Pruning: the hourly delete, here of the oldest day.
    store.retention = timedelta(days=days - 1)
    began = time.perf_counter()
    pruned = store.prune(now)
    prune_s = time.perf_counter() - began
    store.close()
    return {
        "days": days,
        "jobs_per_day": per_day,
        "entries": rows,
        "db_mib": round(db.stat().st_size / 2**20, 1),
        "fill_s": round(fill_s, 1),
        "open_s": round(open_s, 4),
        "queries_ms": {n: round(1000 * statistics.median(t), 2) for n, t in times.items()},
        "entries_found": found,
        "prune_one_day_ms": round(1000 * prune_s, 1),
        "pruned": pruned,
    }


def report(result: dict[str, object], as_json: bool) -> str:
    """The figures as text (or JSON)."""
    if as_json:
        return json.dumps(result, indent=2)
    lines = [
        f"{result['entries']:,} entries ({result['days']} days of {result['jobs_per_day']} jobs), "
        f"{result['db_mib']} MiB, filled in {result['fill_s']} s, opened in {result['open_s']} s",
    ]
    found = result["entries_found"]
    assert isinstance(found, dict)
    queries = result["queries_ms"]
    assert isinstance(queries, dict)
    for name, ms in queries.items():
        lines.append(f"  {name:<22} {ms:>9.2f} ms median  ({found[name]} entries)")
    lines.append(
        f"  {'prune_one_day':<22} {result['prune_one_day_ms']:>9.1f} ms  "
        f"({result['pruned']} entries)"
    )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the bench and print its figures."""
    if args.days < 2 or args.jobs_per_day < 1 or args.units < 1 or args.repeat < 1:
        raise ConfigError("--days ≥ 2, --jobs-per-day ≥ 1, --units ≥ 1, --repeat ≥ 1")
    if args.db is not None:
        if args.db.exists():
            raise ConfigError(f"--db {args.db} exists: give a new file (the bench fills it)")
        print(
            report(
                run_bench(args.days, args.jobs_per_day, args.units, args.repeat, args.db), args.json
            )
        )
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "history.db"
        print(
            report(run_bench(args.days, args.jobs_per_day, args.units, args.repeat, db), args.json)
        )
    return 0
