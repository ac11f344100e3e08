"""The job history in SQLite (stdlib sqlite3), beside the jobs in the coordinator's store.

One row per entry, its fields as columns. Rows older than the retention are removed at start and then hourly. A page is ordered by time, then by row, and
its cursor is the last row's id, so a page that ends between two entries of the same time goes on
exactly after them.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterable, Mapping
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from gridfleet.coordinator.history import DEFAULT_RETENTION_DAYS, Key
from gridfleet.coordinator.records import Entry, RecordQuery, page_of
from gridfleet.protocol.messages import ChargeEntry, JobHistoryEntry, JobHistoryQuery

PRUNE_EVERY = timedelta(hours=1)
# An entry's fields as columns (a year of a busy hall is millions of rows: no JSON keys in each).
COLUMNS = (
    ("job", "TEXT NOT NULL"),
    ("state", "TEXT NOT NULL"),
    ("unit", "TEXT"),
    ("wait", "TEXT"),
    ("reason", "TEXT"),
    ("since_submitted_s", "REAL NOT NULL"),
    ("pickup_x", "INTEGER NOT NULL"),
    ("pickup_y", "INTEGER NOT NULL"),
    ("dropoff_x", "INTEGER NOT NULL"),
    ("dropoff_y", "INTEGER NOT NULL"),
    ("mass_kg", "REAL NOT NULL"),
    ("priority", "INTEGER NOT NULL"),
    ("submitted_by", "TEXT"),
    ("pickup_place", "TEXT"),  # added in 1.6: a store made before gets them, null (`_add_columns`)
    ("dropoff_place", "TEXT"),
)
_NAMES = ", ".join(c for c, _ in COLUMNS)
# Each charge started or ended (protocol.md §6.10, query kind "charges"), in a table of its own.
CHARGE_COLUMNS = (
    ("unit", "TEXT NOT NULL"),
    ("charger", "TEXT NOT NULL"),
    ("event", "TEXT NOT NULL"),
    ("battery_pct", "REAL NOT NULL"),
    ("reason", "TEXT"),
)
_CHARGE_NAMES = ", ".join(c for c, _ in CHARGE_COLUMNS)


def _charge(row: tuple[Any, ...]) -> ChargeEntry:
    at, unit, charger, event, pct, reason = row
    return ChargeEntry.model_validate(
        {
            "at": at,
            "unit": unit,
            "charger": charger,
            "event": event,
            "battery_pct": pct,
            "reason": reason,
        }
    )


def _row(e: JobHistoryEntry) -> tuple[object, ...]:
    return (
        e.at.timestamp(), e.job, e.state, e.unit, e.wait, e.reason, e.since_submitted_s,
        e.pickup.x, e.pickup.y, e.dropoff.x, e.dropoff.y, e.mass_kg, e.priority, e.submitted_by,
        e.pickup_place, e.dropoff_place,
    )  # fmt: skip


def _entry(row: tuple[Any, ...]) -> JobHistoryEntry:
    # Validated (a row written by another version must not pass for an entry), from plain data:
    # pydantic's core does it faster than the constructor, and reads `at` as Unix seconds, UTC.
    at, job, state, unit, wait, reason, since, px, py, dx, dy, mass, priority, by, pp, dp = row
    return JobHistoryEntry.model_validate(
        {
            "at": at,
            "job": job,
            "state": state,
            "unit": unit,
            "wait": wait,
            "reason": reason,
            "since_submitted_s": since,
            "pickup": (px, py),
            "dropoff": (dx, dy),
            "mass_kg": mass,
            "priority": priority,
            "submitted_by": by,
            "pickup_place": pp,
            "dropoff_place": dp,
        }
    )


class HistoryStore:
    """Job history entries, kept `retention_days`; every write is one committed transaction."""

    def __init__(self, path: str | Path, retention_days: float = DEFAULT_RETENTION_DAYS) -> None:
        if not retention_days > 0:
            raise ValueError(f"history retention {retention_days} days: give more than 0")
        self.retention = timedelta(days=retention_days)
        if str(path) != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(str(path))
        self._db.execute("PRAGMA journal_mode=WAL")
        # Each job change is a write: not each one waits for the disk (the jobs' own store does).
        # With WAL this loses nothing when the coordinator dies, only the last moments at a power
        # cut, and the store stays whole.
        self._db.execute("PRAGMA synchronous=NORMAL")
        with self._db:
            self._db.execute(
                "CREATE TABLE IF NOT EXISTS job_history (id INTEGER PRIMARY KEY AUTOINCREMENT, "
                f"at REAL NOT NULL, {', '.join(f'{c} {t}' for c, t in COLUMNS)})"
            )
            self._add_columns()
            # AUTOINCREMENT: a pruned entry's id is never given again, so an old cursor cannot
            # point into newer entries. One index per filter a query may give, each ending in
            # the time it is ordered by.
            for name, columns in (
                ("at", "at"),
                ("unit", "unit, at"),
                ("state", "state, at"),
                ("job", "job, at"),
            ):
                self._db.execute(
                    f"CREATE INDEX IF NOT EXISTS job_history_{name} ON job_history ({columns})"
                )
            self._db.execute(
                "CREATE TABLE IF NOT EXISTS charge_history (id INTEGER PRIMARY KEY AUTOINCREMENT, "
                f"at REAL NOT NULL, {', '.join(f'{c} {t}' for c, t in CHARGE_COLUMNS)})"
            )
            for name, columns in (("at", "at"), ("unit", "unit, at")):
                self._db.execute(
                    f"CREATE INDEX IF NOT EXISTS charge_history_{name} "
                    f"ON charge_history ({columns})"
                )
        self._pruned_at: datetime | None = None
        self.prune(datetime.now(UTC))

    def _add_columns(self) -> None:
        """The columns a store made by an older version lacks, added (its rows read them null)."""
        have = {row[1] for row in self._db.execute("PRAGMA table_info(job_history)")}
        for column, kind in COLUMNS:
            if column not in have:
                self._db.execute(f"ALTER TABLE job_history ADD COLUMN {column} {kind}")

    def close(self) -> None:
        """Close the database."""
        self._db.close()

    def add(self, entries: Iterable[JobHistoryEntry], now: datetime | None = None) -> None:
        """Store `entries`; hourly, drop those older than the retention."""
        rows = [_row(e) for e in entries]
        if rows:
            with self._db:
                self._db.executemany(
                    f"INSERT INTO job_history (at, {_NAMES}) VALUES (?{', ?' * len(COLUMNS)})",
                    rows,
                )
        now = now or datetime.now(UTC)
        if self._pruned_at is None or now - self._pruned_at >= PRUNE_EVERY:
            self.prune(now)

    def add_charges(self, entries: Iterable[ChargeEntry]) -> None:
        """Store charges started and ended (pruned with the job history)."""
        rows = [
            (e.at.timestamp(), e.unit, e.charger, e.event, e.battery_pct, e.reason) for e in entries
        ]
        if rows:
            with self._db:
                self._db.executemany(
                    f"INSERT INTO charge_history (at, {_CHARGE_NAMES}) VALUES (?, ?, ?, ?, ?, ?)",
                    rows,
                )

    def prune(self, now: datetime) -> int:
        """Drop the entries (and charges) older than the retention; how many went."""
        with self._db:
            cut = ((now - self.retention).timestamp(),)
            gone = self._db.execute("DELETE FROM job_history WHERE at < ?", cut).rowcount
            gone += self._db.execute("DELETE FROM charge_history WHERE at < ?", cut).rowcount
        self._pruned_at = now
        return gone

    def last(self, job_id: str) -> tuple[Key, datetime] | None:
        """The latest entry's key of `job_id` and when it was submitted; None if never stored."""
        rows = self._db.execute(
            "SELECT at, since_submitted_s, state, unit, wait FROM job_history WHERE job = ? "
            "ORDER BY at, id",
            (job_id,),
        ).fetchall()
        if not rows:
            return None
        at, since = rows[0][:2]
        state, unit, wait = rows[-1][2:]
        return (state, unit, wait), datetime.fromtimestamp(at - since, UTC)

    def rows(
        self, query: RecordQuery, limit: int
    ) -> list[tuple[int, JobHistoryEntry]] | list[tuple[int, ChargeEntry]]:
        """Up to `limit` entries of `query` (since <= at < until, its filters) after its cursor's
        row, by time and then row (records.RecordsDesk); of kind "charges", charges."""
        q = query.query
        assert isinstance(q, JobHistoryQuery), "a history store answers job history queries"
        if q.kind == "charges":  # the unit filter applies; job_id and state do not
            rows = self._page("charge_history", _CHARGE_NAMES, {"unit": q.unit}, query, limit)
            return [(int(row[0]), _charge(row[1:])) for row in rows]
        filters = {"unit": q.unit, "job": q.job_id, "state": q.state}
        rows = self._page("job_history", _NAMES, filters, query, limit)
        return [(int(row[0]), _entry(row[1:])) for row in rows]

    def _page(
        self,
        table: str,
        names: str,
        filters: Mapping[str, object],
        query: RecordQuery,
        limit: int,
    ) -> list[Any]:
        """Up to `limit` rows (id, at, `names`) of `table` in `query`'s range, equal to the
        `filters` given (None: any), after its cursor's row, by time and then row."""
        where = ["at >= ?", "at < ?"]
        args: list[object] = [query.since, query.until]
        for column, value in filters.items():
            if value is not None:
                where.append(f"{column} = ?")
                args.append(value)
        if query.after is not None:
            # After the cursor's row in (at, id) order; a pruned cursor row starts from `since`.
            where.append(
                f"(at > COALESCE((SELECT at FROM {table} WHERE id = ?), -1e18) OR "
                f"(at = (SELECT at FROM {table} WHERE id = ?) AND id > ?))"
            )
            args += [query.after] * 3
        return self._db.execute(
            f"SELECT id, at, {names} FROM {table} WHERE {' AND '.join(where)} "
            "ORDER BY at, id LIMIT ?",
            [*args, limit],
        ).fetchall()

    def query(self, query: JobHistoryQuery, now: datetime) -> tuple[list[Entry], str | None]:
        """One page of entries for `query` (until `now` if it gives none), and the next cursor."""
        return page_of(self, RecordQuery.of("job_history", query, now))
