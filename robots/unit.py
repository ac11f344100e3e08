"""The pure core of one unit: its state machine (stop, holding, LEDs, steps), orders and cargo.

No sockets, no clock and no world: callers pass what arrived (orders, goals, the emergency stop,
connects), the sensor readings and the time `now` (seconds on any monotonic clock), and get back
the move the unit wants and, from `report`, the state to publish. Coordinated driving lives in
`coordinated.py`, standalone routing in `navigation.py`; the wire (topics, bytes) in `core.py`.

A new `UnitLogic` counts as connected, with the stop known to be released, so a pure simulation
needs no connect; a shell calls `on_disconnect`/`on_connect` as its session comes and goes.

Public surface, for shells and simulations:
- inputs: `start`, `on_order`, `on_goal`, `on_estop`, `on_coordinator`, `on_connect`,
  `on_disconnect`, `error`; a step is `tick` (or `begin_step`, move, `end_step`);
- outputs: `report` (the state message), `leds`, and these fields, read-only for callers:
  `position`, `step`, `status`, `wait_reason`, `direction`, `sensors`, `estop`, `estop_known`,
  `connected`, `job_id`, `load_kg`, `order_id`, `order_update_id`, `released`, `action`, `goal`,
  `known_obstacles`, `errors`, `hold_timeout_s`, `battery` (None: it reports no energy),
  `charging`.

A unit with a battery (`robots/battery.py`) drains by its model each step, charges while it stands
on its order's `charge` square with nothing released left when that square is one of its world's
`chargers` (protocol.md §4.4 rule 8), and at 0 % cannot move.

In a pure simulation, per unit and step::

    unit.on_order(order, now)                       # a Verdict: accepted, stale, refused
    moved = unit.tick(sense, move, now)             # sense() -> Readings; move(d) -> allowed?
    state = unit.report(stamp("state"))             # the UnitState to hand to the coordinator
"""

from __future__ import annotations

from collections.abc import Callable, Container
from typing import Literal

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol.constants import (
    HOLD_AFTER_STEPS,
    LATE_ORDER_MIN_S,
    MAX_TEXT,
    MIN_TIMEOUT_S,
)
from gridfleet.protocol.messages import (
    Action,
    Header,
    Leds,
    Order,
    SensorReading,
    Sensors,
    UnitError,
    UnitState,
    UnitStatus,
)
from gridfleet.robots.battery import Battery
from gridfleet.robots.coordinated import OrderFollower
from gridfleet.robots.decisions import Intent, Readings, Verdict, sq
from gridfleet.robots.fleet_side import letter
from gridfleet.robots.navigation import Navigator

Mode = Literal["coordinated", "standalone"]
LATE_TOLD_EVERY_S = 10.0  # a unit tells of late orders at most this often (protocol §4.4 rule 7)
MAX_ERRORS = 16
ESTOP_WAIT_MIN_S = 0.2  # after connecting, hold at least this long for the retained stop
ESTOP_WAIT_MAX_S = 1.0  # and at most this long (protocol.md §5.1)
BATTERY_EMPTY = "battery empty: cannot move"

Sense = Callable[[], Readings]
"""Reads the unit's four sensors now."""
Move = Callable[[Direction], bool]
"""Makes one move in the world; whether the world allowed it."""


class UnitLogic:
    """One unit's decisions: every input is a method call, every output a return value or field."""

    def __init__(
        self,
        unit_id: str,
        grid: GridMap,
        start: Cell,
        capacity_kg: float,
        step_s: float,
        mode: Mode = "coordinated",
        goal: Cell | None = None,
        *,
        battery: Battery | None = None,
        chargers: Container[Cell] = frozenset(),
    ) -> None:
        self.unit_id = unit_id
        self.grid = grid
        self.position = start
        self.capacity_kg = capacity_kg
        self.step_s = step_s
        self.mode: Mode = mode
        self.step = 0
        self.status: UnitStatus = "idle"
        self.wait_reason: str | None = None
        self.direction: Direction | None = None  # intended move of the coming step (the LEDs)
        self.sensors: dict[Direction, SensorReading] = dict.fromkeys(Direction, "free")
        self.estop = False
        self.estop_known = True  # False from a connect until the retained stop can have arrived
        self.connected = True
        self.coordinator_step_s = step_s
        self.job_id: str | None = None
        self.load_kg = 0.0
        self.known_obstacles: set[Cell] = set()
        self.new_obstacles: list[Cell] = []
        self.errors: list[UnitError] = []
        self.orders = OrderFollower(grid)
        self.navigator = Navigator(unit_id, grid, self.known_obstacles, goal)
        self._started = 0.0
        self._last_order: float | None = None
        self._estop_wait_until: float | None = None
        self.late_by_s: float | None = None  # how late the last order came, while that is too late
        self._late_told_at: float | None = None
        self.battery = battery  # None: no energy, it never runs down (and reports none)
        self.chargers = chargers  # the squares its world charges it on (a scenario's chargers)
        self._no_charger_told: Cell | None = None  # the non-charger it was last told to charge on

    # ---- what it follows ----------------------------------------------------------------------

    @property
    def order_id(self) -> str | None:
        """The last order accepted (None: none yet)."""
        return self.orders.order_id

    @property
    def order_update_id(self) -> int:
        """The update of the last order accepted (0: none yet)."""
        return self.orders.update_id

    @property
    def released(self) -> list[Cell]:
        """Released squares not yet driven, in order."""
        return self.orders.released

    @property
    def action(self) -> Action | None:
        """The action of the current order."""
        return self.orders.action

    @property
    def goal(self) -> Cell | None:
        """The standalone goal."""
        return self.navigator.goal

    @property
    def hold_timeout_s(self) -> float:
        """How long a coordinated unit waits for an order before it holds still (protocol §8)."""
        return max(MIN_TIMEOUT_S, HOLD_AFTER_STEPS * max(self.step_s, self.coordinator_step_s))

    @property
    def late_order_s(self) -> float:
        """How late an order may come and still be driven (protocol §4.4 rule 7)."""
        return max(LATE_ORDER_MIN_S, self.hold_timeout_s)

    @property
    def charging(self) -> bool:
        """It charges: on its order's charger with nothing released left, and not stopped."""
        here = self.orders.charge
        return (
            self.battery is not None
            and here is not None
            and here == self.position
            and not self.released
            and not self.estop
            and here in self.chargers
        )

    def since_order_s(self, now: float) -> float:
        """Seconds since the last valid order (or since `start`)."""
        return now - (self._last_order if self._last_order is not None else self._started)

    # ---- inputs -------------------------------------------------------------------------------

    def start(self, now: float) -> None:
        """The unit starts at `now`: the wait for a first order counts from here."""
        self._started = now

    def error(self, code: str, message: str) -> None:
        """Report a problem in the next state's `errors`."""
        self.errors.append(UnitError(code=code, message=message[:MAX_TEXT]))
        del self.errors[:-MAX_ERRORS]

    def on_order(self, order: Order, now: float) -> Verdict:
        """Take an order: stale ones change nothing, bad ones are refused with a `bad_order` error."""
        if self.mode != "coordinated":
            return Verdict("ignored")
        self.late_by_s = None  # on time again: orders are driven
        verdict = self.orders.take(order, self.position)
        if verdict.result in ("accepted", "stale"):
            self._last_order = now  # even a repeated order shows the coordinator is there
        if verdict.result == "refused":
            self.error("bad_order", verdict.reason or "")
        if verdict.result == "accepted":
            self._check_charger(self.orders.charge)
        if verdict.result != "stale":
            self._refresh(now)
        return verdict

    def _check_charger(self, square: Cell | None) -> None:
        """Ordered to charge where no charger is: said once (not again for each heartbeat)."""
        if square is None or square in self.chargers:
            self._no_charger_told = None
        elif square != self._no_charger_told:
            self._no_charger_told = square
            self.error("no_charger", f"ordered to charge on {sq(square)}, which is no charger")

    def on_late_order(self, late_by_s: float, now: float) -> bool:
        """An order that came too late to drive (protocol §4.4 rule 7): drop what is left, hold.

        True when it is to be told: once a late spell, and at most every LATE_TOLD_EVERY_S (a
        starved link or process flapping between late and on time must not flood `errors`).
        """
        if self.mode != "coordinated":
            return False
        told = self._late_told_at
        tell = self.late_by_s is None and (told is None or now - told >= LATE_TOLD_EVERY_S)
        if tell:
            self.error("late_order", f"orders come {late_by_s:.1f} s late: holding until on time")
            self._late_told_at = now
        self.late_by_s = late_by_s
        self.orders.drop()
        self._refresh(now)
        return tell

    def on_goal(self, target: Cell | None, now: float) -> Verdict:
        """Set or clear the standalone goal; a goal off the map or on a wall is refused."""
        if self.mode != "standalone":
            return Verdict("ignored")
        problem = self.navigator.set_goal(target)
        if problem is not None:
            self.error("bad_goal", problem)
        self._refresh(now)
        return Verdict("accepted") if problem is None else Verdict("refused", problem)

    def on_estop(self, engaged: bool, now: float) -> None:
        """The latched emergency stop; engaging drops every released square (orders resume it)."""
        self.estop_known = True
        if engaged and not self.estop:
            self.orders.drop()
        self.estop = engaged
        self._refresh(now)

    def on_coordinator(self, step_period_s: float) -> None:
        """The coordinator's announced step period, which sizes the hold timeout."""
        self.coordinator_step_s = step_period_s

    def on_connect(self, now: float) -> None:
        """Connected: hold still until the retained emergency stop can have arrived (§5.1)."""
        self.connected = True
        self.estop_known = False
        wait = min(ESTOP_WAIT_MAX_S, max(ESTOP_WAIT_MIN_S, self.step_s))
        self._estop_wait_until = now + wait
        self._refresh(now)

    def on_disconnect(self, now: float, *, first: bool = False) -> None:
        """Lost the broker (or, `first`, not connected yet): hold still, and drop what it was
        told to drive (not yet connected, it keeps its scenario's goal).

        It moves again only on what it hears on its next connection (protocol.md §5.1, "Across
        a broker's death"): a broker failed over to may never have seen the stop engaged, and a
        unit reading no stop there must not drive the rest of a window released before it. The
        released squares not yet driven go (an order on the new connection releases again), and
        in standalone mode the goal (an operator sends it again).
        """
        self.connected = False
        self.orders.drop()
        if self.mode == "standalone" and self.navigator.goal is not None and not first:
            self.navigator.set_goal(None)
        self._refresh(now)

    def _sense(self, readings: Readings) -> None:
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
                self.navigator.map_changed()

    # ---- the step -----------------------------------------------------------------------------

    def tick(self, sense: Sense, move: Move, now: float) -> Direction | None:
        """One whole step: sense, decide, move (nothing else may happen between), sense again."""
        wanted = self.begin_step(sense(), now)
        moved = wanted if wanted is not None and move(wanted) else None
        self.end_step(moved, sense(), now)
        return moved

    def begin_step(self, readings: Readings, now: float) -> Direction | None:
        """Start a step: the move to make now, or None to stay (status says why)."""
        wait_until = self._estop_wait_until
        if not self.estop_known and wait_until is not None and now >= wait_until:
            self.estop_known = True  # no retained stop on the broker: it is not engaged
        self.step += 1
        self._sense(readings)
        intent = self._intent(now, waiting_counts=True)
        self.status, self.wait_reason = intent.status, intent.reason
        if intent.move is not None and intent.move != self.direction:
            # The LEDs must show a move before it is made: show it now, move next step.
            self.direction = intent.move
            self.status, self.wait_reason = "waiting", "showing the new direction before moving"
            return None
        if intent.move is None:
            self.direction = None
        return intent.move

    def end_step(self, moved: Direction | None, readings: Readings, now: float) -> None:
        """Finish a step: `moved` is the move the world performed (None if none or refused)."""
        if self.battery is not None:
            # Charging is judged where it stood this step: a move onto the charger is a move.
            charged = moved is None and self.charging
            self.battery.step(moved=moved is not None, charging=charged, step_s=self.step_s)
        if moved is not None:
            self.position = self.position.step(moved)
            self.status, self.wait_reason = "moving", None
            self.orders.arrived(self.position)
            self.navigator.moved(moved, self.step)
        elif self.direction is not None and self.status == "moving":
            self.status = "waiting"
            self.wait_reason = (
                f"the world refused the move to {sq(self.position.step(self.direction))}"
            )
        self._sense(readings)
        self._act()
        self._refresh(now)

    def _refresh(self, now: float) -> None:
        """Recompute the intended move (the LEDs) after anything changed between steps."""
        intent = self._intent(now, waiting_counts=False)
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
        elif self.status in ("waiting", "idle") and intent.status == "idle":
            # What it waited for went away; an empty battery says why it stays idle.
            self.status, self.wait_reason = "idle", intent.reason

    def _intent(self, now: float, waiting_counts: bool) -> Intent:
        """What it wants now: the order's or the goal's move, unless it cannot move at all."""
        intent = self._wanted(now, waiting_counts)
        if (
            self.battery is None
            or not self.battery.empty
            or intent.status in ("stopped", "holding")
        ):
            return intent
        # At 0 % it stays where it stands, and says why (it can still charge there).
        return Intent(None, "idle" if intent.status == "idle" else "waiting", BATTERY_EMPTY)

    def _wanted(self, now: float, waiting_counts: bool) -> Intent:
        # The emergency stop wins over everything, then not knowing it, then the broker.
        if self.estop:
            return Intent(None, "stopped", "emergency stop engaged")
        if not self.estop_known:
            return Intent(None, "holding", "waiting to read the emergency stop")
        if not self.connected:
            return Intent(None, "holding", "lost the broker; reconnecting")
        if self.mode == "coordinated":
            since = self.since_order_s(now)
            if since > self.hold_timeout_s:
                self.orders.drop()
                return Intent(None, "holding", f"no order from the coordinator for {since:.1f} s")
            if self.late_by_s is not None:
                late = self.late_by_s
                return Intent(None, "holding", f"orders come {late:.1f} s late; holding")
            self._act()
            return self.orders.next_move(self.position, self.sensors)
        return self.navigator.intent(self.position, self.sensors, self.step, waiting_counts)

    def _act(self) -> None:
        """Do the order's action when it is due (protocol §4.4 rule 5); never while stopped."""
        if self.estop:
            return
        a = self.orders.action_due(self.position)
        if a is None:
            return
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
            direction=letter(self.direction),
            status=self.status,
            wait_reason=self.wait_reason,
            mode=self.mode,
            job_id=self.job_id,
            load_kg=self.load_kg,
            leds=self.leds(),
            sensors=Sensors(**{d.value: r for d, r in self.sensors.items()}),
            obstacles=self.new_obstacles[:4],
            order_id=self.order_id,
            order_update_id=self.order_update_id,
            released=list(self.released),
            goal=self.goal,
            estop=self.estop,
            errors=self.errors,
            battery_pct=None if self.battery is None else self.battery.shown_pct,
            charging=self.charging,
        )
        self.new_obstacles = self.new_obstacles[4:]
        self.errors = []
        return state
