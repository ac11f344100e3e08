"""SQLite persistence of jobs (stdlib sqlite3), so a restarted coordinator loses no job."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable
from pathlib import Path

import platformdirs

from coordinator.jobs import Job


def default_db_path() -> Path:
    """`<user data dir>/gridfleet/coordinator.sqlite3`."""
    return Path(platformdirs.user_data_dir("gridfleet")) / "coordinator.sqlite3"


class JobStore:
    """One table of jobs as JSON rows, keyed by id; every save is one committed transaction."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if str(path) != ":memory:":
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(str(path))
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS jobs (id TEXT PRIMARY KEY, ord INTEGER, data TEXT NOT NULL)"
        )
        self._db.commit()

    def load(self) -> list[Job]:
        """Every stored job, in submission order."""
        rows = self._db.execute("SELECT data FROM jobs ORDER BY ord").fetchall()
        return [Job.from_dict(json.loads(r[0])) for r in rows]

    def save(self, jobs: Iterable[Job]) -> None:
        """Insert or update `jobs` in one transaction."""
        rows = [(j.id, j.order, json.dumps(j.to_dict())) for j in jobs]
        if not rows:
            return
        with self._db:
            self._db.executemany(
                "INSERT INTO jobs (id, ord, data) VALUES (?, ?, ?) "
                "ON CONFLICT(id) DO UPDATE SET ord = excluded.ord, data = excluded.data",
                rows,
            )

    def close(self) -> None:
        """Close the database."""
        self._db.close()
