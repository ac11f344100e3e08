"""Released windows (protocol.md §4.4): how many squares of its way a unit is given ahead.

Pure. The planner still decides every settled unit's next square; a window adds the squares of
the unit's way after it (or after what it still may drive) that are safe to give it now, so a
unit on a free road has its next square before it needs it and drives every step instead of
waiting a round trip per square. A square is safe to add when nobody else could be on it or enter
it before the unit's state shows the unit has left it:

- nobody stands on it, holds it (may still drive it, `Orders.reserved`) or waits to follow into it;
- it is nobody else's move of this step, nor in a window given out earlier in this step;
- nobody else's way enters it within the window (contention: there the planner decides, one step
  at a time, pushing the less urgent out of the way; a unit in a window cannot be pushed). A unit
  coming behind on the same way does not contend: it cannot pass the unit ahead of it.

A window is reserved road nobody else may use, so a unit gets one only once it needs it: its
window starts at one square and grows by one (up to the coordinator's bound) each time the unit
ran out of squares before the order that would have given it the next one reached it (a round
trip lost: a unit on its own clock, a loaded broker). Units whose orders arrive in time, as in
`simulate --deterministic`, keep moving one planned square at a time, every square the planner's.

Every square a window gives stays reserved for its unit until the unit's state shows it left, so
the safety argument of single-square releases carries over unchanged: a released square is
empty and nobody else's when given, and nobody else is given it while it is held.
"""

from __future__ import annotations

from collections.abc import Iterable

from gridfleet.errors import ConfigError
from gridfleet.grid import Cell, GridMap

# Squares a unit may be released ahead, by default. A window grows only for a unit that ran dry
# waiting for an order, so a fleet whose orders arrive in time moves as with 1 (one square per
# order, `--window 1`). 4 did 1.25-1.34x the jobs of 1 in the system bench (bench/README.md).
DEFAULT_WINDOW = 4
MAX_WINDOW = 32  # the setting's bound (an order releases at most MAX_RELEASED squares)


def check_window(window: int, flag: str = "--window") -> int:
    """`window` when it is 1 to MAX_WINDOW squares; else a ConfigError naming `flag`."""
    if not 1 <= window <= MAX_WINDOW:
        raise ConfigError(f"{flag} {window}: give 1 to {MAX_WINDOW} squares")
    return window


class Claims:
    """This step's claims on squares: who stands on, holds, enters or intends each one."""

    def __init__(self, grid: GridMap) -> None:
        self.grid = grid
        self._holder: dict[Cell, str] = {}  # first claimant wins; others are refused it
        self._intent: dict[Cell, set[str]] = {}
        self._ways: dict[str, dict[Cell, int]] = {}  # each unit's way: square -> its place
        self._standing: dict[Cell, str] = {}  # where each unit stands

    def hold(self, unit: str, squares: Iterable[Cell]) -> None:
        """`unit` stands on, may drive, follows into or was just given `squares`."""
        for c in squares:
            self._holder.setdefault(c, unit)

    def stand(self, unit: str, square: Cell) -> None:
        """`unit` stands on `square` (and holds it)."""
        self._standing[square] = unit
        self.hold(unit, [square])

    def intend(self, unit: str, way: list[Cell]) -> None:
        """`unit`'s way enters these squares within the window: no other window may take them
        (but for a unit ahead of it on that same way, see `safe`)."""
        order = {c: i for i, c in enumerate(way)}
        self._ways[unit] = order
        for c in way:
            self._intent.setdefault(c, set()).add(unit)

    def safe(self, unit: str, here: Cell, square: Cell) -> bool:
        """Whether `square` may go into the window of `unit`, which stands on `here`."""
        if not self.grid.is_free(square):
            return False
        if self._holder.get(square, unit) != unit:
            return False
        contenders = self._intent.get(square, ())
        return not any(self._contends(other, here, square) for other in contenders)

    def _contends(self, other: str, here: Cell, square: Cell) -> bool:
        """Whether `other` could want `square` before the unit on `here` has left it: any unit
        but the one itself and one coming behind it (its way passes `here` before `square`)."""
        if other == self._standing.get(here):
            return False
        way = self._ways.get(other, {})
        if here not in way:
            return True
        return square in way and way[square] < way[here]

    def ahead(self, unit: str, here: Cell, way: Iterable[Cell], room: int) -> list[Cell]:
        """The first squares of `way` (each adjacent to the one before) that are safe for `unit`
        on `here`, at most `room` of them; given to it at once (held)."""
        out: list[Cell] = []
        for c in way:
            if len(out) >= room or not self.safe(unit, here, c):
                break
            out.append(c)
        self.hold(unit, out)
        return out
