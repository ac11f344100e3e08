"""The audit trail in SQLite (stdlib sqlite3): its own tables beside the coordinator's jobs.

A restart loses no entry; entries older than the retention (days) are deleted at start and then
about once an hour. Rows are the entries' JSON with their time apart, indexed, for range queries.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterable
from pathlib import Path

from gridfleet.coordinator.records import RecordQuery, as_utc
from gridfleet.protocol.messages import AuditEntry, AuditQuery

PRUNE_EVERY_S = 3600.0  # how often old entries are deleted, at most


class AuditStore:
    """Audit entries (id, time, actor, JSON) and the stop payloads the audit has seen."""

    def __init__(self, path: str | Path, keep_days: float) -> None:
        if not keep_days > 0:
            raise ValueError(f"audit retention {keep_days} days: give more than 0")
        self.keep_s = keep_days * 86400.0
        if str(path) != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        # A connection of its own to the coordinator's database: its tables are the audit's only.
        self._db = sqlite3.connect(str(path))
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS audit (id INTEGER PRIMARY KEY AUTOINCREMENT, "
            "at REAL NOT NULL, actor TEXT, data TEXT NOT NULL)"
        )
        self._db.execute("CREATE INDEX IF NOT EXISTS audit_at ON audit (at)")
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS audit_seen (topic TEXT PRIMARY KEY, payload BLOB NOT NULL)"
        )
        self._db.commit()
        self._pruned_at: float | None = None

    def add(self, entries: Iterable[AuditEntry]) -> None:
        """Append `entries` in one transaction."""
        rows = [(as_utc(e.at).timestamp(), e.actor, e.model_dump_json()) for e in entries]
        if rows:
            with self._db:
                self._db.executemany("INSERT INTO audit (at, actor, data) VALUES (?, ?, ?)", rows)

    def rows(self, query: RecordQuery, limit: int) -> list[tuple[int, AuditEntry]]:
        """Up to `limit` entries of `query` (since <= at < until, its actor) after its cursor's
        row, by id (records.RecordsDesk)."""
        assert isinstance(query.query, AuditQuery), "an audit store answers audit queries"
        sql = "SELECT id, data FROM audit WHERE at >= ? AND at < ? AND id > ?"
        args: list[object] = [query.since, query.until, query.after or 0]
        if query.query.actor is not None:
            sql += " AND actor = ?"
            args.append(query.query.actor)
        sql += " ORDER BY id LIMIT ?"
        args.append(limit)
        rows = self._db.execute(sql, args).fetchall()
        return [(int(i), AuditEntry.model_validate_json(data)) for i, data in rows]

    def prune(self, now: float) -> int:
        """Delete entries older than the retention (now: epoch s), at most once per
        PRUNE_EVERY_S; how many were deleted."""
        if self._pruned_at is not None and now - self._pruned_at < PRUNE_EVERY_S:
            return 0
        self._pruned_at = now
        with self._db:
            cursor = self._db.execute("DELETE FROM audit WHERE at < ?", (now - self.keep_s,))
        return cursor.rowcount

    def load_seen(self) -> list[tuple[str, bytes]]:
        """The stop payloads the audit had taken into account, by topic."""
        rows = self._db.execute("SELECT topic, payload FROM audit_seen ORDER BY topic").fetchall()
        return [(str(t), bytes(p)) for t, p in rows]

    def save_seen(self, seen: Iterable[tuple[str, bytes]]) -> None:
        """Remember the latest payload taken into account on each stop topic."""
        rows = list(seen)
        if rows:
            with self._db:
                self._db.executemany(
                    "INSERT OR REPLACE INTO audit_seen (topic, payload) VALUES (?, ?)", rows
                )

    def close(self) -> None:
        """Close the database."""
        self._db.close()
