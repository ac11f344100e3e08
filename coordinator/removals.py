"""Units an operator removed for good (protocol.md §6.11): what the coordinator ignores of them,
and when one joins the fleet again, as a new unit.

Pure. A removed unit's retained topics are cleared by the coordinator (the connection last); once
that clear of its connection comes back, everything later on its topics is newer than the removal.
Until a unit rejoins, whatever it (or the broker's retained copy of it) says is ignored: an old
state must never reserve its squares again. It rejoins with a `connection` `online` heard after
that clear, or stamped after the removal (where the clear cannot come back: an account that may
not write the unit's topics), or with a state heard after that clear (it was on the floor after
all); its first state is then judged as any new unit's.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from typing import Any

from gridfleet.protocol import Connection, UnitState


@dataclass(frozen=True)
class Removal:
    """One unit's removal: when, by whom, and whether its connection's clear has come back."""

    at: datetime  # the coordinator's clock (UTC)
    by: str  # the request's sender
    cleared: bool = False

    def to_json(self) -> str:
        """As the store keeps it."""
        return json.dumps({"at": self.at.isoformat(), "by": self.by, "cleared": self.cleared})

    @classmethod
    def from_json(cls, text: str) -> Removal:
        """Inverse of to_json; ValueError (or KeyError, TypeError) for a row it cannot read."""
        data: dict[str, Any] = json.loads(text)
        at = datetime.fromisoformat(data["at"])
        return cls(
            at if at.tzinfo else at.replace(tzinfo=UTC), str(data["by"]), bool(data["cleared"])
        )


class Removals:
    """The removed units; `changed` says what to store (None: forgotten, it rejoined)."""

    def __init__(self, stored: Mapping[str, Removal] | None = None) -> None:
        self.units: dict[str, Removal] = dict(stored or {})
        self.changed: dict[str, Removal | None] = {}
        self._told: set[str] = set()  # units whose ignored messages the log has named

    def __contains__(self, unit: object) -> bool:
        return unit in self.units

    def remove(self, unit: str, at: datetime, by: str) -> None:
        """`unit` is removed from now on (again, if it was)."""
        self.units[unit] = self.changed[unit] = Removal(at, by)
        self._told.discard(unit)

    def uncleared(self) -> list[str]:
        """The removed units whose clear has not come back yet (to clear again)."""
        return sorted(u for u, r in self.units.items() if not r.cleared)

    def clear_heard(self, unit: str) -> None:
        """The clear of `unit`'s connection came back: later messages are newer than the removal."""
        removal = self.units.get(unit)
        if removal is not None and not removal.cleared:
            self.units[unit] = self.changed[unit] = replace(removal, cleared=True)

    def rejoins(self, unit: str, msg: Connection | UnitState) -> bool:
        """Whether `msg` is `unit` joining again after its removal (it is then forgotten here).

        A state heard after the clear came back is newer than the removal: the unit is on the
        floor after all (its link came back without a new session), and it is taken as a new
        one rather than ignored while it stands there.
        """
        removal = self.units.get(unit)
        if removal is None:
            return False
        if isinstance(msg, UnitState):
            if not removal.cleared:
                return False
            self._forget(unit)
            return True
        if msg.state != "online":
            return False
        stamped = msg.header.timestamp
        if stamped.tzinfo is None:  # a time without a zone is UTC (protocol.md §1)
            stamped = stamped.replace(tzinfo=UTC)
        if not removal.cleared and stamped <= removal.at:
            return False
        self._forget(unit)
        return True

    def _forget(self, unit: str) -> None:
        """`unit` is no longer removed: it joined again."""
        del self.units[unit]
        self.changed[unit] = None
        self._told.discard(unit)

    def first_ignored(self, unit: str) -> bool:
        """Whether this is the first message of removed `unit` ignored (the log says so once)."""
        if unit in self._told:
            return False
        self._told.add(unit)
        return True

    def take(self) -> tuple[tuple[str, Removal | None], ...]:
        """What changed since the last call, to store."""
        out = tuple(sorted(self.changed.items()))
        self.changed.clear()
        return out
