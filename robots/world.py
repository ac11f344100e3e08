"""The world simulation: ground truth of a playfield, distance sensors, atomic moves, collisions."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Literal

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.scenario import Scenario

Reading = Literal["free", "wall", "obstacle", "unit"]


@dataclass(frozen=True)
class Collision:
    """One collision the simulation counted: its kind, the units involved and where."""

    kind: Literal["vertex", "swap", "wall", "obstacle"]
    units: tuple[str, ...]
    square: Cell


class WorldSim:
    """Walls, fixed and hidden obstacles, and every unit's square; refuses and counts bad moves.

    Sensors: off the map reads `wall`; a fixed obstacle (`@` on the map) or a hidden obstacle
    reads `obstacle`; another unit reads `unit`. `move` never performs a move into a blocked or
    occupied square: it refuses and counts it in `prevented`. `force_move` performs moves without
    checks (scripted bad moves for tests) and counts what they collide with in `collisions`.

    With `sensors_see_units` off, sensors read other units as `free`: units then trust their
    orders alone, so every move the coordinator's orders lead into an occupied square shows up
    in `prevented`. Tests use it to check the coordinator without the units' own safety layer.
    """

    def __init__(
        self,
        grid: GridMap,
        hidden: Iterable[Cell] = (),
        units: Mapping[str, Cell] | None = None,
        *,
        sensors_see_units: bool = True,
    ) -> None:
        self.grid = grid
        self.sensors_see_units = sensors_see_units
        self.hidden: frozenset[Cell] = frozenset(hidden)
        self.positions: dict[str, Cell] = dict(units or {})
        self.remote: set[str] = set()  # units simulated elsewhere, known from their state
        self.moves: dict[str, int] = dict.fromkeys(self.positions, 0)
        self.prevented = 0
        self.log: list[Collision] = []

    @classmethod
    def from_scenario(cls, scenario: Scenario, *, sensors_see_units: bool = True) -> WorldSim:
        """The world of `scenario` with every unit on its start square."""
        return cls(
            scenario.grid,
            scenario.hidden_obstacles,
            {u.id: u.start for u in scenario.units},
            sensors_see_units=sensors_see_units,
        )

    @property
    def collisions(self) -> int:
        """How many collisions happened (vertex, swap, into a wall or obstacle)."""
        return len(self.log)

    def position(self, unit_id: str) -> Cell:
        """Where `unit_id` is (KeyError for an unknown unit)."""
        return self.positions[unit_id]

    def square(self, cell: Cell, exclude: str | None = None) -> Reading:
        """What a sensor sees in `cell`; the unit `exclude` (the one asking) is not seen."""
        reading = self._truth(cell, exclude)
        return "free" if reading == "unit" and not self.sensors_see_units else reading

    def _truth(self, cell: Cell, exclude: str | None) -> Reading:
        if not self.grid.in_bounds(cell):
            return "wall"
        if not self.grid.is_free(cell) or cell in self.hidden:
            return "obstacle"
        if any(c == cell and u != exclude for u, c in self.positions.items()):
            return "unit"
        return "free"

    def sense(self, unit_id: str) -> dict[Direction, Reading]:
        """The four distance sensors of `unit_id`: what is in each neighbouring square."""
        here = self.positions[unit_id]
        return {d: self.square(here.step(d), exclude=unit_id) for d in Direction}

    def move(self, unit_id: str, direction: Direction) -> bool:
        """Move one square if it is free; otherwise refuse, count it as prevented, return False."""
        target = self.positions[unit_id].step(direction)
        if self._truth(target, exclude=unit_id) != "free":
            self.prevented += 1
            return False
        self._apply({unit_id: direction})
        return True

    def force_move(self, moves: Mapping[str, Direction]) -> int:
        """Perform `moves` at once without any check; return how many collisions they caused."""
        before = self.collisions
        self._apply(moves)
        return self.collisions - before

    def place(self, unit_id: str, cell: Cell) -> None:
        """Put a unit simulated elsewhere on `cell` (learnt from its published state)."""
        self.positions[unit_id] = cell
        self.remote.add(unit_id)
        self.moves.setdefault(unit_id, 0)

    def remove(self, unit_id: str) -> None:
        """Forget a unit simulated elsewhere."""
        self.positions.pop(unit_id, None)
        self.remote.discard(unit_id)

    def _apply(self, moves: Mapping[str, Direction]) -> None:
        # Every move of one call happens in the same instant, so swaps can be seen.
        old = dict(self.positions)
        for uid, d in moves.items():
            self.positions[uid] = old[uid].step(d)
            self.moves[uid] = self.moves.get(uid, 0) + 1
        for uid in moves:
            cell = self.positions[uid]
            if not self.grid.in_bounds(cell):
                self.log.append(Collision("wall", (uid,), cell))
            elif not self.grid.is_free(cell) or cell in self.hidden:
                self.log.append(Collision("obstacle", (uid,), cell))
        seen: dict[Cell, list[str]] = {}
        for uid, cell in self.positions.items():
            seen.setdefault(cell, []).append(uid)
        for cell, uids in seen.items():
            if len(uids) > 1 and any(u in moves for u in uids):
                self.log.append(Collision("vertex", tuple(sorted(uids)), cell))
        for a in moves:
            for b in moves:
                if a < b and self.positions[a] == old[b] and self.positions[b] == old[a]:
                    self.log.append(Collision("swap", (a, b), self.positions[a]))
