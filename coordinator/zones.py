"""Closed zones (protocol.md §5.11): rectangles of squares no unit is sent into, and the way out.

Pure: requests, the map and the time in; decisions, masks and ways out. An operator closes a zone
(a name, two corners and a reason) and opens it again. Planning treats a closed square as a wall
for every unit outside its zone (the coordinator's planner plans on the map with the closed
squares blocked, coordinator/core.py); a unit standing inside one when it closed is the only one
that may still be released its squares, and only those of its way out: the shortest way to the
nearest free square outside every closed zone, through the squares of the zones it stands in
(`Exits.way_out`). Without such a way (walls, obstacles, other zones all round) it holds, and
says why. Zones only take squares out of plans: the stop and protocol.md §4.4 are unchanged.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime

import numpy as np
import numpy.typing as npt

from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import CloseZone, Header, Zone, ZonesView
from gridfleet.protocol.constants import MAX_TEXT, MAX_ZONES
from gridfleet.protocol.messages import RefusalCode

ZoneChange = tuple[str, Zone | None]  # a zone closed (to store), or (None) opened (to delete)
Mask = npt.NDArray[np.bool_]  # indexed [y, x]: True on every square of a closed zone
NAMED = 8  # zones a refusal or a reason names before "and N more"


def clipped(text: str) -> str:
    """`text` within one protocol text (a zone's reason alone may fill one)."""
    return text if len(text) <= MAX_TEXT else text[: MAX_TEXT - 1] + "…"


def corners(a: Cell, b: Cell) -> tuple[Cell, Cell]:
    """The least (x, y) and the greatest (x, y) corner of the rectangle `a`, `b` span."""
    return Cell(min(a.x, b.x), min(a.y, b.y)), Cell(max(a.x, b.x), max(a.y, b.y))


def rectangle(zone: Zone) -> str:
    """`[2, 3] to [5, 8]`."""
    return f"{list(zone.first)} to {list(zone.last)}"


def closed_words(zone: Zone) -> str:
    """`zone aisle-4 closed: cleaning`: why a job waits on it (protocol.md §5.3)."""
    return clipped(f"zone {zone.name} closed: {zone.reason}")


def holds(zone: Zone, square: Cell) -> bool:
    """Whether `square` lies in `zone`'s rectangle."""
    return zone.first.x <= square.x <= zone.last.x and zone.first.y <= square.y <= zone.last.y


def _names(zones: Sequence[Zone]) -> str:
    names = [z.name for z in zones]
    if len(names) <= NAMED:
        return ", ".join(names)
    return f"{', '.join(names[:NAMED])} and {len(names) - NAMED} more"


@dataclass(frozen=True)
class Decision:
    """What closing or opening a zone came to: accepted or not, in words, why for machines, and
    whether anything changed (a zone closed again as it is: accepted, nothing changes)."""

    accepted: bool
    reason: str | None = None
    code: RefusalCode | None = None
    changed: bool = False


class ZoneBook:
    """The zones closed now, in the order they were closed, on a map of `width` x `height`."""

    def __init__(self, width: int, height: int, zones: Iterable[Zone] = ()) -> None:
        self.width, self.height = width, height
        self.zones: dict[str, Zone] = {}
        self.ignored: list[Zone] = []  # stored zones that do not fit this map: not in force
        for zone in zones:
            if self._on_map(zone.first) and self._on_map(zone.last) and len(self.zones) < MAX_ZONES:
                self.zones[zone.name] = zone
            else:
                self.ignored.append(zone)
        self.version = 0  # counts changes: what was worked out for an older one is out of date
        self.dirty = True  # the retained view is out of date (and goes out at start)
        self._changes: list[ZoneChange] = []
        self._mask: Mask | None = None

    def __len__(self) -> int:
        return len(self.zones)

    def __bool__(self) -> bool:
        return bool(self.zones)

    def _on_map(self, c: Cell) -> bool:
        return 0 <= c.x < self.width and 0 <= c.y < self.height

    # ---- which squares are closed ----------------------------------------------------------

    def mask(self) -> Mask:
        """Every square of every closed zone, as a [y, x] array the size of the map."""
        if self._mask is None:
            mask = np.zeros((self.height, self.width), dtype=bool)
            for z in self.zones.values():
                mask[z.first.y : z.last.y + 1, z.first.x : z.last.x + 1] = True
            mask.setflags(write=False)
            self._mask = mask
        return self._mask

    def covers(self, square: Cell) -> bool:
        """Whether `square` lies in a closed zone."""
        if not self.zones or not self._on_map(square):
            return False
        return bool(self.mask()[square.y, square.x])

    def holding(self, square: Cell) -> list[Zone]:
        """The closed zones `square` lies in, in the order they were closed."""
        if not self.covers(square):
            return []
        return [z for z in self.zones.values() if holds(z, square)]

    def zone_at(self, square: Cell) -> Zone | None:
        """The first closed zone `square` lies in, or None."""
        return next(iter(self.holding(square)), None)

    def blocks(self, here: Cell, square: Cell) -> bool:
        """Whether `square` is closed to a unit standing on `here`: a square of a closed zone,
        unless the unit stands inside that zone itself (it may drive its squares to leave)."""
        zones = self.holding(square)
        return bool(zones) and not any(holds(z, here) for z in zones)

    # ---- the operator's requests -----------------------------------------------------------

    def close(self, req: CloseZone, by: str | None, at: datetime) -> Decision:
        """Close `req.name` over the rectangle of its corners (either order), for its reason."""
        for what, c in (("first", req.first), ("last", req.last)):
            if not self._on_map(c):
                return Decision(
                    False,
                    f"zone {req.name}: corner {what} {list(c)} is off the "
                    f"{self.width}x{self.height} map",
                    "bad_square",
                )
        first, last = corners(req.first, req.last)
        known = self.zones.get(req.name)
        if known is not None:
            if (known.first, known.last, known.reason) == (first, last, req.reason):
                return Decision(
                    True, f"zone {req.name} is already closed, as asked: nothing changed"
                )
            return Decision(
                False,
                clipped(f"zone {req.name} is already closed ({known.reason}): open it first"),
                "conflict",
            )
        if len(self.zones) >= MAX_ZONES:
            return Decision(
                False,
                f"too many zones: {len(self.zones)} are closed (at most {MAX_ZONES}); open one "
                "first, or close one larger zone",
                "invalid",
            )
        zone = Zone(
            name=req.name, first=first, last=last, reason=req.reason, closed_by=by, closed_at=at
        )
        self.zones[req.name] = zone
        self._changed((req.name, zone))
        squares = (last.x - first.x + 1) * (last.y - first.y + 1)
        words = f"zone {req.name} closed: {rectangle(zone)}, {squares} squares"
        return Decision(True, words, None, True)

    def open(self, name: str) -> Decision:
        """Open the closed zone `name` again; refused for a zone not closed."""
        zone = self.zones.pop(name, None)
        stale = next((z for z in self.ignored if z.name == name), None)
        if zone is None and stale is not None:  # kept from a run on another map: forgotten
            self.ignored.remove(stale)
            self._changes.append((name, None))
            return Decision(True, f"zone {name} forgotten (it was not on this map)")
        if zone is None:
            closed = _names(list(self.zones.values())) or "none is"
            return Decision(False, f"zone {name} is not closed (closed: {closed})", "unknown_zone")
        self._changed((name, None))
        words = clipped(f"zone {name} opened ({rectangle(zone)}, closed: {zone.reason})")
        return Decision(True, words, None, True)

    def _changed(self, change: ZoneChange) -> None:
        self._changes.append(change)
        self._mask = None
        self.version += 1
        self.dirty = True

    def take_changes(self) -> tuple[ZoneChange, ...]:
        """The zones closed and opened since the last call (the shell stores them)."""
        out, self._changes = tuple(self._changes), []
        return out

    def view(self, header: Header) -> ZonesView:
        """The retained view `fleet/zones`; it counts as sent from here on."""
        self.dirty = False
        return ZonesView(header=header, zones=list(self.zones.values()))


def zone_refusal(zones: ZoneBook | None, square: Cell, what: str) -> str | None:
    """Why a job's `what` (pickup, dropoff) on `square` is refused while it lies in a closed zone:
    `pickup [3, 4] is in zone aisle-4, closed: cleaning`; None when it does not."""
    zone = None if zones is None else zones.zone_at(square)
    if zone is None:
        return None
    return clipped(f"{what} {list(square)} is in zone {zone.name}, closed: {zone.reason}")


def cut_words(zones: Sequence[Zone], what: str) -> str:
    """`zone aisle-4 (closed: cleaning) cuts every way to its pickup [3, 4]`."""
    each = " and ".join(f"{z.name} (closed: {z.reason})" for z in zones[:NAMED])
    more = f" and {len(zones) - NAMED} more" if len(zones) > NAMED else ""
    verb = "cuts" if len(zones) == 1 else "cut"
    return clipped(f"zone{'s' if len(zones) > 1 else ''} {each}{more} {verb} every way {what}")


# ---- the way out of a zone ------------------------------------------------------------------


@dataclass(frozen=True)
class WayOut:
    """A unit inside closed zones: the zones it stands in, and its way out (the squares after its
    own, the last one outside every closed zone), or None when there is none."""

    zones: tuple[Zone, ...]
    path: tuple[Cell, ...] | None

    @property
    def zone(self) -> Zone:
        """The first of the zones it stands in (the one its words name)."""
        return self.zones[0]

    def note(self) -> str:
        """What its route says (RouteView.note)."""
        z = self.zone
        if self.path is None:
            return clipped(f"holding: inside closed zone {z.name} and no way out")
        return clipped(f"leaving zone {z.name} (closed: {z.reason})")


class Exits:
    """Ways out of closed zones, worked out once per map, zones and region (kept between steps)."""

    def __init__(self) -> None:
        self._grid: GridMap | None = None  # the fields below are of this grid (kept: not its id)
        self._version = -1  # ... and of the zones at this version
        self._fields: dict[frozenset[str], dict[Cell, int]] = {}

    def way_out(self, grid: GridMap, zones: ZoneBook, start: Cell) -> WayOut | None:
        """`start`'s way out of the closed zones it lies in (None: it lies in none).

        The shortest way to the nearest free square outside every closed zone, through free
        squares of the zones `start` lies in only (never through another closed zone); of equal
        ways, the first by N E S W. `grid` is the map with its known obstacles.
        """
        inside = tuple(zones.holding(start))
        if not inside:
            return None
        if grid is not self._grid or zones.version != self._version:
            self._grid, self._version, self._fields = grid, zones.version, {}
        region = frozenset(z.name for z in inside)
        field = self._fields.get(region)
        if field is None:
            field = self._fields[region] = exit_field(grid, zones, inside)
        d = field.get(start)
        if d is None:
            return WayOut(inside, None)
        path: list[Cell] = []
        here = start
        while d > 0:
            here = next(n for n in here.neighbours() if field.get(n) == d - 1)
            path.append(here)
            d -= 1
        return WayOut(inside, tuple(path))


def exit_field(grid: GridMap, zones: ZoneBook, inside: Sequence[Zone]) -> dict[Cell, int]:
    """Steps from each free square of the zones `inside` to the nearest free square outside
    every closed zone (those squares at 0); squares with no way out are left out."""
    x0 = max(0, min(z.first.x for z in inside) - 1)
    y0 = max(0, min(z.first.y for z in inside) - 1)
    x1 = min(grid.width - 1, max(z.last.x for z in inside) + 1)
    y1 = min(grid.height - 1, max(z.last.y for z in inside) + 1)
    free = ~grid.blocked[y0 : y1 + 1, x0 : x1 + 1]
    closed = zones.mask()[y0 : y1 + 1, x0 : x1 + 1]
    region = np.zeros_like(free)
    for z in inside:
        region[z.first.y - y0 : z.last.y - y0 + 1, z.first.x - x0 : z.last.x - x0 + 1] = True
    region &= free
    outside = free & ~closed
    # The squares outside next to the region: where a way out ends.
    near = np.zeros_like(region)
    near[1:, :] |= region[:-1, :]
    near[:-1, :] |= region[1:, :]
    near[:, 1:] |= region[:, :-1]
    near[:, :-1] |= region[:, 1:]
    exits = outside & near
    if not exits.any():
        return {}
    ys, xs = np.nonzero(exits)
    field: dict[Cell, int] = {
        Cell(int(x) + x0, int(y) + y0): 0 for y, x in zip(ys, xs, strict=True)
    }
    frontier = list(field)
    depth = 0
    while frontier:
        depth += 1
        ahead = []
        for c in frontier:
            for n in c.neighbours():
                lx, ly = n.x - x0, n.y - y0
                if 0 <= lx <= x1 - x0 and 0 <= ly <= y1 - y0 and region[ly, lx] and n not in field:
                    field[n] = depth
                    ahead.append(n)
        frontier = ahead
    return field


def leaving_moves(ways: Mapping[str, Sequence[Cell]], taken: set[Cell]) -> dict[str, Cell]:
    """The next square of each unit leaving a zone (its way out, `ways`), when nobody stands on,
    holds, or is given it (`taken`, which the squares given join); nearest its way out first.

    A way out only descends towards the outside, so two units leaving never swap or go round in
    a ring; a square another unit stands on is never given (protocol.md §4.4): the unit behind
    follows once its state shows the square empty.
    """
    out: dict[str, Cell] = {}
    for unit in sorted(ways, key=lambda u: (len(ways[u]), u)):
        way = ways[unit]
        if way and way[0] not in taken:
            out[unit] = way[0]
            taken.add(way[0])
    return out
