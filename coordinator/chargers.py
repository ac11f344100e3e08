"""The chargers and who holds each: never two units sent to one (protocol.md §5.9).

Pure: the map's chargers in, the nearest (free) one of a square out, by the distances given.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence

from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE
from gridfleet.protocol import Charger


class ChargerBook:
    """Every charger of the map, and the unit each one is given to (sent there, or charging)."""

    def __init__(self, chargers: Sequence[Charger] = ()) -> None:
        self.chargers = tuple(chargers)
        self._square = {c.name: c.square for c in self.chargers}
        self.squares = frozenset(self._square.values())
        self._holder: dict[str, str] = {}  # charger name -> unit

    def square(self, name: str) -> Cell | None:
        """The square of charger `name` (None: no such charger)."""
        return self._square.get(name)

    def holder(self, name: str) -> str | None:
        """The unit charger `name` is given to, if any."""
        return self._holder.get(name)

    def take(self, name: str, unit: str) -> None:
        """Give charger `name` to `unit` (it must be free)."""
        assert self._holder.get(name) in (None, unit), (name, self._holder.get(name), unit)
        self._holder[name] = unit

    def release(self, name: str, unit: str) -> None:
        """`unit` no longer holds charger `name`."""
        if self._holder.get(name) == unit:
            del self._holder[name]

    def nearest(
        self,
        square: Cell,
        distance: Callable[[Cell, Cell], int],
        *,
        free_only: bool = False,
        held_by: Collection[str] | None = None,
        within: float | None = None,
        skip: Collection[str] = (),
        blocked: Mapping[Cell, str] | None = None,
        unit: str | None = None,
    ) -> tuple[str, int] | None:
        """(name, squares) of the nearest charger reachable from `square`: any, a free one, or one
        held by a unit of `held_by`; None when there is none. Left out: chargers farther than
        `within` squares, those named in `skip`, and those on a square of `blocked` (square ->
        the unit standing there that cannot make way) unless that unit is `unit`. Ties go to the
        first listed."""
        best: tuple[str, int] | None = None
        for c in self.chargers:
            holder = self._holder.get(c.name)
            if free_only and holder is not None:
                continue
            if held_by is not None and holder not in held_by:
                continue
            if c.name in skip:
                continue
            if blocked is not None and blocked.get(c.square) not in (None, unit):
                continue
            d = distance(square, c.square)
            if d == UNREACHABLE or (within is not None and d > within):
                continue
            if best is None or d < best[1]:
                best = (c.name, int(d))
        return best
