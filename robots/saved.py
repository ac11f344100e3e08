"""Where each simulated unit stood and what it carried, kept in SQLite.

A restarted units process resumes from it instead of teleporting its units back to the scenario's
start squares with their loads gone (the coordinator would then see items vanish mid-job).
"""

from __future__ import annotations

import math
import sqlite3
from dataclasses import dataclass
from pathlib import Path

from gridfleet.errors import ConfigError, ProtocolError
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import validate_id

_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS units ("
    "id TEXT PRIMARY KEY, x INTEGER NOT NULL, y INTEGER NOT NULL, job_id TEXT, load_kg REAL NOT NULL)"
)


@dataclass(frozen=True)
class Saved:
    """One unit's square and load."""

    position: Cell
    job_id: str | None = None
    load_kg: float = 0.0


class SavedUnits:
    """The units' saved squares and loads in one SQLite file; `save` writes through at once."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            # Each unit's row has one writer (a sharded fleet's workers share the file, hence the
            # busy timeout); a SIGKILL loses nothing the OS already has (synchronous off).
            self._db = sqlite3.connect(
                path, isolation_level=None, check_same_thread=False, timeout=10.0
            )
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=OFF")
            self._db.execute(_SCHEMA)
        except sqlite3.Error as exc:
            raise ConfigError(f"{path}: cannot use it as the units' state file: {exc}") from None
        self._last: dict[str, Saved] = {}

    def load(self, grid: GridMap, units: list[str]) -> dict[str, Saved]:
        """The saved state of each of `units` that has one; a bad row is a ConfigError naming it."""
        try:
            rows = self._db.execute("SELECT id, x, y, job_id, load_kg FROM units").fetchall()
        except sqlite3.Error as exc:
            raise ConfigError(f"{self.path}: cannot read the units' state: {exc}") from None
        out = {}
        for uid, x, y, job_id, load in rows:
            if uid not in units:
                continue  # a unit of another run or scenario: not ours to resume
            out[uid] = self._checked(grid, uid, x, y, job_id, load)
        self._last = dict(out)
        return out

    def _checked(
        self, grid: GridMap, uid: str, x: object, y: object, job: object, load: object
    ) -> Saved:
        where = f"{self.path}: unit {uid}"
        if not (isinstance(x, int) and isinstance(y, int)) or not grid.is_free(Cell(x, y)):
            raise ConfigError(f"{where}: square {[x, y]} is not a free square of the map")
        if not isinstance(load, int | float) or not math.isfinite(load) or load < 0:
            raise ConfigError(f"{where}: load {load!r} is not a mass in kg")
        if job is not None:
            try:
                validate_id(job, "job id")  # type: ignore[arg-type]
            except ProtocolError as exc:
                raise ConfigError(f"{where}: {exc}") from None
        return Saved(Cell(x, y), job if isinstance(job, str) else None, float(load))

    def save(self, unit_id: str, saved: Saved) -> None:
        """Keep `saved` for `unit_id` (nothing is written when it has not changed)."""
        if self._last.get(unit_id) == saved:
            return
        self._db.execute(
            "INSERT OR REPLACE INTO units VALUES (?, ?, ?, ?, ?)",
            (unit_id, saved.position.x, saved.position.y, saved.job_id, saved.load_kg),
        )
        self._last[unit_id] = saved

    def close(self) -> None:
        """Close the file."""
        self._db.close()
