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

It is as strict as Webots' controller library where gridfleet could trip: once `step` has
returned -1 the library ends the controller's process (`exit()`) at its next call, so every
call after that (a step, a field, a device, the robot's own getters) raises `WebotsExited` and
is listed in `calls_after_end`, since the code under test may catch the error. `getSFBool` gives
an int (0 or 1), as the C function behind it does, and `setSFVec3f` ignores anything but a list
of three numbers, with Webots' message on stderr.
"""

from __future__ import annotations

import math
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.robots.world import WorldSim

from support.paths import REPO
from support.vrml import Is, Node, Scalar, Value, read_proto, read_world
from support.webots_rays import Ray, hit, numbers, to_wall, unit_geometry

PROTOS = REPO / "robots" / "webots" / "protos"
SQUARE_M = 0.1  # the course's square: the only number this double shares with the product


class SharedTruth(WorldSim):
    """A WorldSim that headless units and Webots doubles on other threads share, under a lock."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.lock = threading.RLock()

    def turn(self) -> threading.RLock:  # type: ignore[override]
        """One unit's step: no one else reads or moves meanwhile."""
        return self.lock


class WebotsExited(AssertionError):
    """A call into Webots after `step` returned -1: the real library ends the process there."""


class FieldDouble:
    """A field as one robot's controller reaches it: a world file's value, or a live translation."""

    def __init__(
        self,
        robot: SupervisorDouble,
        value: Value | list[NodeDouble],
        live: SupervisorDouble | None = None,
        kind: str = "",
    ) -> None:
        self.robot = robot  # the controller that holds this field (its calls are checked)
        self.value = value
        self.kind = kind  # its PROTO type when it matters (an MFVec2f counts pairs)
        self.live = live  # set for a grid unit's translation: read from and set in the truth

    def _items(self) -> list[Scalar | Node | NodeDouble]:
        return list(self.value) if isinstance(self.value, tuple | list) else []

    def getSFVec3f(self) -> list[float]:
        self.robot.api("Field.getSFVec3f")
        if self.live is not None:
            return self.live.translation()
        return numbers(self.value)

    def setSFVec3f(self, value: list[float]) -> None:
        self.robot.api("Field.setSFVec3f")
        if self.live is None:
            raise PermissionError("only a grid unit's translation is set in these tests")
        if not isinstance(value, list) or len(value) != 3:
            print("Error: new field value has wrong type or length.", file=sys.stderr)
            return
        self.live.pending = list(value)

    def getSFFloat(self) -> float:
        self.robot.api("Field.getSFFloat")
        (number,) = numbers(self.value)
        return number

    def getSFString(self) -> str:
        self.robot.api("Field.getSFString")
        (text,) = self._items()
        assert isinstance(text, str), self.value
        return text

    def getSFColor(self) -> list[float]:
        self.robot.api("Field.getSFColor")
        return numbers(self.value)

    def getSFBool(self) -> int:
        self.robot.api("Field.getSFBool")
        (flag,) = self._items()
        assert isinstance(flag, bool), self.value
        return 1 if flag else 0

    def getCount(self) -> int:
        self.robot.api("Field.getCount")
        if self.kind == "MFVec2f":  # the reader gives its numbers in one flat list
            return len(numbers(self.value)) // 2
        return len(self._items())

    def getMFVec2f(self, index: int) -> list[float]:
        self.robot.api("Field.getMFVec2f")
        assert self.kind == "MFVec2f", self.kind
        return numbers(self.value)[2 * index : 2 * index + 2]

    def getMFString(self, index: int) -> str:
        self.robot.api("Field.getMFString")
        text = self._items()[index]
        assert isinstance(text, str), self.value
        return text

    def getMFNode(self, index: int) -> NodeDouble:
        self.robot.api("Field.getMFNode")
        node = self._items()[index]
        assert isinstance(node, NodeDouble)
        return node


class NodeDouble:
    """A node of the scene as one robot's controller sees it: its type and (PROTO) fields."""

    def __init__(self, robot: SupervisorDouble, kind: str, fields: dict[str, FieldDouble]) -> None:
        self.robot = robot
        self.kind = kind
        self.fields = fields

    def getField(self, name: str) -> FieldDouble | None:
        self.robot.api("Node.getField")
        return self.fields.get(name)

    def getTypeName(self) -> str:
        self.robot.api("Node.getTypeName")
        return self.kind


class DistanceSensorDouble:
    """A DistanceSensor: NaN until enabled and stepped once, then measured from the truth."""

    def __init__(self, robot: SupervisorDouble, ray: Ray) -> None:
        self.robot = robot
        self.ray = ray
        self.enabled_at: int | None = None

    def enable(self, sampling_period: int) -> None:
        self.robot.api("DistanceSensor.enable")
        assert sampling_period > 0
        self.enabled_at = self.robot.time_ms

    def getValue(self) -> float:
        self.robot.api("DistanceSensor.getValue")
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
        self.robot.api("LED.set")
        self.value = value
        self.history.append((self.robot.time_ms, value))

    def get(self) -> int:
        self.robot.api("LED.get")
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
            name: FieldDouble(self, scene.field_value(node, name), kind=kind)
            for name, (kind, _) in scene.unit_proto.interface.items()
        }
        fields["translation"] = FieldDouble(self, (), live=self)
        self.node = NodeDouble(self, "GridUnit", fields)
        self.sensors = {r.name: DistanceSensorDouble(self, r) for r in scene.rays}
        self.leds = {f"led {d.value}": LedDouble(self) for d in Direction}
        self.exited = False  # a step returned -1: the library ends the process at the next call
        self.calls_after_end: list[str] = []
        self._root: NodeDouble | None = None

    def api(self, call: str) -> None:
        """Every call into this controller's API comes here first: none may follow a -1."""
        if self.exited:
            self.calls_after_end.append(call)
            raise WebotsExited(f"{self.unit_id}: {call} after step() returned -1")

    def seen_by(self, robot: SupervisorDouble) -> NodeDouble:
        """This unit's node as another robot's controller finds it in the scene tree."""
        fields = {
            n: FieldDouble(robot, f.value, f.live, f.kind) for n, f in self.node.fields.items()
        }
        return NodeDouble(robot, "GridUnit", fields)

    # -- the API ---------------------------------------------------------------------------------

    def getName(self) -> str:
        self.api("Robot.getName")
        return self.unit_id

    def getBasicTimeStep(self) -> float:
        self.api("Robot.getBasicTimeStep")
        return float(self.scene.basic_time_step)

    def getSelf(self) -> NodeDouble:
        self.api("Supervisor.getSelf")
        return self.node

    def getRoot(self) -> NodeDouble:
        self.api("Supervisor.getRoot")
        if self._root is None:
            self._root = self.scene.root_for(self)
        return self._root

    def getDevice(self, name: str) -> DistanceSensorDouble | LedDouble | None:
        self.api("Robot.getDevice")
        return self.sensors.get(name) or self.leds.get(name)

    def step(self, duration_ms: int) -> int:
        self.api("Robot.step")
        assert duration_ms > 0 and duration_ms % self.scene.basic_time_step == 0, duration_ms
        if self.scene.end_at_step is not None and self.steps + 1 >= self.scene.end_at_step:
            self.scene.ended.set()
        if self.scene.end_on_move and self.pending is not None:
            self.scene.ended.set()
        if self.scene.ended.is_set():
            self.exited = True
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
        self.end_on_move = False  # True: Webots ends during a step that would apply a translation
        self.jumps: list[tuple[str, Cell, Cell]] = []  # translations more than one square
        self.robots = {
            r.unit_id: r
            for r in (SupervisorDouble(self, n) for n in self.world.of_type("GridUnit"))
        }

    def field_value(self, node: Node, name: str) -> Value:
        """A field of a PROTO instance in the file: its own value, else the PROTO's default."""
        if name in node.fields:
            return node.fields[name]
        proto = {"GridUnit": self.unit_proto, "GridObstacle": self.obstacle_proto}[node.type]
        default = proto.interface[name][1]
        assert not isinstance(default, Is)
        return default

    def root_for(self, robot: SupervisorDouble) -> NodeDouble:
        """The scene tree's root as `robot`'s controller gets it (`Supervisor.getRoot`)."""
        return NodeDouble(
            robot, "Group", {"children": FieldDouble(robot, list(self._children(robot)))}
        )

    def _children(self, robot: SupervisorDouble) -> Iterator[NodeDouble]:
        for node in self.world.nodes:
            if node.type == "GridUnit":
                unit = self.robots[str(self.field_value(node, "name")[0])]  # type: ignore[index]
                yield robot.node if unit is robot else unit.seen_by(robot)
            elif node.type == "GridObstacle":
                fields = {
                    n: FieldDouble(robot, self.field_value(node, n))
                    for n in ("translation", "name")
                }
                yield NodeDouble(robot, "GridObstacle", fields)
            else:
                yield NodeDouble(robot, node.type, {})

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
