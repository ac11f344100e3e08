"""SQLite persistence of jobs, of the answers to requests, of operators' controls and removals
of units, of the zones closed, and of the recent history (stdlib sqlite3).

A restarted coordinator loses no job, and still recognises a request retried across the restart.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable
from pathlib import Path
from typing import get_args

import platformdirs

from gridfleet.coordinator.answers import ANSWERS_KEPT, Answer
from gridfleet.coordinator.jobs import Job
from gridfleet.coordinator.removals import Removal
from gridfleet.protocol import EventEntry, Zone
from gridfleet.protocol.messages import MAX_EVENTS, UnitControlState

# More than the view shows: the view keeps stop and loss lines that chatter would have pushed out
# (coordinator/events.py), and must find them again after a restart.
STORED_EVENTS = 10 * MAX_EVENTS


def default_db_path() -> Path:
    """`<user data dir>/gridfleet/coordinator.sqlite3`."""
    return Path(platformdirs.user_data_dir("gridfleet")) / "coordinator.sqlite3"


class JobStore:
    """Jobs and answers as JSON rows; every save is one committed transaction."""

    def __init__(self, path: str | Path, answers_kept: int = ANSWERS_KEPT) -> None:
        self.path = Path(path)
        self.answers_kept = answers_kept
        if str(path) != ":memory:":
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(str(path))
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS jobs (id TEXT PRIMARY KEY, ord INTEGER, data TEXT NOT NULL)"
        )
        # Newest answer last (by rowid: a replaced row gets a new one).
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS answers (sender TEXT, request_id TEXT, data TEXT NOT NULL, "
            "PRIMARY KEY (sender, request_id))"
        )
        # An operator's control of a unit (paused, out of service) outlives a restart too.
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS controls (unit TEXT PRIMARY KEY, state TEXT NOT NULL)"
        )
        # Units an operator removed for good (protocol.md §6.11): ignored until they rejoin.
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS removed_units (unit TEXT PRIMARY KEY, data TEXT NOT NULL)"
        )
        # The recent history (fleet/events), newest last by rowid.
        self._db.execute("CREATE TABLE IF NOT EXISTS events (data TEXT NOT NULL)")
        # The zones closed (protocol.md §5.11), in the order they were closed (by rowid).
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS zones (name TEXT PRIMARY KEY, data TEXT NOT NULL)"
        )
        self._db.commit()

    def load_events(self) -> list[EventEntry]:
        """The stored history, oldest first (rows that no longer parse are skipped)."""
        rows = self._db.execute("SELECT data FROM events ORDER BY rowid").fetchall()
        events = []
        for (data,) in rows:
            try:
                events.append(EventEntry.model_validate_json(data))
            except ValueError:
                continue  # written by another version: the history is for people, not kept exact
        return events[-STORED_EVENTS:]

    def save_events(self, events: Iterable[EventEntry]) -> None:
        """Append `events`, keeping the latest STORED_EVENTS, in one transaction."""
        with self._db:
            self._db.executemany(
                "INSERT INTO events (data) VALUES (?)", [(e.model_dump_json(),) for e in events]
            )
            self._db.execute(
                "DELETE FROM events WHERE rowid <= (SELECT MAX(rowid) FROM events) - ?",
                (STORED_EVENTS,),
            )

    def load_controls(self) -> dict[str, UnitControlState]:
        """Unit -> its control (paused, out_of_service); a row of another version's is skipped."""
        rows = self._db.execute("SELECT unit, state FROM controls").fetchall()
        return {unit: state for unit, state in rows if state in get_args(UnitControlState)}

    def save_controls(self, changes: Iterable[tuple[str, str | None]]) -> None:
        """Set or (None) lift units' controls, in one transaction."""
        with self._db:
            for unit, state in changes:
                if state is None:
                    self._db.execute("DELETE FROM controls WHERE unit = ?", (unit,))
                else:
                    self._db.execute(
                        "INSERT OR REPLACE INTO controls (unit, state) VALUES (?, ?)", (unit, state)
                    )

    def load_removals(self) -> dict[str, Removal]:
        """Unit -> its removal; a row of another version's is skipped."""
        rows = self._db.execute("SELECT unit, data FROM removed_units").fetchall()
        out = {}
        for unit, data in rows:
            try:
                out[unit] = Removal.from_json(data)
            except (ValueError, KeyError, TypeError):
                continue
        return out

    def save_removals(self, changes: Iterable[tuple[str, Removal | None]]) -> None:
        """Store units' removals, or (None) forget them (they rejoined), in one transaction."""
        with self._db:
            for unit, removal in changes:
                if removal is None:
                    self._db.execute("DELETE FROM removed_units WHERE unit = ?", (unit,))
                else:
                    self._db.execute(
                        "INSERT OR REPLACE INTO removed_units (unit, data) VALUES (?, ?)",
                        (unit, removal.to_json()),
                    )

    def load_zones(self) -> list[Zone]:
        """The zones closed, in the order they were closed; a row of another version's is
        skipped."""
        rows = self._db.execute("SELECT data FROM zones ORDER BY rowid").fetchall()
        zones = []
        for (data,) in rows:
            try:
                zones.append(Zone.model_validate_json(data))
            except ValueError:
                continue
        return zones

    def save_zones(self, changes: Iterable[tuple[str, Zone | None]]) -> None:
        """Store zones closed, or (None) delete those opened, in one transaction."""
        with self._db:
            for name, zone in changes:
                self._db.execute("DELETE FROM zones WHERE name = ?", (name,))
                if zone is not None:
                    self._db.execute(
                        "INSERT INTO zones (name, data) VALUES (?, ?)",
                        (name, zone.model_dump_json()),
                    )

    def load(self) -> list[Job]:
        """Every stored job, in submission order."""
        rows = self._db.execute("SELECT data FROM jobs ORDER BY ord").fetchall()
        return [Job.from_dict(json.loads(r[0])) for r in rows]

    def load_answers(self) -> list[Answer]:
        """The latest stored answers, oldest first."""
        rows = self._db.execute("SELECT data FROM answers ORDER BY rowid").fetchall()
        return [Answer.from_dict(json.loads(r[0])) for r in rows]

    def save(self, jobs: Iterable[Job], answers: Iterable[Answer] = ()) -> None:
        """Insert or update `jobs` and `answers` in one transaction (a job with its answer)."""
        rows = [(j.id, j.order, json.dumps(j.to_dict())) for j in jobs]
        answered = [(a.sender, a.request_id, json.dumps(a.to_dict())) for a in answers]
        if not rows and not answered:
            return
        with self._db:
            self._db.executemany(
                "INSERT INTO jobs (id, ord, data) VALUES (?, ?, ?) "
                "ON CONFLICT(id) DO UPDATE SET ord = excluded.ord, data = excluded.data",
                rows,
            )
            if answered:
                self._db.executemany(
                    "INSERT OR REPLACE INTO answers (sender, request_id, data) VALUES (?, ?, ?)",
                    answered,
                )
                self._db.execute(
                    "DELETE FROM answers WHERE rowid <= (SELECT MAX(rowid) FROM answers) - ?",
                    (self.answers_kept,),
                )

    def close(self) -> None:
        """Close the database."""
        self._db.close()
