"""Order tracking (protocol.md §4.4): each unit's order ids and updates, what we released to it,
and what it has acknowledged.

Pure. A square stays reserved for a unit until its state shows it left: its reported square, the
squares it still may drive (`state.released`) and, until it has acknowledged our latest change,
every square we sent it since its last acknowledgement. Only *settled* units (acknowledged,
nothing left to drive) get new moves; a unit in motion gets its remaining squares again
(heartbeat), or a halt order when it has waited too long or its way is blocked by a newly known
obstacle.
"""

from __future__ import annotations

from collections.abc import Container, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from gridfleet.coordinator.window import Claims
from gridfleet.coordinator.world import UnitRecord
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import Action, UnitState
from gridfleet.protocol.constants import HOLD_AFTER_STEPS, MAX_PLANNED, MIN_TIMEOUT_S

# A step waits for acknowledgements only while more than one in LATE_SHARE of the units ordered
# still owe one (see Orders.holding_back). A unit acknowledges with the state of its next step,
# and units step when their own clocks say: at the next step, the units whose step comes late in
# the period have not yet (protocol.md §4.3).
LATE_SHARE = 3
WAIT_BEFORE_HOLD = 3  # coordinator steps a unit may wait on a released square before we re-plan it
# An order that changes nothing is repeated once this share of a unit's hold time has passed.
HEARTBEAT_SHARE = 4
PLANNED_SHOWN = min(MAX_PLANNED, 64)  # squares of the planned rest an order shows


class Router(Protocol):
    """Ways on the map for a unit (the planner's `route`): its window ahead, its planned rest."""

    def route(
        self, start: Cell, target: Cell, limit: int = 256, unit: str | None = None
    ) -> list[Cell]:
        """The way after `start` to `target`, at most `limit` squares (empty: unreachable)."""
        ...


@dataclass(frozen=True)
class StepContext:
    """What every unit's order of one step is made from: the core makes it once a step."""

    step_no: int
    now: float
    estop: bool  # the fleet is stopped: halt orders
    grid: GridMap  # with every obstacle known and every closed zone's square blocked
    heartbeat_s: float  # an order that changes nothing is repeated after this long
    window: int  # squares a unit may be released ahead this step (window.py)
    settled: Container[str]  # units acknowledged with nothing left to drive: they get moves
    moves: Mapping[str, Cell]  # this step's move of each unit the planner moves
    targets: Mapping[str, Cell | None]  # where each unit is going
    actions: Mapping[str, Action | None]  # what each unit does at the end of its route
    held: Container[str]  # paused or out of service by an operator: a halt order
    router: Router
    claims: Claims  # who stands on, holds, enters or intends each square (window.py)
    # The charger square each unit sent to charge (or charging) charges on (energy.py).
    charges: Mapping[str, Cell] = field(default_factory=dict)
    # Each unit inside a closed zone: the squares of its way out, the only closed squares it may
    # still drive (`grid` has every closed square blocked; zones.py).
    leaving: Mapping[str, frozenset[Cell]] = field(default_factory=dict)


def heartbeat_s(step_period_s: float) -> float:
    """How long an unchanged order goes unrepeated (protocol.md §4.4 rule 6): a quarter of the
    time a unit waits for orders before it holds, so a late step or two cannot make it hold."""
    return max(MIN_TIMEOUT_S, HOLD_AFTER_STEPS * step_period_s) / HEARTBEAT_SHARE


@dataclass(frozen=True)
class OrderPlan:
    """One order to send (the header is added when it becomes a message)."""

    order_id: str
    update_id: int
    step: int
    released: list[Cell]
    planned: list[Cell]
    target: Cell | None
    action: Action | None
    send: bool = True  # False: nothing changed and the last one is recent; shown, not sent
    charge: Cell | None = None  # the charger square it charges on (protocol.md §4.4, §5.9)


@dataclass
class Track:
    """Our side of one unit's orders."""

    order_id: str | None = None
    route_no: int = 0
    update_id: int = 0
    content_update: int = 0  # update id at which the current released squares were first sent
    acked_update: int = 0  # the latest update of this order the unit's state has shown
    sent: list[Cell] = field(default_factory=list)  # released squares of the latest order
    unacked: set[Cell] = field(default_factory=set)  # every square sent since the last ack
    target: Cell | None = None
    waiting: int = 0
    forged: bool = False  # the unit follows an update we never sent: halt it, then a new order
    sent_at: float = float("-inf")  # when the latest update went out
    action: Action | None = None  # the action of the latest update
    charge: Cell | None = None  # the charger square of the latest update
    reach: int = 1  # squares it may be released ahead: grows each time it ran dry (window.py)


def acknowledges(state: UnitState, order_id: str | None, update_id: int) -> bool:
    """Whether a unit's state shows it has accepted update `update_id` of order `order_id`."""
    return state.order_id == order_id and state.order_update_id >= update_id


def follows_unsent(state: UnitState, t: Track) -> bool:
    """Whether a state shows an update of our current order beyond the latest we sent."""
    return (
        t.order_id is not None
        and state.order_id == t.order_id
        and (state.order_update_id > t.update_id)
    )


def _ahead(
    step: StepContext, unit: str, pos: Cell, target: Cell, last: Cell, room: int
) -> list[Cell]:
    """The squares of `unit`'s way after `last` that its window may take (window.py)."""
    way = step.router.route(last, target, room, unit)
    return step.claims.ahead(unit, pos, way, room)


def _no_return(more: list[Cell], pos: Cell, released: list[Cell]) -> list[Cell]:
    """`more` up to the first square the unit stands on or is already given: a way back through
    its own square would make the unit drop the squares before it (§4.4 rule 3)."""
    been = {pos, *released}
    for i, c in enumerate(more):
        if c in been:
            return more[:i]
    return more


class Orders:
    """Every unit's Track, the order each unit gets next, and the acknowledgements still due."""

    def __init__(self, nonce: str) -> None:
        self.nonce = nonce  # per run, so a restarted coordinator's orders are new orders
        self.tracks: dict[str, Track] = {}
        # Orders of the last step not yet acknowledged: unit -> (order id, update id). The next
        # step waits for them (a while) unless only a few are late (holding_back).
        self.awaiting: dict[str, tuple[str, int]] = {}
        self._late_allowed = 0  # of the awaited units, how many the next step goes on without

    def track(self, unit_id: str) -> Track:
        """The Track of `unit_id`, created on first use."""
        return self.tracks.setdefault(unit_id, Track())

    def forget(self, unit_id: str) -> None:
        """Nothing sent to `unit_id` counts any more (removed, §6.11); its next order is a new
        route, never an id it may still hold as accepted."""
        t = self.tracks.pop(unit_id, None)
        if t is not None:
            self.tracks[unit_id] = Track(route_no=t.route_no)
        self.awaiting.pop(unit_id, None)

    def reach(self, unit_id: str) -> int:
        """Squares `unit_id` may be released ahead now: 1 until it ran dry waiting (window.py)."""
        t = self.tracks.get(unit_id)
        return 1 if t is None else t.reach

    def acked(self, u: UnitRecord) -> bool:
        """Whether the unit has accepted the squares we last released to it."""
        assert u.state is not None
        t = self.tracks.get(u.id)
        if t is None or t.order_id is None:
            return True
        return acknowledges(u.state, t.order_id, t.content_update)

    def settled(self, u: UnitRecord) -> bool:
        """Acknowledged, with nothing left to drive: it may get a new move."""
        assert u.state is not None
        return self.acked(u) and not u.state.released

    def reserved(self, u: UnitRecord) -> set[Cell]:
        """Squares besides its own that nobody else may enter: what the unit may still drive.

        A lost unit's too, for as long as it is lost: unheard, it may have driven them (a unit
        cut off holds still only after a few periods without orders, a VDA 5050 vehicle drives
        its whole base), so it may stand on any of them now (protocol.md §8).
        """
        assert u.state is not None
        t = self.tracks.get(u.id)
        out = set(u.state.released)
        if t is not None and not self.acked(u):
            out |= t.unacked
        return out

    def order(self, u: UnitRecord, step: StepContext) -> OrderPlan:
        """This step's order for an active unit: a new move, its remaining squares, or a halt order.

        A unit `held` by an operator gets a halt order. With a `window` > 1, a unit whose squares
        are known exactly (it settled with a move, or acknowledged what it drives) gets its way
        topped up (`_ahead`) to as many squares as it has needed ahead so far, at most `window`
        (window.py). Sent when it changes anything, else only once `heartbeat_s` have passed
        since the last (a repeat costs the broker, the unit and us a round trip, and tells the
        unit nothing).
        """
        assert u.state is not None
        st = u.state
        settled, estop, window = u.id in step.settled, step.estop, step.window
        target, now = step.targets.get(u.id), step.now
        t = self.track(u.id)
        pos = st.position
        if self.acked(u):
            t.unacked = set()  # what it may still drive is exactly its reported `released`
        elif t.sent and not st.released and st.status != "waiting":
            # It drove all it had before our latest squares reached it: a round trip lost.
            t.reach = min(window, t.reach + 1)
        if settled or estop or st.estop:
            t.waiting = 0
        elif st.status == "waiting":
            t.waiting += 1
        exact = False  # whether `released` is exactly what the unit will drive
        if estop or t.forged or u.id in step.held:
            released: list[Cell] = []
        elif settled:
            move = step.moves.get(u.id)
            released = [move] if move is not None and move != pos else []
            exact = True
        else:
            remaining = self._remaining(u, t)
            way_out = step.leaving.get(u.id, frozenset())
            blocked = any(not step.grid.is_free(c) and c not in way_out for c in remaining)
            released = [] if blocked or t.waiting >= WAIT_BEFORE_HOLD else remaining
            exact = self.acked(u) and st.status != "waiting"
        room = min(window, t.reach) - len(released)
        if exact and released and room > 0 and target is not None and released[-1] != target:
            ahead = _ahead(step, u.id, pos, target, released[-1], room)
            released = released + _no_return(ahead, pos, released)
        t.forged = False
        if target != t.target or t.order_id is None:
            t.route_no += 1
            t.order_id = f"{self.nonce}-{u.id}-{t.route_no}"
            t.update_id = 0
            t.target = target
            t.content_update = 0
            t.acked_update = 0
        action = None if estop else step.actions.get(u.id)
        charge = None if estop else step.charges.get(u.id)  # a heartbeat repeats it
        content = released != t.sent or t.content_update == 0  # awaits an acknowledgement
        send = (
            content
            or action != t.action
            or charge != t.charge
            or now - t.sent_at >= step.heartbeat_s
        )
        if send:
            t.update_id += 1
            t.sent_at, t.action, t.charge = now, action, charge
        if content:
            t.content_update = t.update_id
            t.unacked |= set(released)
            t.sent = released
            t.waiting = 0
        planned: list[Cell] = []
        if target is not None and not estop:
            start = released[-1] if released else pos
            planned = step.router.route(start, target, PLANNED_SHOWN, u.id)
        return OrderPlan(
            order_id=t.order_id,
            update_id=t.update_id,
            step=step.step_no,
            released=released,
            planned=planned,
            target=target,
            action=action,
            send=send,
            charge=charge,
        )

    def _remaining(self, u: UnitRecord, t: Track) -> list[Cell]:
        assert u.state is not None
        st = u.state
        if self.acked(u) or not t.sent:
            return list(st.released)
        pos = st.position
        if pos in t.sent:
            return t.sent[t.sent.index(pos) + 1 :]
        return list(t.sent) if t.sent[0].manhattan(pos) == 1 else []

    def expect(self, plans: dict[str, OrderPlan]) -> None:
        """Await an acknowledgement of each of this step's orders that changes the unit's squares.

        A heartbeat (the same squares again) needs none of its own: a unit answers it with its
        next state, which may come a few steps later (protocol.md §4.1); until the squares it
        repeats are acknowledged, it is their acknowledgement that is awaited.
        """
        self.awaiting = {}
        for u, p in plans.items():
            t = self.track(u)
            if t.content_update > t.acked_update:
                self.awaiting[u] = (p.order_id, t.content_update)
        self._late_allowed = len(self.awaiting) // LATE_SHARE

    @property
    def holding_back(self) -> bool:
        """Whether the next step should wait: more than a third of the units ordered owe acks.

        A late unit gets no new squares until its state shows it settled, whatever the step (the
        planner moves settled units only), so waiting for the slowest of a hundred would only
        slow the others; when most acknowledgements are late (an overloaded broker), waiting
        keeps steps from piling more orders onto it.
        """
        return len(self.awaiting) > self._late_allowed

    def heard(self, unit_id: str, state: UnitState) -> str | None:
        """A unit's state arrived: it may acknowledge the order awaited from it.

        Returns a problem when the state follows an update of our order that we never sent: a
        forged order (same order id, a jumped update id), which would make every later real
        update look stale to the unit. The unit then gets a halt order under a new order id, which
        it takes at once.
        """
        t = self.tracks.get(unit_id)
        if t is not None and follows_unsent(state, t):
            problem = (
                f"unit {unit_id} follows update {state.order_update_id} of order {t.order_id}, "
                f"which was never sent (the latest is {t.update_id}): a forged order; it gets a "
                "halt order under a new order"
            )
            t.order_id, t.forged = None, True
            self.awaiting.pop(unit_id, None)
            return problem
        if t is not None and state.order_id == t.order_id:
            t.acked_update = max(t.acked_update, state.order_update_id)
        awaited = self.awaiting.get(unit_id)
        if awaited is not None and acknowledges(state, *awaited):
            del self.awaiting[unit_id]
        return None

    def halt_orders(self, unit_ids: list[str], step_no: int) -> dict[str, OrderPlan]:
        """An update releasing nothing for each unit that has had an order; nothing is awaited."""
        self.awaiting.clear()  # holds need no acknowledgement before the next step
        out = {}
        for unit_id in unit_ids:
            t = self.tracks.get(unit_id)
            if t is None or t.order_id is None:
                continue
            t.update_id += 1
            t.content_update = t.update_id
            t.sent = []
            t.charge = None  # halt orders carry none
            out[unit_id] = OrderPlan(t.order_id, t.update_id, step_no, [], [], None, None)
        return out
