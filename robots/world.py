"""The world simulation: ground truth of a playfield, distance sensors, atomic moves, collisions."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal, Protocol

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol.messages import SensorReading
from gridfleet.scenario import Scenario


@dataclass(frozen=True)
class Collision:
    """One collision the simulation counted: its kind, the units involved and where."""

    kind: Literal["vertex", "swap", "wall", "obstacle"]
    units: tuple[str, ...]
    square: Cell


class SimulatedWorld(Protocol):
    """What a unit's shell needs of the world: `WorldSim` in one process, `SharedWorld` across."""

    @property
    def positions(self) -> Mapping[str, Cell]: ...
    @property
    def moves(self) -> Mapping[str, int]: ...
    @property
    def prevented(self) -> int: ...
    @property
    def collisions(self) -> int: ...
    def turn(self) -> contextlib.AbstractContextManager[None]: ...
    def position(self, unit_id: str) -> Cell: ...
    def sense(self, unit_id: str) -> dict[Direction, SensorReading]: ...
    def move(self, unit_id: str, direction: Direction) -> bool: ...
    def resume(self, unit_id: str, cell: Cell) -> None: ...
    def observe(self, unit_id: str, cell: Cell) -> None: ...


class Sensing:
    """Distance sensors over a world: walls and obstacles from the map, units where they stand."""

    grid: GridMap
    hidden: frozenset[Cell]
    sensors_see_units: bool

    def position(self, unit_id: str) -> Cell:
        """Where `unit_id` is (KeyError for an unknown unit)."""
        raise NotImplementedError

    def _others_on(self, cell: Cell, exclude: str | None) -> bool:
        """Whether a unit other than `exclude` stands on `cell`."""
        raise NotImplementedError

    def square(self, cell: Cell, exclude: str | None = None) -> SensorReading:
        """What a sensor sees in `cell`; the unit `exclude` (the one asking) is not seen."""
        reading = self._truth(cell, exclude)
        return "free" if reading == "unit" and not self.sensors_see_units else reading

    def _truth(self, cell: Cell, exclude: str | None) -> SensorReading:
        if not self.grid.in_bounds(cell):
            return "wall"
        if not self.grid.is_free(cell) or cell in self.hidden:
            return "obstacle"
        return "unit" if self._others_on(cell, exclude) else "free"

    def sense(self, unit_id: str) -> dict[Direction, SensorReading]:
        """The four distance sensors of `unit_id`: what is in each neighbouring square."""
        here = self.position(unit_id)
        return {d: self.square(here.step(d), exclude=unit_id) for d in Direction}


class WorldSim(Sensing):
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
        self._positions: dict[str, Cell] = dict(units or {})
        # Who stands where, kept with `positions`: a sensor reading must not scan the whole fleet.
        self._occupants: dict[Cell, set[str]] = {}
        for uid, cell in self._positions.items():
            self._occupants.setdefault(cell, set()).add(uid)
        self.remote: set[str] = set()  # units simulated elsewhere, known from their state
        self.moves: dict[str, int] = dict.fromkeys(self._positions, 0)
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
    def positions(self) -> Mapping[str, Cell]:
        """Every unit's square (read-only: `place`, `remove` and moves keep the index with it)."""
        return MappingProxyType(self._positions)

    @property
    def collisions(self) -> int:
        """How many collisions happened (vertex, swap, into a wall or obstacle)."""
        return len(self.log)

    def position(self, unit_id: str) -> Cell:
        """Where `unit_id` is (KeyError for an unknown unit)."""
        return self._positions[unit_id]

    @contextlib.contextmanager
    def turn(self) -> Iterator[None]:
        """One unit's step: already atomic, as every unit here runs on one event loop."""
        yield

    def _others_on(self, cell: Cell, exclude: str | None) -> bool:
        there = self._occupants.get(cell)
        return there is not None and (len(there) > 1 or exclude not in there)

    def move(self, unit_id: str, direction: Direction) -> bool:
        """Move one square if it is free; otherwise refuse, count it as prevented, return False."""
        target = self._positions[unit_id].step(direction)
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
        self._relocate(unit_id, cell)
        self.remote.add(unit_id)
        self.moves.setdefault(unit_id, 0)

    def resume(self, unit_id: str, cell: Cell) -> None:
        """Put a unit simulated here on `cell`: where it stood before this process restarted."""
        self._relocate(unit_id, cell)

    def observe(self, unit_id: str, cell: Cell) -> None:
        """A unit seen on `cell` in its published state; units simulated here are the truth."""
        if unit_id in self._positions and unit_id not in self.remote:
            return
        self.place(unit_id, cell)

    def remove(self, unit_id: str) -> None:
        """Forget a unit simulated elsewhere."""
        cell = self._positions.pop(unit_id, None)
        if cell is not None:
            self._leave(unit_id, cell)
        self.remote.discard(unit_id)

    def _relocate(self, unit_id: str, cell: Cell) -> None:
        old = self._positions.get(unit_id)
        if old is not None:
            self._leave(unit_id, old)
        self._positions[unit_id] = cell
        self._occupants.setdefault(cell, set()).add(unit_id)

    def _leave(self, unit_id: str, cell: Cell) -> None:
        there = self._occupants.get(cell)
        if there is not None:
            there.discard(unit_id)
            if not there:
                del self._occupants[cell]

    def _apply(self, moves: Mapping[str, Direction]) -> None:
        # Every move of one call happens in the same instant, so swaps can be seen.
        old = {uid: self._positions[uid] for uid in moves}
        for uid, d in moves.items():
            self._relocate(uid, old[uid].step(d))
            self.moves[uid] = self.moves.get(uid, 0) + 1
        for uid in moves:
            cell = self._positions[uid]
            if not self.grid.in_bounds(cell):
                self.log.append(Collision("wall", (uid,), cell))
            elif not self.grid.is_free(cell) or cell in self.hidden:
                self.log.append(Collision("obstacle", (uid,), cell))
        for cell in dict.fromkeys(self._positions[uid] for uid in moves):  # each square once
            uids = self._occupants[cell]
            if len(uids) > 1:
                self.log.append(Collision("vertex", tuple(sorted(uids)), cell))
        for a in moves:
            for b in moves:
                if a < b and self._positions[a] == old[b] and self._positions[b] == old[a]:
                    self.log.append(Collision("swap", (a, b), self._positions[a]))
