"""`WebotsWorld`: one grid unit in Webots, as the world its shell senses and moves in.

The shell of a simulated unit (`UnitShell`) asks its world for the unit's four sensor readings
and to move it one square (`robots.world.SimulatedWorld`); here Webots answers. Readings are the unit's
four DistanceSensors (`geometry.reading`), a move sets the unit's translation through the
Supervisor and advances the simulation one basic time step so that the move takes effect and the
sensors measure from the new square, and the LEDs show the unit's intended move whenever a
step of the unit begins and ends.

Every call into Webots goes through `call`, which runs it where the controller API may be used
(the one Webots thread, `robots.webots.clock`; inline in tests). The robot is passed in, so
tests give a test double of Webots' `controller.Supervisor`.

Once a step has returned -1 (Webots reloads or quits) no call reaches Webots again: the
controller library ends the process at the next step or field read (`exit()`), and the unit
would leave without its `offline` goodbye. From then on the LEDs stay as they are, the sensors
read as not measured (a unit: never free, never reported) and every move is refused, while the
shell stops and says goodbye.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator, Mapping
from types import MappingProxyType
from typing import Protocol, TypeVar, cast

from gridfleet.errors import ConfigError
from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol.messages import Leds, SensorReading
from gridfleet.robots.webots.api import LED, DistanceSensor, Field, Node, Supervisor
from gridfleet.robots.webots.geometry import LED_NAMES, SENSOR_NAMES, metres, reading, square_at
from gridfleet.robots.world import Collision

T = TypeVar("T")
UNIT_PROTO = "GridUnit"
OBSTACLE_PROTO = "GridObstacle"


class Call(Protocol):
    """Runs `work` where Webots' controller API may be called, and returns its result."""

    def __call__(self, work: Callable[[], T]) -> T: ...


def inline(work: Callable[[], T]) -> T:
    """Run `work` here and now: for a robot that any thread may call (tests' doubles)."""
    return work()


def _dark() -> Leds:
    return Leds(N=False, E=False, S=False, W=False)


class WebotsWorld:
    """The world of one Webots grid unit: its sensors, its translation and its LEDs.

    It counts what `WorldSim` counts, for this unit: its moves, the moves it refused because a
    sensor saw the square taken (`prevented`), and collisions it finds in this Webots world after
    a move: onto the square of another grid unit run in this world (vertex), of an obstacle
    (obstacle), or off the map (wall). Units run elsewhere are here as mirrors at most, which
    are not counted; a shell that watches other units' states tells it through `observe`.
    """

    def __init__(
        self,
        robot: Supervisor,
        unit_id: str,
        grid: GridMap,
        *,
        leds: Callable[[], Leds] = _dark,
        call: Call = inline,
    ) -> None:
        self.robot = robot
        self.unit_id = unit_id
        self.grid = grid
        self._intended = leds  # what the LEDs must show now (the unit's logic)
        self._call = call
        self._moves = {unit_id: 0}
        self.prevented = 0
        self.log: list[Collision] = []
        self.ended = False  # Webots ends this controller (a step returned -1)
        self._seen: dict[str, Cell] = {}
        self._shown: dict[Direction, bool] = {}
        self._call(self._open)

    # ---- on the Webots side (run through `call`) ----------------------------------------------

    def _open(self) -> None:
        """Find the devices and the translation, enable the sensors, read the scene, step once."""
        robot = self.robot
        self.timestep_ms = int(robot.getBasicTimeStep())
        own = robot.getSelf()
        self._translation = _field(own, "translation", self.unit_id)
        self._z = float(self._translation.getSFVec3f()[2])
        self._sensors = {d: cast(DistanceSensor, self._device(n)) for d, n in SENSOR_NAMES.items()}
        self._leds = {d: cast(LED, self._device(n)) for d, n in LED_NAMES.items()}
        for sensor in self._sensors.values():
            sensor.enable(self.timestep_ms)
        self._others, self._blocked = self._scene()
        self._here = self._read_square()
        self.advance()  # sensors measure during a step: none has a value before the first

    def _device(self, name: str) -> object:
        device = self.robot.getDevice(name)
        if device is None:
            raise ConfigError(f"grid unit {self.unit_id!r}: no device {name!r} (not a GridUnit?)")
        return device

    def _scene(self) -> tuple[list[Node], set[Cell]]:
        """The other grid units run in this Webots world, and the squares of its obstacles.

        Mirrors of units run elsewhere are left out: each follows its unit's state, a little
        after the unit has moved, and would show collisions that never happened.
        """
        children = _field(self.robot.getRoot(), "children", "the scene")
        others: list[Node] = []
        blocked: set[Cell] = set()
        for i in range(children.getCount()):
            node = children.getMFNode(i)
            kind = node.getTypeName()
            if kind == UNIT_PROTO:
                mirror = _field(node, "mirror", kind).getSFBool()
                if not mirror and _field(node, "name", kind).getSFString() != self.unit_id:
                    others.append(node)
            elif kind == OBSTACLE_PROTO:
                blocked.add(_square_of(node))
        return others, blocked

    def _read_square(self) -> Cell:
        x, y, _ = self._translation.getSFVec3f()
        return square_at(x, y)

    def advance(self, leds: Leds | None = None) -> bool:
        """Show `leds` (default: the intention now) and let the simulation run one basic step.

        False once Webots ends the controller (reload, quit): then the unit must say goodbye.
        """
        if self.ended:
            return False
        self._show(self._intended() if leds is None else leds)
        if self.robot.step(self.timestep_ms) == -1:
            self.ended = True
        return not self.ended

    def _show(self, leds: Leds) -> None:
        if self.ended:
            return
        for d, led in self._leds.items():
            on = bool(getattr(leds, d.value))
            if self._shown.get(d) != on:
                led.set(1 if on else 0)
                self._shown[d] = on

    def _sense(self) -> dict[Direction, SensorReading]:
        here = self._here
        return {
            d: reading(
                # after -1 a read would end the process; not measured reads as a unit
                math.nan if self.ended else sensor.getValue(),
                not self.grid.in_bounds(here.step(d)),
            )
            for d, sensor in self._sensors.items()
        }

    def _move(self, direction: Direction) -> bool:
        if self.ended:
            return False
        if self._sense()[direction] != "free":
            self.prevented += 1
            return False
        target = self._here.step(direction)
        self._place(target)
        if self._here != target:  # Webots did not take the translation: the unit did not move
            return False
        self._moves[self.unit_id] += 1
        self._check()
        return True

    def _place(self, cell: Cell) -> None:
        """Set the translation to `cell` and step, so that the move is made and sensed."""
        if self.ended:
            return
        x, y = metres(cell)
        self._translation.setSFVec3f([x, y, self._z])
        if self.advance():  # a step that ended Webots made no move, and nothing may be read now
            self._here = self._read_square()

    def _check(self) -> None:
        """Count what the unit now shares its square with in this Webots world."""
        here = self._here
        if not self.grid.in_bounds(here):
            self.log.append(Collision("wall", (self.unit_id,), here))
        elif here in self._blocked:
            self.log.append(Collision("obstacle", (self.unit_id,), here))
        for node in self._others:
            if _square_of(node) == here:
                other = _field(node, "name", UNIT_PROTO).getSFString()
                self.log.append(Collision("vertex", tuple(sorted((self.unit_id, other))), here))

    # ---- the world the shell sees (`robots.world.SimulatedWorld`) -----------------------------

    @property
    def positions(self) -> Mapping[str, Cell]:
        """This unit's square, and the squares other units said they stand on."""
        return MappingProxyType({**self._seen, self.unit_id: self._here})

    @property
    def moves(self) -> Mapping[str, int]:
        """Moves made, by unit (only this one)."""
        return MappingProxyType(self._moves)

    @property
    def collisions(self) -> int:
        """Collisions this unit's moves ran into (see the class)."""
        return len(self.log)

    @contextlib.contextmanager
    def turn(self) -> Iterator[None]:
        """One step of the unit: its LEDs show its intention as the step begins and as it ends.

        A unit moves only in the direction its LEDs already showed (`UnitLogic.begin_step`), so
        lighting them here, before the step, puts that rule into Webots too.
        """
        before = self._intended()
        self._call(lambda: self._show(before))
        yield
        after = self._intended()
        self._call(lambda: self._show(after))

    def position(self, unit_id: str) -> Cell:
        """Where `unit_id` is: this unit from Webots, others as last seen (KeyError if never)."""
        return self._here if unit_id == self.unit_id else self._seen[unit_id]

    def sense(self, unit_id: str) -> dict[Direction, SensorReading]:
        """The four distance sensors of this unit (KeyError for any other unit)."""
        self._own(unit_id)
        return self._call(self._sense)

    def move(self, unit_id: str, direction: Direction) -> bool:
        """Move one square if the sensor that way sees it free; else count it as prevented."""
        self._own(unit_id)
        return self._call(lambda: self._move(direction))

    def resume(self, unit_id: str, cell: Cell) -> None:
        """Put this unit on `cell` at once: where it stood before a restart, where a mirror's is."""
        self._own(unit_id)
        self._call(lambda: self._place(cell))

    def observe(self, unit_id: str, cell: Cell) -> None:
        """Another unit said where it stands (this unit's own square comes from Webots)."""
        if unit_id != self.unit_id:
            self._seen[unit_id] = cell

    def _own(self, unit_id: str) -> None:
        if unit_id != self.unit_id:
            raise KeyError(unit_id)


def _field(node: Node, name: str, owner: str) -> Field:
    found = node.getField(name)
    if found is None:
        raise ConfigError(f"{owner}: no field {name!r} in Webots")
    return found


def _square_of(node: Node) -> Cell:
    x, y, _ = _field(node, "translation", node.getTypeName()).getSFVec3f()
    return square_at(x, y)
