"""Where each simulated unit stood, what it carried and its battery's charge, kept in SQLite.

A restarted units process resumes from it instead of teleporting its units back to the scenario's
start squares with their loads gone (the coordinator would then see items vanish mid-job) and
their batteries back at their start charge.
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
    "id TEXT PRIMARY KEY, x INTEGER NOT NULL, y INTEGER NOT NULL, job_id TEXT, load_kg REAL NOT NULL,"
    " battery_pct REAL)"
)
_COLUMNS = "id, x, y, job_id, load_kg, battery_pct"


@dataclass(frozen=True)
class Saved:
    """One unit's square and load."""

    position: Cell
    job_id: str | None = None
    load_kg: float = 0.0
    battery_pct: float | None = None  # None: no battery (or none saved yet)


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
            columns = {row[1] for row in self._db.execute("PRAGMA table_info(units)")}
            if "battery_pct" not in columns:  # a file from before batteries: keep its rows
                self._db.execute("ALTER TABLE units ADD COLUMN battery_pct REAL")
        except sqlite3.Error as exc:
            raise ConfigError(f"{path}: cannot use it as the units' state file: {exc}") from None
        self._last: dict[str, Saved] = {}

    def load(self, grid: GridMap, units: list[str]) -> dict[str, Saved]:
        """The saved state of each of `units` that has one; a bad row is a ConfigError naming it."""
        try:
            rows = self._db.execute(f"SELECT {_COLUMNS} FROM units").fetchall()
        except sqlite3.Error as exc:
            raise ConfigError(f"{self.path}: cannot read the units' state: {exc}") from None
        out = {}
        for uid, x, y, job_id, load, battery in rows:
            if uid not in units:
                continue  # a unit of another run or scenario: not ours to resume
            out[uid] = self._checked(grid, uid, x, y, job_id, load, battery)
        self._last = dict(out)
        return out

    def _checked(
        self,
        grid: GridMap,
        uid: str,
        x: object,
        y: object,
        job: object,
        load: object,
        battery: object,
    ) -> Saved:
        where = f"{self.path}: unit {uid}"
        if not (isinstance(x, int) and isinstance(y, int)) or not grid.is_free(Cell(x, y)):
            raise ConfigError(f"{where}: square {[x, y]} is not a free square of the map")
        if not isinstance(load, int | float) or not math.isfinite(load) or load < 0:
            raise ConfigError(f"{where}: load {load!r} is not a mass in kg")
        pct: float | None = None
        if battery is not None:
            if not isinstance(battery, int | float) or not 0 <= battery <= 100:  # NaN too
                raise ConfigError(f"{where}: battery {battery!r} is not a charge of 0 to 100 %")
            pct = float(battery)
        if job is not None:
            try:
                validate_id(job, "job id")  # type: ignore[arg-type]
            except ProtocolError as exc:
                raise ConfigError(f"{where}: {exc}") from None
        return Saved(Cell(x, y), job if isinstance(job, str) else None, float(load), pct)

    def save(self, unit_id: str, saved: Saved) -> None:
        """Keep `saved` for `unit_id` (nothing is written when it has not changed)."""
        if self._last.get(unit_id) == saved:
            return
        self._db.execute(
            f"INSERT OR REPLACE INTO units ({_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?)",
            (
                unit_id,
                saved.position.x,
                saved.position.y,
                saved.job_id,
                saved.load_kg,
                saved.battery_pct,
            ),
        )
        self._last[unit_id] = saved

    def close(self) -> None:
        """Close the file."""
        self._db.close()
