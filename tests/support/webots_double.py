"""A test double of Webots' controller API: `controller.Supervisor` and the nodes, fields and
devices it hands out. Never importable as `controller`: tests pass it to the code under test,
which takes its robot injected.

A `SceneDouble` is one Webots world as a generated `.wbt` file describes it. Its grid units stand
in a ground truth shared with headless units (`SharedTruth`, a `robots.world.WorldSim`, so
collisions are counted); its obstacles are the file's `GridObstacle`s. Each unit's
`SupervisorDouble` reads its PROTO fields from the file (defaults from GridUnit.proto), moves by
translation (a set takes effect at the next `step`, as in Webots), and measures its distance
sensors by casting each sensor's ray, as placed in GridUnit.proto, against the other units'
boxes, the obstacles' boxes and the arena's walls.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.robots.world import WorldSim

from support.vrml import Is, Node, Scalar, Value, read_proto, read_world
from support.webots_rays import Ray, hit, numbers, to_wall, unit_geometry

PROTOS = Path(__file__).resolve().parents[2] / "robots" / "webots" / "protos"
SQUARE_M = 0.1  # the course's square: the only number this double shares with the product


class SharedTruth(WorldSim):
    """A WorldSim that headless units and Webots doubles on other threads share, under a lock."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.lock = threading.RLock()

    def turn(self) -> threading.RLock:  # type: ignore[override]
        """One unit's step: no one else reads or moves meanwhile."""
        return self.lock


class FieldDouble:
    """A field of a node: a value from the world file, or the unit's live translation."""

    def __init__(
        self, value: Value | list[NodeDouble], owner: SupervisorDouble | None = None
    ) -> None:
        self.value = value
        self.owner = owner  # set for a grid unit's translation: read from and set in the truth

    def _items(self) -> list[Scalar | Node | NodeDouble]:
        return list(self.value) if isinstance(self.value, tuple | list) else []

    def getSFVec3f(self) -> list[float]:
        if self.owner is not None:
            return self.owner.translation()
        return numbers(self.value)

    def setSFVec3f(self, value: list[float]) -> None:
        if self.owner is None:
            raise PermissionError("only a grid unit's translation is set in these tests")
        assert len(value) == 3, value
        self.owner.pending = list(value)

    def getSFFloat(self) -> float:
        (number,) = numbers(self.value)
        return number

    def getSFString(self) -> str:
        (text,) = self._items()
        assert isinstance(text, str), self.value
        return text

    def getSFColor(self) -> list[float]:
        return numbers(self.value)

    def getSFBool(self) -> bool:
        (flag,) = self._items()
        assert isinstance(flag, bool), self.value
        return flag

    def getCount(self) -> int:
        return len(self._items())

    def getMFString(self, index: int) -> str:
        text = self._items()[index]
        assert isinstance(text, str), self.value
        return text

    def getMFNode(self, index: int) -> NodeDouble:
        node = self._items()[index]
        assert isinstance(node, NodeDouble)
        return node


class NodeDouble:
    """A node of the scene: its type and fields (a PROTO instance answers with its own)."""

    def __init__(self, kind: str, fields: dict[str, FieldDouble]) -> None:
        self.kind = kind
        self.fields = fields

    def getField(self, name: str) -> FieldDouble | None:
        return self.fields.get(name)

    def getTypeName(self) -> str:
        return self.kind


class DistanceSensorDouble:
    """A DistanceSensor: NaN until enabled and stepped once, then measured from the truth."""

    def __init__(self, robot: SupervisorDouble, ray: Ray) -> None:
        self.robot = robot
        self.ray = ray
        self.enabled_at: int | None = None

    def enable(self, sampling_period: int) -> None:
        assert sampling_period > 0
        self.enabled_at = self.robot.time_ms

    def getValue(self) -> float:
        if self.enabled_at is None or self.robot.time_ms <= self.enabled_at:
            return math.nan
        return self.robot.scene.measure(self.robot, self.ray)


class LedDouble:
    """An LED: the value last set, and every change with the simulation time it came at."""

    def __init__(self, robot: SupervisorDouble) -> None:
        self.robot = robot
        self.value = 0
        self.history: list[tuple[int, int]] = []

    def set(self, value: int) -> None:
        self.value = value
        self.history.append((self.robot.time_ms, value))

    def get(self) -> int:
        return self.value


@dataclass(frozen=True)
class Applied:
    """A translation a step made: where from and to, and which LEDs were lit as it happened."""

    time_ms: int
    start: Cell
    end: Cell
    lit: frozenset[str]


class SupervisorDouble:
    """`controller.Supervisor` of one grid unit of the scene."""

    def __init__(self, scene: SceneDouble, node: Node) -> None:
        self.scene = scene
        self.unit_id = str(scene.field_value(node, "name")[0])  # type: ignore[index]
        self.time_ms = 0
        self.steps = 0
        self.pending: list[float] | None = None
        self.applied: list[Applied] = []
        self.z = numbers(scene.field_value(node, "translation"))[2]
        fields = {
            name: FieldDouble(scene.field_value(node, name)) for name in scene.unit_proto.interface
        }
        fields["translation"] = FieldDouble((), owner=self)
        self.node = NodeDouble("GridUnit", fields)
        self.sensors = {r.name: DistanceSensorDouble(self, r) for r in scene.rays}
        self.leds = {f"led {d.value}": LedDouble(self) for d in Direction}

    # -- the API ---------------------------------------------------------------------------------

    def getName(self) -> str:
        return self.unit_id

    def getBasicTimeStep(self) -> float:
        return float(self.scene.basic_time_step)

    def getSelf(self) -> NodeDouble:
        return self.node

    def getRoot(self) -> NodeDouble:
        return self.scene.root

    def getDevice(self, name: str) -> DistanceSensorDouble | LedDouble | None:
        return self.sensors.get(name) or self.leds.get(name)

    def step(self, duration_ms: int) -> int:
        assert duration_ms > 0 and duration_ms % self.scene.basic_time_step == 0, duration_ms
        if self.scene.end_at_step is not None and self.steps + 1 >= self.scene.end_at_step:
            self.scene.ended.set()
        if self.scene.ended.is_set():
            return -1
        self.time_ms += duration_ms
        self.steps += 1
        if self.pending is not None:
            self._apply(self.pending)
            self.pending = None
        return 0

    # -- the truth -------------------------------------------------------------------------------

    def square(self) -> Cell:
        with self.scene.truth.lock:
            return self.scene.truth.position(self.unit_id)

    def translation(self) -> list[float]:
        cell = self.square()
        return [cell.x * SQUARE_M, -cell.y * SQUARE_M, self.z]

    def lit(self) -> frozenset[str]:
        """The LEDs on now, by their direction."""
        return frozenset(name.split()[1] for name, led in self.leds.items() if led.value)

    def _apply(self, target: list[float]) -> None:
        end = Cell(round(target[0] / SQUARE_M), round(-target[1] / SQUARE_M))
        truth = self.scene.truth
        with truth.lock:
            start = truth.position(self.unit_id)
            direction = Direction.between(start, end)
            if direction is not None:
                truth.force_move({self.unit_id: direction})
            elif end != start:
                self.scene.jumps.append((self.unit_id, start, end))
                truth.resume(self.unit_id, end)
        self.applied.append(Applied(self.time_ms, start, end, self.lit()))


class SceneDouble:
    """One Webots world (a generated .wbt file) whose grid units stand in a shared truth."""

    def __init__(self, world_text: str, truth: SharedTruth) -> None:
        self.world = read_world(world_text)
        self.truth = truth
        self.unit_proto = read_proto((PROTOS / "GridUnit.proto").read_text(encoding="utf-8"))
        self.obstacle_proto = read_proto(
            (PROTOS / "GridObstacle.proto").read_text(encoding="utf-8")
        )
        self.unit_side, self.rays = unit_geometry(self.unit_proto)
        (info,) = self.world.of_type("WorldInfo")
        self.basic_time_step = int(numbers(info.fields["basicTimeStep"])[0])
        (arena,) = self.world.of_type("RectangleArena")
        cx, cy, _ = numbers(arena.fields["translation"])
        sx, sy = numbers(arena.fields["floorSize"])
        self.floor = (cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2)
        self.obstacles: list[tuple[float, float, float, float]] = []
        for node in self.world.of_type("GridObstacle"):
            x, y, _ = numbers(self.field_value(node, "translation"))
            w, d, _ = numbers(self.field_value(node, "size"))
            self.obstacles.append((x - w / 2, y - d / 2, x + w / 2, y + d / 2))
        self.ended = threading.Event()  # set: every robot's next step returns -1 (Webots quits)
        self.end_at_step: int | None = None  # a robot's step with this number ends Webots
        self.jumps: list[tuple[str, Cell, Cell]] = []  # translations more than one square
        self.robots = {
            r.unit_id: r
            for r in (SupervisorDouble(self, n) for n in self.world.of_type("GridUnit"))
        }
        self.root = NodeDouble("Group", {"children": FieldDouble(list(self._children()))})

    def field_value(self, node: Node, name: str) -> Value:
        """A field of a PROTO instance in the file: its own value, else the PROTO's default."""
        if name in node.fields:
            return node.fields[name]
        proto = {"GridUnit": self.unit_proto, "GridObstacle": self.obstacle_proto}[node.type]
        default = proto.interface[name][1]
        assert not isinstance(default, Is)
        return default

    def _children(self) -> Iterator[NodeDouble]:
        for node in self.world.nodes:
            if node.type == "GridUnit":
                yield self.robots[str(self.field_value(node, "name")[0])].node  # type: ignore[index]
            elif node.type == "GridObstacle":
                fields = {
                    n: FieldDouble(self.field_value(node, n)) for n in ("translation", "name")
                }
                yield NodeDouble("GridObstacle", fields)
            else:
                yield NodeDouble(node.type, {})

    def robot(self, unit_id: str) -> SupervisorDouble:
        """The Supervisor of grid unit `unit_id`."""
        return self.robots[unit_id]

    def measure(self, robot: SupervisorDouble, ray: Ray) -> float:
        """A sensor's value: the nearest face its ray meets within range, or the maximum."""
        here = robot.square()
        px, py = here.x * SQUARE_M + ray.x, -here.y * SQUARE_M + ray.y
        dx, dy = math.cos(ray.heading), math.sin(ray.heading)
        half = self.unit_side / 2
        with self.truth.lock:
            others = [c for u, c in self.truth.positions.items() if u != robot.unit_id]
        boxes = [
            (
                c.x * SQUARE_M - half,
                -c.y * SQUARE_M - half,
                c.x * SQUARE_M + half,
                -c.y * SQUARE_M + half,
            )
            for c in others
        ]
        boxes += self.obstacles
        nearest = min((hit(px, py, dx, dy, b) for b in boxes), default=math.inf)
        nearest = min(nearest, to_wall(self.floor, px, py, dx, dy))
        return ray.value(nearest)


def grid_of(world_text: str) -> GridMap:
    """The static map the world's first grid unit carries in its `map` field."""
    unit = read_world(world_text).of_type("GridUnit")[0]
    rows = unit.fields["map"]
    assert isinstance(rows, list)
    return GridMap.from_rows([str(r) for r in rows])
