"""One VDA 5050 vehicle as a gridfleet unit, pure: both protocols' messages in, `Outbound`s out.

To the fleet the vehicle is a unit like any other (protocol.md §4): its `connection`, `factsheet`,
`state` and `direction`, and a press on its `stop` when its own emergency stop is pressed. To the
vehicle the fleet is a master control (VDA 5050): `order`s whose base is what gridfleet released,
and `instantActions` to pause, resume and cancel.

- **Where it stands** (states.py): the square it is leaving for as long as any part of it may be
  on it; the squares of its base ahead are reported as `released` until it has driven them, so the
  coordinator keeps them reserved. Squares sent to the vehicle count as released from the moment
  they are sent: the vehicle may drive them before its next state says so.
- **Orders** (orders.py): gridfleet's released squares become base nodes once, in order; planned
  ones the horizon. A gridfleet order is acknowledged (its id and update in the unit's state) once
  the vehicle's order is sent. A vehicle that finished its base gets a new order from its square.
- **The stop**: the fleet's stop pauses the vehicle (`startPause`) and the release resumes it
  (`stopPause`); the squares left on its base stay reserved meanwhile. Its own emergency stop is a
  press. A `FATAL` error or a mode other than AUTOMATIC makes the unit `broken` to the fleet, as a
  lost unit, until it is well again: its job goes back to the queue.
- **Charging** (charging.py): an order whose `charge` is the square the vehicle stands on, with
  nothing left to drive, sends `startCharging`; an order taking it elsewhere (or naming no charge)
  sends `stopCharging` and goes nowhere until the vehicle reports `charging` false. Its
  `batteryState` is the unit's `battery_pct` and `charging` when its vehicles file gives it an
  `energy` model (else the unit reports no energy).
- **Heartbeat**: a vehicle may stay silent for 30 s; the fleet hears the unit every
  `STATE_HEARTBEAT_STEPS` steps anyway, from what the vehicle said last (`tick`).
- **A new coordinator**: an announced unit says `online`, its factsheet and its state again to
  every new coordinator session, as a gridfleet unit does (robots/sessions.py, protocol.md §5.5).

Its parts: what it says to the fleet, and when, is every unit's (`robots/fleet_side.py`); our
pause, resume and cancel are one state machine (pause_cancel.py); an order not yet seen is sent
again (resend.py); orders the vehicle refuses end here (refusals.py).
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable
from typing import Any, Literal

from gridfleet.errors import ProtocolError
from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    TOPICS,
    Action,
    Connection,
    CoordinatorStatus,
    HeaderStamper,
    Leds,
    Order,
    Sensors,
    Topics,
    UnitState,
    VehicleCondition,
    decode,
)
from gridfleet.protocol.constants import MAX_TEXT
from gridfleet.protocol.device import EstopSignal, encode_estop
from gridfleet.protocol.messages import SensorReading, UnitError, UnitStatus
from gridfleet.protocol.stop import STOP_KINDS, StopView, stop_filters
from gridfleet.robots.fleet_side import Condition, FleetSide, letter
from gridfleet.robots.sessions import CoordinatorSessions
from gridfleet.robots.vda5050.charging import Charge, Charging
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.inbound import VdaConnection, VdaFactsheet, VdaState, read_vda
from gridfleet.robots.vda5050.instant import InstantKind, instant_action
from gridfleet.robots.vda5050.orders import OrderStitcher
from gridfleet.robots.vda5050.pause_cancel import Cancel, PauseCancel
from gridfleet.robots.vda5050.refusals import Refusals, refuses
from gridfleet.robots.vda5050.resend import OrderResend
from gridfleet.robots.vda5050.states import VehicleView, read_state, reported_square
from gridfleet.robots.vda5050.wire import Headers, VdaTopic

Link = Literal["ONLINE", "OFFLINE", "CONNECTIONBROKEN"]
# Checks a message to or from the vehicle (the official schema, when the shell has it).
Check = Callable[[VdaTopic, dict[str, Any]], None]
VDA_QOS = {"order": 1, "instantActions": 1}  # the spec allows 0; a lost order costs a stop
# The vehicle's states in a row the adapter failed on (a bug) before its unit is `broken`.
UNREADABLE_STATES = 3
MODEL = "vda5050"
# A charge the vehicle ended itself at this battery or more ended because it was full: its unit
# still says `charging` while its order names that charger (protocol.md §4.3: true at 100 %).
FULL_PCT = 99.0
EMPTY = "battery empty: cannot move"


class VehicleCore:
    """One vehicle's two sides: VDA 5050 messages and the fleet's, in; what to publish, out."""

    def __init__(
        self,
        config: VehicleConfig,
        grid: GridMap,
        topics: Topics,
        *,
        run_id: str,
        step_s: float = 0.5,
        color: str = "#795548",
        stamp: HeaderStamper | None = None,
        reporter: HeaderStamper | None = None,
        check: Check | None = None,
    ) -> None:
        self.config = config
        self.vehicle = config.vehicle
        self.id = config.vehicle.unit
        self.grid = grid
        self.topics = topics
        self.step_s = step_s
        self.color = color
        self.stamp = stamp or HeaderStamper(self.id)
        self.check = check
        # What it says to the fleet, and when; its reports on `errors` in the name of whoever
        # sends them (the adapter: a broker with accounts passes a report only from an id its
        # sender's account owns, and a vehicle's unit is its vehicle account's name).
        self.side = FleetSide(self.id, topics, self.stamp, reporter)
        self.headers = Headers(config.vehicle)
        self.orders = OrderStitcher(
            self.headers, config.frame, f"gf-{run_id}-{self.id}", config.action_parameters
        )
        self.capacity_kg = config.capacity_kg  # a 2.1 vehicle's factsheet may tell it
        self.link: Link | None = None  # the vehicle's own `connection`
        # Back on line after it was not: its next state says whether it still has its order.
        self.reconnected = False
        self.view: VehicleView | None = None
        self.nodes_left = 0  # released nodes of its order still ahead, by its last state
        self.horizon_left = 0  # and nodes of its horizon (not released)
        self.square: Cell | None = None
        self.stop = StopView()
        self.instants = PauseCancel()  # our pause, resume and cancel, until the vehicle shows them
        self.resend = OrderResend()  # the latest order sent, until a state shows it
        self.controlled = False  # an operator paused it or took it out of service
        # Since the adapter lost the broker, no order heard that lets the vehicle drive on: it
        # is paused meanwhile (a broker failed over to may never have seen the stop engaged).
        self.unheard = False
        self.pressed = False  # its own emergency stop pressed on the fleet's behalf
        self.announced = False  # the fleet was told `online` (and not `broken` since)
        # The coordinator sessions told who it is on this connection (protocol.md §5.5).
        self.sessions = CoordinatorSessions()
        self.order_id: str | None = None  # gridfleet's order, as acknowledged
        self.update_id = 0
        self.actions: dict[str, Action] = {}  # VDA action id -> the gridfleet action it does
        self.job_id: str | None = None
        self.load_kg = 0.0
        self.errors: list[UnitError] = []
        self.refusals = Refusals()  # new orders refused in a row; whether it refuses every route
        self.charging = Charging()  # our startCharging / stopCharging, until its state shows them
        self.charge_at: Cell | None = None  # the charger gridfleet's latest order names
        # An order held back for the charge would move it: no new charge until the next order.
        self.charge_leave = False
        self.unreadable = 0  # the vehicle's states in a row the adapter failed on (`on_failure`)
        self.step = 0
        self._condition_sent: tuple[object, ...] | None = None
        self._ids = itertools.count(1)

    # ---- subscriptions ------------------------------------------------------------------------

    def vehicle_subscriptions(self) -> list[tuple[str, int]]:
        """The vehicle's topics to follow, as every subscription at SUBSCRIBE_QOS (a clean session)."""
        v = self.vehicle
        return [(v.topic(name), SUBSCRIBE_QOS) for name in ("state", "connection", "factsheet")]

    def fleet_subscriptions(self) -> list[tuple[str, int]]:
        """The fleet's topics this unit follows: the stop, its orders, its own `connection`
        (set right while announced, as a gridfleet unit's: protocol.md §4.1) and the
        coordinator's status (a new session is told again who the unit is: §5.5)."""
        order = self.topics.unit("order", self.id)
        connection = self.topics.unit("connection", self.id)
        return [
            *stop_filters(self.topics),
            (order, SUBSCRIBE_QOS),
            (connection, SUBSCRIBE_QOS),
            (self.topics.fleet("coordinator"), SUBSCRIBE_QOS),
        ]

    # ---- the vehicle --------------------------------------------------------------------------

    def on_vehicle(self, name: VdaTopic, payload: bytes, now: float) -> list[Outbound]:
        """One message on one of the vehicle's topics; what to publish because of it."""
        topic = self.vehicle.topic(name)
        held = self._held_to_schema(name)
        try:
            if name == "connection":
                return self._on_link(read_vda(VdaConnection, payload, self.vehicle, held), now)
            if name == "factsheet":
                return self._on_factsheet(read_vda(VdaFactsheet, payload, self.vehicle, held), now)
            if name == "state":
                outs = self._on_state(read_vda(VdaState, payload, self.vehicle, held), now)
                self.unreadable = 0  # read again: a unit broken by unreadable states is back
                return outs
        except ProtocolError as exc:
            return [self.side.report(topic, f"vehicle {self.id}: refused: {exc}")]
        return []

    def _held_to_schema(self, name: VdaTopic) -> Callable[[Any], None] | None:
        """The official schema's check of what comes on `name`, when the shell has the schemas
        (`--schemas`); without, what the adapter reads is checked alone (inbound.py)."""
        check = self.check
        return None if check is None else lambda data: check(name, data)

    def on_failure(self, name: VdaTopic, error: str) -> list[Outbound]:
        """Handling the vehicle's `name` raised `error` (its class: a bug of the adapter's).

        The unit's state says so at once (`unreadable_state`, or `unreadable_message` for its
        connection or factsheet), never frozen on what it said last; after UNREADABLE_STATES
        such states in a row the unit is `broken` (lost to the fleet, its job back in the
        queue), its last state first, until a state of the vehicle is handled again.
        """
        topic = self.vehicle.topic(name)
        code = "unreadable_state" if name == "state" else "unreadable_message"
        words = f"the adapter failed on the vehicle's {name} on {topic} ({error}); see its log"
        error_ = UnitError(code=code, message=words[:200])
        if error_ not in self.errors:  # one of each while no state goes out (not announced)
            self.errors.append(error_)
        try:
            last = self.state()
        except Exception:  # its state cannot even be made: lost to the fleet at once
            return self._goodbye("broken")
        if name != "state":
            return last
        self.unreadable += 1
        if self.unreadable < UNREADABLE_STATES or not self.announced:
            return last
        return last + self._goodbye("broken")

    def _on_link(self, message: VdaConnection, now: float) -> list[Outbound]:
        was, self.link = self.link, message.connectionState
        if self.link == "ONLINE" and was is not None and was != "ONLINE":
            # What it said before it went may be long past (it may have restarted elsewhere):
            # its unit is announced from its next state, never from the last one before.
            self.reconnected = True
            self.view = None
        if self.link != "ONLINE":
            # Whatever it was driving, the fleet hears it as lost (or gone): its job is handled
            # as a lost unit's, and its squares stay reserved as long as the coordinator keeps a
            # lost unit's.
            self.instants.let_go()
            self.charging.let_go()
            return self._goodbye("offline" if self.link == "OFFLINE" else "broken")
        outs: list[Outbound] = []
        if self.view is None or not self.announced:
            # It may say nothing more for 30 s (its state is not retained): ask. (After the
            # adapter lost the broker too: its unit is announced again from what it said last.)
            outs += self._instant("stateRequest", now)
        if self.vehicle.version != "2.0.0" and self.capacity_kg is None:
            outs += self._instant("factsheetRequest", now)
        return outs + self._announce(now)

    def _on_factsheet(self, message: VdaFactsheet, now: float) -> list[Outbound]:
        capacity = message.capacity_kg
        if capacity is None:
            raise ProtocolError("no maxLoadMass nor maxWeight: no capacity to go by")
        changed = capacity != self.capacity_kg
        self.capacity_kg = capacity
        if self.announced and changed:
            return [self._factsheet()]
        return self._announce(now)

    def _on_state(self, message: VdaState, now: float) -> list[Outbound]:
        grid = (self.grid.width, self.grid.height)  # off the grid is on none of its squares
        view = read_state(
            message.model_dump(mode="json"), self.config.frame, self.config.margin_m, grid
        )
        self.view = view
        if self.reconnected:
            self.reconnected = False
            if message.orderId != self.orders.order_id:
                self._lost_order()
        self.resend.seen(message.orderId, message.orderUpdateId, refuses(message))
        self.nodes_left = sum(1 for n in message.nodeStates if n.released)
        self.horizon_left = len(message.nodeStates) - self.nodes_left
        outs: list[Outbound] = []
        square = reported_square(self.square, view.under, self.orders.base)
        if square is None:
            self.errors.append(UnitError(code="off_route", message=self._off_route(view)))
            outs += self._pause(now)  # it is where the fleet did not send it: hold it
        else:
            self.square = square
        if view.paused:
            if not self._held() and self.instants.resend_resume(now):
                # The last one may have been lost. (REPAUSED too, as ever: a pause that came over
                # an unseen resume, off route, is resumed again by it.)
                outs += self._instant("stopPause", now)
        else:
            self.instants.resumed()
            if self._held():
                # The stop always wins: a vehicle that let go of its pause (a cancel ends a pause
                # on some; a restart forgets it) is paused again.
                self.instants.let_go()
                outs += self._pause(now)
        self._actions_done(view)
        # Our cancel done, or there was nothing to cancel (noOrderToCancel): once it has stopped,
        # its order ends. Else it drives on what it was released (reserved still): the next
        # order that finds the dropped action cancels again.
        cancelled = self.instants.cancel_done(view.finished | view.failed)
        if cancelled and not view.driving and self.nodes_left == 0:
            outs += self._after_cancel(view, now)
        outs += self._charge_seen(message, view) + self._follow_charge(now)
        self._refusals(message)
        if view.estop and not self.pressed:
            self.pressed = True
            press = EstopSignal(True, self.id, "the vehicle's own emergency stop")
            outs.append(Outbound.of("stop", self.topics.unit("stop", self.id), encode_estop(press)))
        elif not view.estop:
            self.pressed = False
        if not self._can_drive():
            why = "; ".join(view.fatal) or (
                "its emergency stop"
                if view.estop
                else "it refuses every route"
                if self.refusals.unroutable
                else "not AUTOMATIC"
            )
            if self.announced and not view.estop:
                self.errors.append(UnitError(code="vehicle_down", message=why[:200]))
                # A last state first: the fleet keeps a lost unit's squares as it last heard
                # them, and an order the vehicle refused has ended (it releases nothing now).
                last = self.state()
                return outs + last + self._goodbye("broken") + self._vehicle_condition(view)
        # Its condition even while it is not a unit of the fleet: a vehicle down from the start
        # shows why on the dashboard.
        return outs + (self._announce(now) or self.state()) + self._vehicle_condition(view)

    def _vehicle_condition(self, view: VehicleView) -> list[Outbound]:
        """The vehicle's battery and own errors (protocol.md §4.7), when they changed."""
        battery = min(100.0, max(0.0, view.battery_pct))
        errors = [e[:MAX_TEXT] for e in view.errors[:8]]
        seen = (int(battery), view.charging, tuple(errors))
        if seen == self._condition_sent:
            return []
        self._condition_sent = seen
        message = VehicleCondition(
            header=self.stamp("vehicle"),
            battery_pct=round(battery, 1),
            charging=view.charging,
            errors=errors,
        )
        return [Outbound.of("vehicle", self.topics.unit("vehicle", self.id), message)]

    def _refusals(self, message: VdaState) -> None:
        """An order or update the vehicle refused: what it will not drive is not released.

        The spec lets a vehicle refuse an update (`orderUpdateError`) or a route
        (`noRouteError`); it then finishes what it had accepted and stops. Once it has, the
        order ends here too: the squares it refused are no longer reported as released (the
        coordinator plans the unit afresh from its square), and actions it never took are
        dropped. A vehicle that refuses REFUSALS_TO_GIVE_UP new orders in a row, and says so
        still, counts as unable to drive: its unit is lost to the fleet and its job goes to
        another.
        """
        refused = self.refusals.read(message, self.orders.order_id, self.nodes_left)
        if not refused:
            return
        taken = {a.actionId for a in message.actionStates}
        self.actions = {k: a for k, a in self.actions.items() if k in taken}
        self.errors.append(
            UnitError(code="order_refused", message=f"the vehicle refused: {refused}")
        )
        self.orders.end()

    def _can_drive(self) -> bool:
        return self.view is not None and self.view.can_drive and not self.refusals.unroutable

    def _off_route(self, view: VehicleView) -> str:
        if not view.under:
            return "the vehicle gives no position on the map (none, not initialised, or off it)"
        under = sorted(list(c) for c in view.under)
        return f"the vehicle is on {under[:4]}, off the squares the fleet sent it"[:200]

    def _actions_done(self, view: VehicleView) -> None:
        """Picks and drops the vehicle reports finished: what it carries now."""
        for action_id in list(self.actions):
            if action_id in view.finished:
                action = self.actions.pop(action_id)
                if action.kind == "pick":
                    self.job_id, self.load_kg = action.job_id, self.load_kg + action.mass_kg
                else:
                    self.job_id, self.load_kg = None, max(0.0, self.load_kg - action.mass_kg)
            elif action_id in view.failed:
                action = self.actions.pop(action_id)
                self.errors.append(
                    UnitError(code="action_failed", message=f"{action.kind} of {action.job_id}")
                )

    # ---- the fleet ----------------------------------------------------------------------------

    def on_fleet(
        self, topic: str, payload: bytes, now: float, *, retained: bool = False
    ) -> list[Outbound]:
        """One message on one of the fleet's topics this unit follows (`retained`: replayed by
        the broker on subscribing)."""
        where = self.side.parse(topic)
        if where is not None and where[0] in STOP_KINDS:
            try:
                self.stop.apply(*where, topic, payload)
            except ProtocolError as exc:
                return [self.side.report(topic, str(exc))]  # never a release
            return self._follow_stop(now) + self.state()
        if where == ("connection", self.id):
            return self._on_own_connection(topic, payload)
        if where is not None and where[0] == "coordinator":
            return self._on_coordinator(topic, payload, retained)
        return self._on_order(topic, payload, now) if where == ("order", self.id) else []

    def _on_own_connection(self, topic: str, payload: bytes) -> list[Outbound]:
        """The unit's `connection` read back: anything but `online` while the fleet was told
        `online` (and not `offline` or `broken` since) is set right with `online` again, as a
        gridfleet unit does (robots/core.py): a stale word of a clustered broker's. Its own
        `offline` or `broken` comes back after it stopped announcing, and changes nothing."""
        if not payload or not self.announced:
            return []
        try:
            said = decode(Connection, payload)
        except ProtocolError as exc:
            return [self.side.report(topic, str(exc))]
        return [] if said.state == "online" else [self.side.connection("online")]

    def _on_coordinator(self, topic: str, payload: bytes, retained: bool) -> list[Outbound]:
        """The coordinator's status: a new session of it is told again who the unit is, once
        announced (`online`, the factsheet, the state; fresh headers): its broker may not have
        given it the retained ones. Before that, the announcement tells it anyway."""
        if not payload:
            return []  # cleared (`gridfleet clean`)
        try:
            status = decode(CoordinatorStatus, payload)
        except ProtocolError as exc:
            return [self.side.report(topic, str(exc))]
        if not self.sessions.new_session(status, retained=retained) or not self.announced:
            return []
        return [self.side.connection("online"), self._factsheet(), *self.state()]

    def _held(self) -> bool:
        """Whether the vehicle must stay paused: the fleet's stop, an operator's control, or no
        order heard yet on the adapter's present connection (`unheard`)."""
        return self.stop.engaged or self.controlled or self.unheard

    def on_control(self, control: str | None, now: float) -> list[Outbound]:
        """An operator's control of the unit (fleet/routes): paused or out of service pauses
        the vehicle where it is (a vehicle cannot be told to stop at the end of its base); its
        squares stay released meanwhile."""
        controlled = control in ("paused", "out_of_service")
        if controlled == self.controlled:
            return []
        self.controlled = controlled
        return self._follow_stop(now) + self.state()

    def _follow_stop(self, now: float) -> list[Outbound]:
        if self._held():
            return self._pause(now)
        outs: list[Outbound] = []
        if self.instants.resume(now):
            outs += self._instant("stopPause", now)
        if self.instants.cancel_state is Cancel.ENDED and self.view is not None:
            outs += self._after_cancel(self.view, now)
        return outs + self._follow_charge(now)

    def _pause(self, now: float) -> list[Outbound]:
        if self.link != "ONLINE" or not self.instants.pause():
            return []
        return self._instant("startPause", now)

    def _on_order(self, topic: str, payload: bytes, now: float) -> list[Outbound]:
        try:
            order = decode(Order, payload, TOPICS["order"].max_bytes)
        except ProtocolError as exc:
            return self._refuse(topic, str(exc))
        before = (self.order_id, self.update_id)
        outs = self._take_order(topic, order, now)
        taken = (self.order_id, self.update_id) != before
        if self.unheard and taken and (order.released or not self.released()):
            # The coordinator's word on this connection: squares to drive (its base ahead among
            # them), or a halt with nothing left to drive. A halt order cannot take back a base
            # already sent, so one with a base ahead keeps it paused (under a stop the adapter
            # has not read yet, the coordinator sends nothing else).
            self.unheard = False
            outs += self._follow_stop(now)
        return outs

    def _take_order(self, topic: str, order: Order, now: float) -> list[Outbound]:
        if order.order_id == self.order_id and order.update_id <= self.update_id:
            return []  # stale or repeated (rule 1)
        if self.square is None or not self.announced:
            return []  # not a unit of the fleet yet: the coordinator sends again
        released = [Cell(*c) for c in order.released]
        if released and released[0] == self.square:
            released = released[1:]  # planned from an older state (rule 3)
        planned = [Cell(*c) for c in order.planned]
        problem = self._bad_release(released)
        if problem is not None:
            return self._refuse(topic, problem)
        dropped = self._dropped_actions(order.action)
        if dropped or self.instants.cancelling:
            # The job of an action already sent was cancelled or went elsewhere: what the
            # vehicle was released cannot be taken back, so its whole order is cancelled (not
            # under the stop: on some vehicles a cancel ends their pause). Until that is done,
            # gridfleet's orders are acknowledged and go nowhere.
            self.order_id, self.update_id = order.order_id, order.update_id
            if dropped and not self.instants.cancelling and not self._held():
                action_id = f"cancelOrder-{next(self._ids)}"
                self.instants.start_cancel(action_id)
                return self._instant("cancelOrder", now, action_id) + self.state()
            return self.state()
        self._charge_ordered(order, released)
        if released and self._finished_base():
            self.orders.end()  # it stands at the end of its order: the next one is new
        if self._charge_holds() and self.orders.adds(self.square, released, planned, order.action):
            # A charging vehicle takes no order (VDA 5050: it reports charging false only once
            # it is ready for one): acknowledged, it goes nowhere; one that would move it stops
            # the charge, and the coordinator's next order after that goes to the vehicle.
            self.order_id, self.update_id = order.order_id, order.update_id
            if released or order.action is not None:
                self.charge_leave = True
            return self._follow_charge(now) + self.state()
        try:
            message = self.orders.order(self.square, released, planned, order.action, now)
        except ValueError as exc:
            return self._refuse(topic, str(exc))
        self.order_id, self.update_id = order.order_id, order.update_id
        self.charge_leave = False
        outs: list[Outbound] = []
        if message is not None:
            if order.action is not None:
                self.actions[f"{order.action.kind}-{order.action.job_id}"] = order.action
            outs.append(self._to_vehicle("order", message, now))
        return outs + self._follow_charge(now) + self.state()

    # ---- charging -----------------------------------------------------------------------------

    def _charge_ordered(self, order: Order, released: list[Cell]) -> None:
        """The charger gridfleet's order names (a halt order under the stop or an operator's
        control names none, and changes nothing: the paused vehicle charges on)."""
        charge = None if order.charge is None else Cell(*order.charge)
        if charge is None and not released and self._held():
            return
        self.charge_at = charge

    def _charge_holds(self) -> bool:
        """Whether no order may go to the vehicle: it charges, or our start or stop is in flight."""
        return self.charging.busy or (self.view is not None and self.view.charging)

    def _stands_done(self, view: VehicleView) -> bool:
        """Whether the vehicle stands with nothing left to drive or do, its orders all seen."""
        return (
            not view.driving
            and not view.paused
            and self.nodes_left == 0
            and self.horizon_left == 0  # its order done: no horizon either
            and not self.released()
            and not self.actions
            and not self.instants.cancelling
            and not self.resend.pending
        )

    def _follow_charge(self, now: float) -> list[Outbound]:
        """Start or stop the vehicle's charge as gridfleet's latest order says.

        It starts once the vehicle stands on the order's `charge` square with nothing left to
        drive (at most once there: a failed or ended charge is not started again until the
        charge is ordered afresh); it stops when the order names another square or none, or an
        order held back for the charge would move it. Never under the stop (the vehicle is
        paused; on the release the coordinator's orders say again).
        """
        view, c = self.view, self.charging
        if view is None or self.link != "ONLINE" or not self.announced or self.square is None:
            return []
        if self._held() or not view.can_drive:
            return []
        here = self.charge_at is not None and self.square == self.charge_at
        if c.state in (Charge.FAILED, Charge.ENDED) and (not here or c.square != self.square):
            c.forget()
        if self.charge_leave or not here:
            if c.state is Charge.CHARGING:
                action_id = f"stopCharging-{next(self._ids)}"
                c.stop(action_id, now)
                return self._instant("stopCharging", now, action_id)
            return []
        if c.state is Charge.NONE and not view.charging and self._stands_done(view):
            action_id = f"startCharging-{next(self._ids)}"
            c.start(action_id, self.square, now)
            return self._instant("startCharging", now, action_id)
        return []

    def _charge_seen(self, message: VdaState, view: VehicleView) -> list[Outbound]:
        """What a state says of the charge: a failed start or stop is told (the unit's errors
        and the fleet's `errors`), once; a charge the vehicle ended itself below FULL_PCT too."""
        self.charging.heard(view.listed)
        ours = self.charging.action_id
        at = self.charging.square
        event = self.charging.seen(view.charging, view.finished, view.failed, self.square)
        battery = _pct(view.battery_pct)
        if event == "failed":
            where = "" if at is None else f" at {list(at)}"
            words = (
                f"the vehicle did not start charging{where}: startCharging failed "
                f"({_why(message, ours)}); not tried again until it is sent to charge afresh"
            )
            return self._charge_problem("no_charger", words)
        if event == "stop_failed":
            words = (
                f"the vehicle failed stopCharging ({_why(message, ours)}): it charges on, and "
                "takes no order until it reports charging false"
            )
            return self._charge_problem("charge_not_stopped", words)
        if event == "ended" and battery < FULL_PCT:
            self.errors.append(
                UnitError(
                    code="charge_ended",
                    message=f"the vehicle ended its charge itself at {battery:.0f} %",
                )
            )
        return []

    def _charge_problem(self, code: str, words: str) -> list[Outbound]:
        self.errors.append(UnitError(code=code, message=words[:200]))
        return [self.side.report(self.vehicle.topic("state"), f"vehicle {self.id}: {words}")]

    def _charge_again(self, now: float) -> list[Outbound]:
        """Our startCharging or stopCharging again when no state has listed it (QoS 0)."""
        if self.link != "ONLINE" or self.view is None:
            return []
        again = self.charging.resend(self.view.listed, now)
        if again is None:
            return []
        kind: InstantKind = (
            "startCharging" if self.charging.state is Charge.STARTING else "stopCharging"
        )
        return self._instant(kind, now, again)

    def battery(self) -> tuple[float | None, bool]:
        """The unit's `battery_pct` and `charging`: None and False without an energy model.

        `charging` is the vehicle's, and true still after the vehicle ended a charge itself at
        FULL_PCT or more while its order names that charger (full, it stays there charged).
        """
        view = self.view
        if view is None or self.config.energy is None:
            return None, False
        pct = _pct(view.battery_pct)
        full = (
            self.charging.state is Charge.ENDED
            and pct >= FULL_PCT
            and self.square is not None
            and self.square == self.charge_at
        )
        return round(pct, 2), view.charging or full

    def _dropped_actions(self, wanted: Action | None) -> bool:
        """Whether an action sent to the vehicle, not done yet, is no longer gridfleet's."""
        return any(
            wanted is None or (a.kind, a.job_id) != (wanted.kind, wanted.job_id)
            for a in self.actions.values()
        )

    def _lost_order(self) -> None:
        """Back on line without the order it had (it restarted): none of that order's squares
        are its any more, and where it stands is read afresh from its state."""
        self.orders.end()
        self.actions = {}
        self.square = None
        self.charging.let_go()

    def _after_cancel(self, view: VehicleView, now: float) -> list[Outbound]:
        """The vehicle's order is cancelled: it ends here, where it stopped."""
        if self._held():
            self.instants.end_under_stop()  # under the stop nothing new goes out: on the release
            return []
        self.instants.ended()
        ahead = self.released()[:1]
        self.actions = {}
        self.orders.end()
        if self.square is None or view.under == {self.square} or not ahead:
            return []
        # It stopped between its square and the next (a vehicle may stop at once): the next
        # stays released to it, and a new order from its square takes it on to that one.
        message = self.orders.order(self.square, ahead, [], None, now)
        return [] if message is None else [self._to_vehicle("order", message, now)]

    def _bad_release(self, released: list[Cell]) -> str | None:
        """Why gridfleet's release cannot be driven (rule 3), or None."""
        previous = self.square
        for cell in released:
            if not self.grid.is_free(cell):
                return f"released square {list(cell)} is off the map or a wall"
            if previous is None or previous.manhattan(cell) != 1:
                return f"released squares are not contiguous at {list(cell)}"
            previous = cell
        return None

    def _finished_base(self) -> bool:
        """Whether the vehicle has driven its whole order and done its actions."""
        base = self.orders.base
        # A horizon still ahead keeps its order under way (VDA 5050 §6.6: the vehicle waits for
        # an update; vda-5050-lib takes no new order then but one stitching onto its base).
        return (
            bool(base)
            and self.square == base[-1]
            and self.nodes_left == 0
            and self.horizon_left == 0
            and not self.actions
        )

    def _refuse(self, topic: str, reason: str) -> list[Outbound]:
        self.errors.append(UnitError(code="bad_order", message=reason[:200]))
        return [self.side.report(topic, reason), *self.state()]

    # ---- what goes out ------------------------------------------------------------------------

    def _instant(
        self, kind: InstantKind, now: float, action_id: str | None = None
    ) -> list[Outbound]:
        message = instant_action(
            self.headers,
            kind,
            action_id or f"{kind}-{next(self._ids)}",
            now,
            legacy_actions_key=self.config.legacy_actions_key,
        )
        return [self._to_vehicle("instantActions", message, now)]

    def _to_vehicle(
        self, name: Literal["order", "instantActions"], message: dict[str, Any], now: float
    ) -> Outbound:
        if self.check is not None:
            self.check(name, message)
        if name == "order":
            self.resend.sent(message, now)
        payload = json.dumps(message, separators=(",", ":")).encode()
        return Outbound(self.vehicle.topic(name), payload, VDA_QOS[name], False)

    def _announce(self, now: float) -> list[Outbound]:
        """`online`, the factsheet and the state, once everything they need is known."""
        if self.announced or self.link != "ONLINE" or self.capacity_kg is None:
            return []
        if self.square is None or not self._can_drive():
            return []
        self.announced = True
        self.side.new_connection()
        outs = [self.side.connection("online"), self._factsheet(), *self.state()]
        if self._held():
            outs = self._pause(now) + outs
        return outs

    def _goodbye(self, state: Literal["offline", "broken"]) -> list[Outbound]:
        if not self.announced:
            return []
        self.announced = False
        return [self.side.connection(state)]

    def _factsheet(self) -> Outbound:
        assert self.capacity_kg is not None
        return self.side.factsheet(
            capacity_kg=self.capacity_kg,
            step_s=self.step_s,
            color=self.color,
            model=f"{MODEL}-{self.vehicle.version}",
            map_id=self.grid.map_id(),
            sensors=[],
            energy=self.config.energy,
        )

    def on_broker_lost(self) -> None:
        """The adapter lost the broker: all is heard afresh (the retained messages come again),
        and the vehicle is paused until an order on the next connection lets it drive on."""
        self.announced = False  # the next word from the vehicle announces the unit again
        self.sessions.reset()
        self.unheard = True
        self.stop = StopView()  # a press cleared meanwhile is not replayed
        self.side.new_connection()
        self._condition_sent = None

    def offline(self) -> list[Outbound]:
        """The goodbye of a clean stop: the unit is offline."""
        return self._goodbye("offline")

    def tick(self, now: float) -> list[Outbound]:
        """One step of the adapter's clock: the state when it changed or is due again, and an
        order the vehicle has not shown it has, sent again."""
        self.step += 1
        outs = self._order_again(now) + self._charge_again(now)
        if not self.side.due(self._condition()):
            return outs
        return outs + self.state()

    def _order_again(self, now: float) -> list[Outbound]:
        """The latest order again when no state has shown it for RESEND_S (a vehicle takes its
        orders at QoS 0: one can be lost; the same order again is discarded by the spec)."""
        if self.link != "ONLINE" or self.instants.cancelling:
            return []
        message = self.resend.due(now)
        if message is None:
            return []
        again = {**message, **self.headers("order", now)}
        return [self._to_vehicle("order", again, now)]

    def released(self) -> list[Cell]:
        """The squares of its base it has not driven yet: the coordinator keeps them reserved."""
        base = list(self.orders.base)
        if self.square is None:
            return []
        if self.square not in base:
            return base  # an order from the square it is entering (after a cancel)
        return base[len(base) - 1 - base[::-1].index(self.square) + 1 :]

    def direction(self) -> Direction | None:
        """Its next move, when it has one and may make it."""
        ahead = self.released()
        if self.square is None or not ahead or self.stop.engaged:
            return None
        return Direction.between(self.square, ahead[0])

    def status(self) -> tuple[UnitStatus, str | None]:
        """Its gridfleet status and why it waits."""
        view = self.view
        if self.stop.engaged or (view is not None and view.estop):
            return "stopped", None
        if view is not None and view.paused:
            return "holding", "the vehicle is paused"
        if view is not None and view.driving:
            return "moving", None
        battery, charging = self.battery()
        if battery is not None and battery <= 0 and not charging:
            return ("waiting" if self.released() or self.actions else "idle"), EMPTY
        doing = [a for k, a in self.actions.items() if view is not None and k in view.running]
        if doing:
            return "waiting", f"the vehicle is doing its {doing[0].kind} of {doing[0].job_id}"
        if self.released() or self.actions:
            return "waiting", "the vehicle has not reported driving on"
        return "idle", None

    def _condition(self) -> Condition:
        if self.errors:
            return None
        battery, charging = self.battery()
        return (
            None if battery is None else int(battery),  # by whole percent, as every unit's
            charging,
            self.square,
            self.direction(),
            self.status(),
            self.job_id,
            self.load_kg,
            self.order_id,
            tuple(self.released()),
            self.stop.engaged,
        )

    def state(self) -> list[Outbound]:
        """The unit's state now (and its direction when that changed); nothing before `online`."""
        if not self.announced or self.square is None:
            return []
        told = self._condition()
        direction = self.direction()
        status, why = self.status()
        battery, charging = self.battery()
        stopped = status == "stopped"
        leds = (
            Leds(N=True, E=True, S=True, W=True)
            if stopped
            else Leds(**({direction.value: True} if direction is not None else {}))
        )
        state = UnitState(
            header=self.stamp("state"),
            step=self.step,
            position=self.square,
            direction=letter(direction),
            status=status,
            wait_reason=why,
            job_id=self.job_id,
            load_kg=round(self.load_kg, 6),
            leds=leds,
            sensors=self._sensors(),
            order_id=self.order_id,
            order_update_id=self.update_id,
            released=self.released(),
            estop=stopped,
            errors=self.errors[:16],
            battery_pct=battery,
            charging=charging,
        )
        self.errors = []
        return self.side.state(state, told, direction)

    def _sensors(self) -> Sensors:
        """What the map says lies beside its square (a vehicle has no gridfleet sensors)."""
        assert self.square is not None
        seen: dict[str, SensorReading] = {}
        for d in Direction:
            cell = self.square.step(d)
            seen[d.value] = (
                "wall"
                if not self.grid.in_bounds(cell)
                else ("free" if self.grid.is_free(cell) else "obstacle")
            )
        return Sensors(**seen)


def _pct(value: float) -> float:
    """A vehicle's batteryCharge as a share of a full battery: within 0 and 100."""
    return min(100.0, max(0.0, value))


def _why(message: VdaState, action_id: str | None) -> str:
    """Why the vehicle failed action `action_id`: its errors naming it, else its result."""
    told = [
        e.errorDescription or e.errorType
        for e in message.errors
        if action_id is not None and e.about("actionId") == action_id
    ]
    result = next(
        (a.resultDescription for a in message.actionStates if a.actionId == action_id), None
    )
    return "; ".join(told) or result or "no reason given"
