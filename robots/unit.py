"""The pure core of one unit: orders, emergency stop, holding, LEDs, route following, own planning.

No sockets and no clock: the I/O shell feeds it sensor readings, orders, the emergency stop and
how long ago the last order came, and performs the move it asks for in the world.
"""

from __future__ import annotations

import random
import zlib
from dataclasses import dataclass
from typing import Literal

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.paths import UNREACHABLE, DistanceFieldCache, distance_field, route
from gridfleet.protocol.constants import HOLD_AFTER_STEPS, MAX_TEXT, MIN_TIMEOUT_S
from gridfleet.protocol.messages import (
    Action,
    Header,
    Leds,
    Order,
    Sensors,
    UnitError,
    UnitState,
    UnitStatus,
)
from robots.world import Reading, WorldSim

Mode = Literal["coordinated", "standalone"]
OrderOutcome = Literal["accepted", "stale", "refused", "ignored"]
MAX_ERRORS = 16
AVOID_STEPS = 4  # how long a standalone unit keeps out of a square where a unit blocked it
PAUSE_STEPS = 3  # how long a unit that stepped aside stays there to let the other pass
QUIET_STEPS = 3  # steps without the other unit in front that end giving way
DETOUR_MAX = 4  # extra steps a unit accepts to route around another rather than give way

_NO_SENSORS: dict[Direction, Reading] = dict.fromkeys(Direction, "free")
_THING = {"wall": "a wall", "obstacle": "an obstacle", "unit": "another unit"}


def sq(cell: Cell) -> str:
    """A square as protocol.md writes it: [x, y]."""
    return f"[{cell.x}, {cell.y}]"


@dataclass(frozen=True)
class Intent:
    """What the unit wants to do next: a move (or None) with the status and reason if it cannot."""

    move: Direction | None
    status: UnitStatus
    reason: str | None = None


class UnitLogic:
    """One unit's decisions; every input is a method call, every output a field or return value."""

    def __init__(
        self,
        unit_id: str,
        grid: GridMap,
        start: Cell,
        capacity_kg: float,
        step_s: float,
        mode: Mode = "coordinated",
        goal: Cell | None = None,
    ) -> None:
        self.unit_id = unit_id
        self.grid = grid
        self.position = start
        self.capacity_kg = capacity_kg
        self.step_s = step_s
        self.mode: Mode = mode
        self.goal = goal
        self.step = 0
        self.status: UnitStatus = "idle"
        self.wait_reason: str | None = None
        self.direction: Direction | None = None  # intended move of the coming step (the LEDs)
        self.sensors: dict[Direction, Reading] = dict(_NO_SENSORS)
        self.estop = False
        self.estop_known = True  # the shell sets False until it has read the retained value
        self.connected = True
        self.coordinator_step_s = step_s
        self.order_id: str | None = None
        self.order_update_id = 0
        self.released: list[Cell] = []
        self.action: Action | None = None
        self._acted: tuple[str | None, int, str] | None = None
        self.job_id: str | None = None
        self.load_kg = 0.0
        self.known_obstacles: set[Cell] = set()
        self.new_obstacles: list[Cell] = []
        self.errors: list[UnitError] = []
        self._fields_cache: DistanceFieldCache | None = None  # built on first standalone plan
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

    # ---- inputs -------------------------------------------------------------------------------

    @property
    def hold_timeout_s(self) -> float:
        """How long a coordinated unit waits for an order before it holds still (protocol §8)."""
        return max(MIN_TIMEOUT_S, HOLD_AFTER_STEPS * max(self.step_s, self.coordinator_step_s))

    def error(self, code: str, message: str) -> None:
        """Report a problem in the next state's `errors`."""
        self.errors.append(UnitError(code=code, message=message[:MAX_TEXT]))
        del self.errors[:-MAX_ERRORS]

    def on_order(self, order: Order) -> OrderOutcome:
        """Take an order: stale ones change nothing, bad ones are refused with a `bad_order` error."""
        if self.mode != "coordinated":
            return "ignored"
        if order.order_id == self.order_id and order.update_id <= self.order_update_id:
            return "stale"
        released = [Cell(*c) for c in order.released]
        if self.position in released:
            # The unit already drove the leading squares (the order was planned from an older
            # state): it follows on from where it stands.
            released = released[released.index(self.position) + 1 :]
        problem = self._check_route(released)
        if problem is None and order.action is not None:
            square = Cell(*order.action.square)
            if not self.grid.is_free(square):
                problem = f"action square {sq(square)} is off the map or on a wall"
        if problem is not None:
            self.error("bad_order", f"order {order.order_id!r} update {order.update_id}: {problem}")
            return "refused"
        self.order_id = order.order_id
        self.order_update_id = order.update_id
        self.released = released
        if self.action != order.action:
            self.action = order.action
        return "accepted"

    def _check_route(self, released: list[Cell]) -> str | None:
        here = self.position
        for i, cell in enumerate(released):
            if not self.grid.in_bounds(cell):
                return f"released square {sq(cell)} is off the {self.grid.width}x{self.grid.height} map"
            if not self.grid.is_free(cell):
                return f"released square {sq(cell)} is a wall"
            if here.manhattan(cell) != 1:
                before = "the unit's square" if i == 0 else "the square before it"
                return f"released square {sq(cell)} is not adjacent to {before} {sq(here)}"
            here = cell
        return None

    def on_goal(self, target: Cell | None) -> bool:
        """Set or clear the standalone goal; a goal off the map or on a wall is refused."""
        if self.mode != "standalone":
            return False
        if target is not None and (not self.grid.is_free(target) or target in self.known_obstacles):
            self.error("bad_goal", f"goal {sq(target)} is off the map, on a wall or an obstacle")
            return False
        self.goal = target
        self._avoid.clear()
        self._waited = 0
        self._yield_from = None
        self._pause_until = 0
        self._gave_way = False
        self._best = UNREACHABLE
        return True

    def on_estop(self, engaged: bool) -> None:
        """The latched emergency stop; engaging drops every released square (orders resume it)."""
        self.estop_known = True
        if engaged and not self.estop:
            self.released = []
        self.estop = engaged

    def sense(self, readings: dict[Direction, Reading]) -> None:
        """Take fresh sensor readings; an obstacle seen for the first time is reported once."""
        self.sensors = dict(readings)
        for d, reading in readings.items():
            cell = self.position.step(d)
            # Fixed obstacles are on everyone's map already: only report what the map lacks.
            if (
                reading == "obstacle"
                and self.grid.is_free(cell)
                and cell not in self.known_obstacles
            ):
                self.known_obstacles.add(cell)
                self.new_obstacles.append(cell)
                self._fields_cache = None  # the known map changed: plan on the new one

    # ---- the step -----------------------------------------------------------------------------

    def begin_step(
        self, readings: dict[Direction, Reading], since_order_s: float | None
    ) -> Direction | None:
        """Start a step: the move to make now, or None to stay (status says why)."""
        self.step += 1
        self.sense(readings)
        intent = self._intent(since_order_s, waiting_counts=True)
        self.status, self.wait_reason = intent.status, intent.reason
        if intent.move is not None and intent.move != self.direction:
            # The LEDs must show a move before it is made: show it now, move next step.
            self.direction = intent.move
            self.status, self.wait_reason = "waiting", "showing the new direction before moving"
            return None
        if intent.move is None:
            self.direction = None
        return intent.move

    def end_step(
        self,
        moved: Direction | None,
        readings: dict[Direction, Reading],
        since_order_s: float | None,
    ) -> None:
        """Finish a step: `moved` is the move the world performed (None if none or refused)."""
        if moved is not None:
            self.position = self.position.step(moved)
            self.status, self.wait_reason = "moving", None
            if self.released and self.released[0] == self.position:
                self.released.pop(0)
            self._waited = 0
            if self._yield_from is not None and moved not in (
                self._yield_from,
                self._yield_from.opposite,
            ):
                # Stepped aside: stay a few steps so the other unit can pass.
                self._yield_from = None
                self._pause_until = self.step + PAUSE_STEPS
        elif self.direction is not None and self.status == "moving":
            self.status = "waiting"
            self.wait_reason = (
                f"the world refused the move to {sq(self.position.step(self.direction))}"
            )
        self.sense(readings)
        self._act()
        self.refresh(since_order_s)

    def refresh(self, since_order_s: float | None) -> None:
        """Recompute the intended move (the LEDs) after anything changed between steps."""
        intent = self._intent(since_order_s, waiting_counts=False)
        self.direction = intent.move
        if intent.status in ("stopped", "holding"):
            self.status, self.wait_reason = intent.status, intent.reason
        elif self.status in ("stopped", "holding"):
            # Resuming: it has not moved yet, so it is not `moving` before its next step.
            if intent.status == "idle":
                self.status, self.wait_reason = "idle", None
            else:
                self.status = "waiting"
                self.wait_reason = intent.reason or "resuming: moves at the next step"
        elif self.status == "idle" and intent.move is not None:
            # A new order between steps: the LEDs show the move now, so the state must not say idle.
            self.status, self.wait_reason = "waiting", "moves at the next step"
        elif self.status == "waiting" and intent.status == "idle":
            self.status, self.wait_reason = "idle", None  # what it waited for went away

    def _intent(self, since_order_s: float | None, waiting_counts: bool) -> Intent:
        if self.estop:
            return Intent(None, "stopped", "emergency stop engaged")
        if not self.estop_known:
            return Intent(None, "holding", "waiting to read the emergency stop")
        if not self.connected:
            return Intent(None, "holding", "lost the broker; reconnecting")
        if self.mode == "coordinated":
            if since_order_s is not None and since_order_s > self.hold_timeout_s:
                self.released = []
                return Intent(
                    None, "holding", f"no order from the coordinator for {since_order_s:.1f} s"
                )
            self._act()
            return self._follow_order()
        return self._follow_goal(waiting_counts)

    def _follow_order(self) -> Intent:
        if not self.released:
            return Intent(None, "idle")
        nxt = self.released[0]
        d = self.position.direction_to(nxt)
        if d is None:  # cannot happen: orders are checked to be contiguous
            self.released = []
            return Intent(None, "idle")
        reading = self.sensors[d]
        if reading != "free":
            return Intent(
                None, "waiting", f"released square {sq(nxt)} is blocked by {_THING[reading]}"
            )
        return Intent(d, "moving")

    def _act(self) -> None:
        a = self.action
        if a is None or self.released or self.position != a.square or self.estop:
            return
        key = (self.order_id, self.order_update_id, f"{a.kind}:{a.job_id}")
        if self._acted is not None and self._acted[0] == key[0] and self._acted[2] == key[2]:
            return
        self._acted = key
        if a.kind == "pick":
            if self.job_id == a.job_id:
                return
            if self.job_id is not None:
                self.error("bad_action", f"cannot pick {a.job_id!r}: carrying {self.job_id!r}")
            elif self.load_kg + a.mass_kg > self.capacity_kg:
                self.error(
                    "over_capacity",
                    f"cannot pick {a.job_id!r} of {a.mass_kg} kg: capacity {self.capacity_kg} kg",
                )
            else:
                self.job_id, self.load_kg = a.job_id, self.load_kg + a.mass_kg
        elif self.job_id == a.job_id:
            self.job_id, self.load_kg = None, 0.0

    def _follow_goal(self, waiting_counts: bool) -> Intent:
        if self.goal is None or self.position == self.goal:
            self._yield_from = None
            return Intent(None, "idle")
        if self.step < self._pause_until:
            return Intent(None, "waiting", "giving way to another unit")
        if self._yield_from is not None:
            intent = self._give_way(self._yield_from, waiting_counts)
            if intent is not None:
                return intent
        self._avoid = {c: until for c, until in self._avoid.items() if until > self.step}
        path = self._plan(avoid=True) or self._plan(avoid=False)
        if not path:
            return Intent(None, "waiting", f"no known route to the goal {sq(self.goal)}")
        if len(path) < self._best:
            self._best, self._gave_way = len(path), False
        nxt = path[0]
        d = self.position.direction_to(nxt)
        assert d is not None
        reading = self.sensors[d]
        if reading == "free":
            return Intent(d, "moving")
        if reading == "unit" and waiting_counts:
            self._waited += 1
            if self._waited >= self.patience:
                self._waited = 0
                self.patience = self._rng.randint(2, 6)
                around = self._plan(avoid=True, extra=nxt)
                if around and (len(around) <= len(path) + DETOUR_MAX or self._gave_way):
                    # Waited long enough and there is another way: route around that unit
                    # until the detour is driven.
                    self._avoid[nxt] = self.step + max(AVOID_STEPS, len(around))
                else:
                    # No way around (a corridor) or a long one: give way by stepping aside or
                    # backing off; if that does not help, the next time it takes the detour.
                    self._yield_from, self._quiet, self._gave_way = d, 0, True
        return Intent(None, "waiting", f"next square {sq(nxt)} is blocked by {_THING[reading]}")

    def _give_way(self, blocker: Direction, waiting_counts: bool) -> Intent | None:
        """Step aside from, or back off before, a unit on side `blocker`; None when done."""
        if self.sensors[blocker] != "unit":
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
            if self.sensors[d] == "free":
                return Intent(d, "moving")
        return Intent(None, "waiting", "giving way to another unit, but boxed in")

    @property
    def _fields(self) -> DistanceFieldCache:
        """Distance fields on the map as this unit knows it (static map plus sensed obstacles)."""
        if self._fields_cache is None:
            self._fields_cache = DistanceFieldCache(self.grid.with_blocked(self.known_obstacles))
        return self._fields_cache

    def _plan(self, avoid: bool, extra: Cell | None = None) -> list[Cell] | None:
        assert self.goal is not None
        if avoid:
            blocked = {*self._avoid, *([extra] if extra is not None else [])} - {self.goal}
            if not blocked:
                return None
            grid = self._fields.grid.with_blocked(blocked)
            field = distance_field(grid, self.goal)
        else:
            field = self._fields.get(self.goal)
        if int(field[self.position.y, self.position.x]) == UNREACHABLE:
            return None
        return route(field, self.position)

    # ---- outputs ------------------------------------------------------------------------------

    def leds(self) -> Leds:
        """All four when emergency-stopped, else exactly the LED of the intended move (or none)."""
        if self.estop:
            return Leds(N=True, E=True, S=True, W=True)
        d = self.direction
        return Leds(N=d is Direction.N, E=d is Direction.E, S=d is Direction.S, W=d is Direction.W)

    def report(self, header: Header) -> UnitState:
        """The state message; obstacles and errors in it are reported once, then forgotten."""
        state = UnitState(
            header=header,
            step=self.step,
            position=self.position,
            direction="-" if self.direction is None else self.direction.value,
            status=self.status,
            wait_reason=self.wait_reason,
            mode=self.mode,
            job_id=self.job_id,
            load_kg=self.load_kg,
            leds=self.leds(),
            sensors=Sensors(**{d.value: r for d, r in self.sensors.items()}),
            obstacles=[(c.x, c.y) for c in self.new_obstacles[:4]],
            order_id=self.order_id,
            order_update_id=self.order_update_id,
            released=[(c.x, c.y) for c in self.released],
            goal=self.goal,
            estop=self.estop,
            errors=self.errors,
        )
        self.new_obstacles = self.new_obstacles[4:]
        self.errors = []
        return state


def step_in(world: WorldSim, logic: UnitLogic, since_order_s: float | None) -> Direction | None:
    """One step of `logic` in `world`: sense, decide, move atomically; the move made, if any."""
    move = logic.begin_step(world.sense(logic.unit_id), since_order_s)
    moved = move if move is not None and world.move(logic.unit_id, move) else None
    logic.end_step(moved, world.sense(logic.unit_id), since_order_s)
    return moved
