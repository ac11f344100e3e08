"""One world simulation for a fleet whose units run in several processes of one machine.

The parent process creates it in shared memory; each worker process attaches to it. Every unit's
square, its move count and the counters live there, so the world stays one ground truth whatever
process a unit runs in: a unit's step (sense, decide, move) happens under one lock across the
processes (`turn()`), exactly as one process's event loop makes it atomic for `WorldSim`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from multiprocessing import shared_memory
from multiprocessing.synchronize import Lock
from typing import Any

import numpy as np

from gridfleet.errors import ConfigError
from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.robots.world import Sensing
from gridfleet.scenario import Scenario, with_units

_NOBODY = -1  # a position not set yet


def _layout(n: int, cells: int) -> list[tuple[type[np.signedinteger[Any]], int]]:
    """The block's arrays in order: positions (x, y), units per square, moves, refusals."""
    return [(np.int32, 2 * n), (np.int32, cells), (np.int64, n), (np.int64, 1)]


@dataclass(frozen=True)
class SharedHandle:
    """What a worker needs to attach: the block's name and the lock (pickled at process start)."""

    name: str
    lock: Lock
    sensors_see_units: bool = True


class SharedWorld(Sensing):
    """The world of a scenario in shared memory (see the module doc); `WorldSim`'s interface.

    Every unit of the scenario lives here: there are no remote units to observe. Sensors and moves
    read and change it only inside `turn()`; counts may be read at any time.
    """

    def __init__(
        self, scenario: Scenario, block: shared_memory.SharedMemory, handle: SharedHandle
    ) -> None:
        scenario = with_units(scenario)
        self.grid: GridMap = scenario.grid
        self.hidden = frozenset(scenario.hidden_obstacles)
        self.sensors_see_units = handle.sensors_see_units
        self.handle = handle
        self._block = block
        self._ids = [u.id for u in scenario.units]
        self._index = {uid: i for i, uid in enumerate(self._ids)}
        n, cells = len(self._ids), self.grid.width * self.grid.height
        arrays, offset = [], 0
        for dtype, size in _layout(n, cells):
            arrays.append(np.ndarray((size,), dtype=dtype, buffer=block.buf, offset=offset))
            offset += size * np.dtype(dtype).itemsize
        pos, count, self._moves, self._prevented = arrays
        self._pos = pos.reshape(n, 2)
        self._count = count.reshape(self.grid.height, self.grid.width)

    @staticmethod
    def size(scenario: Scenario) -> int:
        """Bytes of shared memory the world of `scenario` takes."""
        scenario = with_units(scenario)
        n, cells = len(scenario.units), scenario.grid.width * scenario.grid.height
        return sum(size * np.dtype(dtype).itemsize for dtype, size in _layout(n, cells))

    @classmethod
    def create(
        cls, scenario: Scenario, lock: Lock, *, sensors_see_units: bool = True
    ) -> SharedWorld:
        """A new shared world with every unit on its start square (the creator unlinks it)."""
        block = shared_memory.SharedMemory(create=True, size=cls.size(scenario))
        world = cls(scenario, block, SharedHandle(block.name, lock, sensors_see_units))
        world._pos[:] = _NOBODY
        world._count[:] = 0
        world._moves[:] = 0
        world._prevented[:] = 0
        for unit in with_units(scenario).units:
            world.resume(unit.id, unit.start)
        return world

    @classmethod
    def attach(cls, scenario: Scenario, handle: SharedHandle) -> SharedWorld:
        """The shared world a parent process created, seen from a worker."""
        try:
            block = shared_memory.SharedMemory(name=handle.name)
        except FileNotFoundError:
            raise ConfigError(f"shared world {handle.name!r} is gone") from None
        # Attaching registers the block with the resource tracker again: harmless, as workers
        # share their creator's tracker (spawned by it), which removes the block once, at its end.
        if block.size < cls.size(scenario):
            raise ConfigError(f"shared world {handle.name!r} does not fit this scenario")
        return cls(scenario, block, handle)

    def close(self, unlink: bool = False) -> None:
        """Let go of the shared memory (the creator also removes it)."""
        # numpy views hold the buffer: drop them before closing the block.
        del self._pos, self._count, self._moves, self._prevented
        self._block.close()
        if unlink:
            with contextlib.suppress(FileNotFoundError):
                self._block.unlink()

    @contextlib.contextmanager
    def turn(self) -> Iterator[None]:
        """One unit's step, atomic across every process of the fleet."""
        with self.handle.lock:
            yield

    # ---- WorldSim's interface -------------------------------------------------------------

    @property
    def positions(self) -> Mapping[str, Cell]:
        """Every unit's square (a snapshot)."""
        return {
            uid: Cell(int(x), int(y))
            for uid, (x, y) in zip(self._ids, self._pos.tolist(), strict=True)
            if x != _NOBODY
        }

    @property
    def moves(self) -> Mapping[str, int]:
        """Moves made, by unit (a snapshot)."""
        return dict(zip(self._ids, self._moves.tolist(), strict=True))

    @property
    def prevented(self) -> int:
        """Moves refused because the square was taken or blocked, across every process."""
        return int(self._prevented[0])

    @property
    def collisions(self) -> int:
        """Always 0: moves are checked and applied under one lock, so none can collide."""
        return 0

    def position(self, unit_id: str) -> Cell:
        """Where `unit_id` is (KeyError for an unknown unit)."""
        x, y = self._pos[self._index[unit_id]].tolist()
        if x == _NOBODY:
            raise KeyError(unit_id)
        return Cell(x, y)

    def _others_on(self, cell: Cell, exclude: str | None) -> bool:
        there = int(self._count[cell.y, cell.x])
        if exclude is not None and self.position(exclude) == cell:
            there -= 1
        return there > 0

    def move(self, unit_id: str, direction: Direction) -> bool:
        """Move one square if it is free; otherwise refuse, count it as prevented, return False."""
        here = self.position(unit_id)
        target = here.step(direction)
        if self._truth(target, exclude=unit_id) != "free":
            self._prevented[0] += 1
            return False
        self._relocate(unit_id, target)
        self._moves[self._index[unit_id]] += 1
        return True

    def resume(self, unit_id: str, cell: Cell) -> None:
        """Put a unit on `cell`: its start, or where it stood before its process restarted."""
        with self.turn():
            self._relocate(unit_id, cell)

    def observe(self, unit_id: str, cell: Cell) -> None:
        """Nothing to learn from a published state: every unit's square is here already."""

    def _relocate(self, unit_id: str, cell: Cell) -> None:
        i = self._index[unit_id]
        x, y = self._pos[i].tolist()
        if x != _NOBODY:
            self._count[y, x] -= 1
        self._pos[i] = (cell.x, cell.y)
        self._count[cell.y, cell.x] += 1

    def __getstate__(self) -> Any:
        raise TypeError("pass SharedWorld.handle to another process, not the world")
