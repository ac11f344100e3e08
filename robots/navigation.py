"""Standalone routing (protocol.md §4.5): a unit's own way to its goal, giving way to other units.

It plans breadth-first on the map it knows (the static map plus the obstacles it has sensed). A
unit blocked by another waits a few (randomised, id-seeded) steps, then routes around it if the
detour is short, else gives way (steps aside, or backs off until it can), and takes the detour the
next time.
"""

from __future__ import annotations

import random
import zlib

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.paths import UNREACHABLE, DistanceFieldCache, distance_field, route
from gridfleet.robots.decisions import THING, Intent, Readings, sq

AVOID_STEPS = 4  # how long a standalone unit keeps out of a square where a unit blocked it
PAUSE_STEPS = 3  # how long a unit that stepped aside stays there to let the other pass
QUIET_STEPS = 3  # steps without the other unit in front that end giving way
DETOUR_MAX = 4  # extra steps a unit accepts to route around another rather than give way


class Navigator:
    """A standalone unit's goal and the way to it; one `intent` per decision, `moved` per move."""

    def __init__(
        self, unit_id: str, grid: GridMap, known_obstacles: set[Cell], goal: Cell | None = None
    ) -> None:
        self.grid = grid
        self.known_obstacles = known_obstacles  # the unit's own set: it grows as the unit senses
        self.goal = goal
        self._fields_cache: DistanceFieldCache | None = None  # built on first plan
        self._avoid: dict[Cell, int] = {}
        self._waited = 0
        self._yield_from: Direction | None = None  # giving way to a unit on this side
        self._quiet = 0
        self._pause_until = 0
        self._gave_way = False  # gave way since its last progress: next time it routes around
        self._best = UNREACHABLE  # closest it has been to the goal (progress resets _gave_way)
        # Units give way after different, re-drawn waits, so two of them never do it in
        # lock-step; the generator is seeded by the id, so runs repeat exactly.
        self._rng = random.Random(zlib.crc32(unit_id.encode()))
        self.patience = self._rng.randint(2, 6)

    def set_goal(self, target: Cell | None) -> str | None:
        """Set or clear the goal; why not when it is off the map, on a wall or a known obstacle."""
        if target is not None and (not self.grid.is_free(target) or target in self.known_obstacles):
            return f"goal {sq(target)} is off the map, on a wall or an obstacle"
        self.goal = target
        self._avoid.clear()
        self._waited = 0
        self._yield_from = None
        self._pause_until = 0
        self._gave_way = False
        self._best = UNREACHABLE
        return None

    def map_changed(self) -> None:
        """A new obstacle was sensed: plan on the map as it is now known."""
        self._fields_cache = None

    def moved(self, direction: Direction, step: int) -> None:
        """The unit made a move in step `step`."""
        self._waited = 0
        if self._yield_from is not None and direction not in (
            self._yield_from,
            self._yield_from.opposite,
        ):
            # Stepped aside: stay a few steps so the other unit can pass.
            self._yield_from = None
            self._pause_until = step + PAUSE_STEPS

    def intent(self, position: Cell, sensors: Readings, step: int, waiting_counts: bool) -> Intent:
        """The next move towards the goal; `waiting_counts` once per step (not on a refresh)."""
        if self.goal is None or position == self.goal:
            self._yield_from = None
            return Intent(None, "idle")
        if step < self._pause_until:
            return Intent(None, "waiting", "giving way to another unit")
        if self._yield_from is not None:
            intent = self._give_way(self._yield_from, sensors, waiting_counts)
            if intent is not None:
                return intent
        self._avoid = {c: until for c, until in self._avoid.items() if until > step}
        path = self._plan(position, avoid=True) or self._plan(position, avoid=False)
        if not path:
            return Intent(None, "waiting", f"no known route to the goal {sq(self.goal)}")
        if len(path) < self._best:
            self._best, self._gave_way = len(path), False
        nxt = path[0]
        d = position.direction_to(nxt)
        assert d is not None
        reading = sensors[d]
        if reading == "free":
            return Intent(d, "moving")
        if reading == "unit" and waiting_counts:
            self._waited += 1
            if self._waited >= self.patience:
                self._waited = 0
                self.patience = self._rng.randint(2, 6)
                around = self._plan(position, avoid=True, extra=nxt)
                if around and (len(around) <= len(path) + DETOUR_MAX or self._gave_way):
                    # Waited long enough and there is another way: route around that unit
                    # until the detour is driven.
                    self._avoid[nxt] = step + max(AVOID_STEPS, len(around))
                else:
                    # No way around (a corridor) or a long one: give way by stepping aside or
                    # backing off; if that does not help, the next time it takes the detour.
                    self._yield_from, self._quiet, self._gave_way = d, 0, True
        return Intent(None, "waiting", f"next square {sq(nxt)} is blocked by {THING[reading]}")

    def _give_way(
        self, blocker: Direction, sensors: Readings, waiting_counts: bool
    ) -> Intent | None:
        """Step aside from, or back off before, a unit on side `blocker`; None when done."""
        if sensors[blocker] != "unit":
            if waiting_counts:
                self._quiet += 1
            if self._quiet >= QUIET_STEPS:
                self._yield_from = None
                return None
            return Intent(None, "waiting", "giving way to another unit")
        if waiting_counts:
            self._quiet = 0
        sides = [d for d in Direction if d not in (blocker, blocker.opposite)]
        for d in [*sides, blocker.opposite]:
            if sensors[d] == "free":
                return Intent(d, "moving")
        return Intent(None, "waiting", "giving way to another unit, but boxed in")

    @property
    def _fields(self) -> DistanceFieldCache:
        """Distance fields on the map as this unit knows it (static map plus sensed obstacles)."""
        if self._fields_cache is None:
            self._fields_cache = DistanceFieldCache(self.grid.with_blocked(self.known_obstacles))
        return self._fields_cache

    def _plan(self, position: Cell, avoid: bool, extra: Cell | None = None) -> list[Cell] | None:
        assert self.goal is not None
        if avoid:
            blocked = {*self._avoid, *([extra] if extra is not None else [])} - {self.goal}
            if not blocked:
                return None
            grid = self._fields.grid.with_blocked(blocked)
            field = distance_field(grid, self.goal)
        else:
            field = self._fields.get(self.goal)
        if int(field[position.y, position.x]) == UNREACHABLE:
            return None
        return route(field, position)
