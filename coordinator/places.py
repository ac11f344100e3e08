"""Named places (protocol.md §5.10): a job's pickup or dropoff given by name is resolved to the
square the map names so (the scenario is the truth), its kind checked.

Pure: the map's places in, a square (with the name it was given by) or a refusal out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from gridfleet.grid import Cell
from gridfleet.protocol import Place
from gridfleet.protocol.messages import RefusalCode

PLACES_LISTED = 20  # names a refusal lists of the map's places, at most
Role = Literal["pickup", "dropoff"]  # what a job asks of a place


@dataclass(frozen=True)
class Spot:
    """Where a job's pickup or dropoff is: its square, and the place it was named by (if any)."""

    square: Cell
    place: str | None = None

    def words(self) -> str:
        """`A3 [3, 4]` for a place, `[3, 4]` for a bare square."""
        square = f"[{self.square.x}, {self.square.y}]"
        return square if self.place is None else f"{self.place} {square}"


@dataclass(frozen=True)
class Refusal:
    """Why a request is refused: its code (Reply.code) and its reason in words."""

    code: RefusalCode
    reason: str


class Places:
    """The map's places by name."""

    def __init__(self, places: Sequence[Place] = ()) -> None:
        self.by_name = {p.name: p for p in places}
        if len(self.by_name) != len(places):
            raise ValueError("two places have one name")
        self.names = sorted(self.by_name)

    def resolve(self, where: Cell | str, role: Role) -> Spot | Refusal:
        """The square `where` names as a job's `role`: a square is itself; a name must be a place
        of kind `role`."""
        if not isinstance(where, str):
            return Spot(where)
        place = self.by_name.get(where)
        if place is None:
            return Refusal("unknown_place", f"unknown place {where!r}: {self.listing()}")
        if role not in place.kinds:
            kinds = ", ".join(place.kinds)
            return Refusal("bad_square", f"place {where} is not a {role} (it is: {kinds})")
        return Spot(place.square, place.name)

    def listing(self) -> str:
        """The places' names in words, the first PLACES_LISTED of them in order."""
        if not self.names:
            return "the map has no places"
        shown = ", ".join(self.names[:PLACES_LISTED])
        more = len(self.names) - PLACES_LISTED
        return f"the places are {shown}" + (f" (and {more} more)" if more > 0 else "")
