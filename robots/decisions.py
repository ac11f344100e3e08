"""What a unit's core decides: the move it wants next, and what it made of an order or a goal."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from gridfleet.grid import Cell, Direction
from gridfleet.protocol.messages import SensorReading, UnitStatus

Readings = Mapping[Direction, SensorReading]
"""The four distance sensors: what each neighbouring square holds (protocol.md §4.3 `sensors`)."""

THING: dict[SensorReading, str] = {
    "wall": "a wall",
    "obstacle": "an obstacle",
    "unit": "another unit",
}
"""A sensor reading that blocks a square, in the words a `wait_reason` uses."""


def sq(cell: Cell) -> str:
    """A square as protocol.md writes it: [x, y]."""
    return f"[{cell.x}, {cell.y}]"


@dataclass(frozen=True)
class Intent:
    """What the unit wants to do next: a move (or None) with the status and reason if it cannot."""

    move: Direction | None
    status: UnitStatus
    reason: str | None = None


@dataclass(frozen=True)
class Verdict:
    """What a unit made of an order or goal; `reason` says why when it was refused."""

    result: Literal["accepted", "stale", "refused", "ignored"]
    reason: str | None = None
