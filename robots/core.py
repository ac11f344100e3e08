"""One unit's side of the protocol, pure: what arrives in, exactly what to publish out.

`UnitCore` wraps a `UnitLogic` with the wire: it reads every inbound topic a unit follows (the stop,
orders, goals, the coordinator's status, its own `connection`), connects, disconnects and steps,
and returns the messages to publish as `Outbound`s, in the order they must leave: the state after
a step that changed something (an accepted order's included) and at once on the stop, the
direction whenever it changed (an order's first move at once), an error report (with the reason)
for every refused message, `online` and the factsheet on connect, and `online` again while
connected whenever its own `connection` reads otherwise (a clustered broker's late last will of
an earlier session, protocol.md §4.1), and `online`, the factsheet and the state again to every
new coordinator session (whose broker may not have given it the retained ones, §5.5). Time comes
in as `now`; headers come from the stamper it is given, so tests can pin every payload.
"""

from __future__ import annotations

from gridfleet.errors import ProtocolError
from gridfleet.grid import Cell
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    TOPICS,
    Connection,
    CoordinatorStatus,
    Goal,
    HeaderStamper,
    Order,
    Topics,
    UnitState,
    decode,
)
from gridfleet.protocol.stop import STOP_KINDS, StopView, stop_filters
from gridfleet.robots.fleet_side import Condition, FleetSide
from gridfleet.robots.sessions import CoordinatorSessions
from gridfleet.robots.unit import Move, Sense, UnitLogic


class Lateness:
    """How much later than the most punctual order lately one arrives (protocol §4.4 rule 7).

    The coordinator's and the unit's clocks need not agree: the least gap between an order's
    header time and its arrival stands for their offset plus the link's delay, and an order is
    late by how much its gap exceeds that. The least gap creeps up by `RELAX_S_PER_S` a second,
    so a clock that slews (or a route that gets slower for good) is followed, while a queue that
    piles up on a thin link, seconds a second, is not.
    """

    RELAX_S_PER_S = 0.05

    def __init__(self) -> None:
        self._least: float | None = None
        self._at = 0.0

    def reset(self) -> None:
        """A new session or a new coordinator (another clock, perhaps): learn afresh."""
        self._least = None

    def late_by(self, gap_s: float, now: float) -> float:
        """How late an order with this gap (arrival minus header time) is, in seconds."""
        if self._least is None:
            self._least = gap_s
        else:
            self._least = min(self._least + self.RELAX_S_PER_S * max(0.0, now - self._at), gap_s)
        self._at = now
        return gap_s - self._least


class UnitCore:
    """A unit's decisions on the wire: inbound topics, connects and steps in; `Outbound`s out."""

    def __init__(
        self,
        logic: UnitLogic,
        topics: Topics,
        *,
        color: str = "#607d8b",
        stamp: HeaderStamper | None = None,
        model: str = "gridfleet-sim",
    ) -> None:
        self.logic = logic
        self.topics = topics
        self.color = color
        self.model = model  # the factsheet's `model`: what kind of unit this is
        self.id = logic.unit_id
        self.stamp = stamp or HeaderStamper(self.id)
        self.side = FleetSide(self.id, topics, self.stamp)  # what it says to the fleet, and when
        self.stop = StopView()  # the latch and the held presses, as this unit read them
        self.map_id = logic.grid.map_id()  # the static map, before any obstacle is found
        self.lateness = Lateness()  # of orders, against this unit's own clock (its stamper's)
        self.leaving = False  # its clean stop's `offline` is made: its record is not set right
        # Times its own `connection` read other than `online` while connected, and it said
        # `online` again (a late last will of an earlier session; tests and logs watch it).
        self.connection_corrections = 0
        # The coordinator sessions told who it is on this connection (protocol.md §5.5).
        self.sessions = CoordinatorSessions()
        self.announcements = 0  # times it told a new coordinator session again (tests watch it)

    def subscriptions(self, watch_peers: bool = False) -> list[tuple[str, int]]:
        """Topics to follow with their subscription QoS; `watch_peers` adds every unit's state."""
        t = self.topics
        topics: list[str] = []
        if self.logic.mode == "coordinated":
            topics += [t.unit("order", self.id), t.fleet("coordinator")]
        else:
            topics.append(t.unit("goal", self.id))
        # Its own record, set right while connected (protocol.md §4.1).
        topics.append(t.unit("connection", self.id))
        if watch_peers:
            topics.append(t.all_units("state"))
        return [*stop_filters(t), *((topic, SUBSCRIBE_QOS) for topic in topics)]

    # ---- the session --------------------------------------------------------------------------

    def start(self, now: float) -> None:
        """The unit starts at `now`, not connected yet: it holds still until it is."""
        self.logic.start(now)
        self.logic.on_disconnect(now, first=True)

    def will(self) -> Outbound:
        """The last will of the coming connection: `broken` (stamped before its `online`)."""
        return self.side.connection("broken")

    def on_connect(self, now: float) -> list[Outbound]:
        """Connected and subscribed: `online`, the factsheet, then the state and direction."""
        self.logic.on_connect(now)
        self.leaving = False
        self.lateness.reset()  # a new session: whatever piled up on the old one is gone
        self.side.new_connection()  # say the direction again
        return [self.side.connection("online"), self._factsheet(), *self.state()]

    def _factsheet(self) -> Outbound:
        """Its factsheet, with a fresh header."""
        return self.side.factsheet(
            capacity_kg=self.logic.capacity_kg,
            step_s=self.logic.step_s,
            color=self.color,
            model=self.model,
            map_id=self.map_id,
            energy=None if self.logic.battery is None else self.logic.battery.model,
        )

    def on_disconnect(self, now: float) -> None:
        """Lost the broker: hold still (nothing can be sent until the next connect), and drive
        nothing released before: it moves again on an order heard on the next connection."""
        # The stop is read afresh from the retained messages: a press cleared meanwhile is not
        # replayed, so one kept from before would hold the unit for good.
        self.stop = StopView()
        self.sessions.reset()  # the next connection announces itself anyway
        self.logic.on_disconnect(now)

    def offline(self) -> Outbound:
        """The goodbye of a clean stop (its own `offline`, read back, is not set right)."""
        self.leaving = True
        return self.side.connection("offline")

    # ---- what arrives -------------------------------------------------------------------------

    def on_message(
        self, topic: str, payload: bytes, now: float, *, retained: bool = False
    ) -> list[Outbound]:
        """React to one inbound message; what to publish because of it.

        `retained`: the broker replayed it on subscribing (MQTT's retain flag on delivery).
        """
        where = self.side.parse(topic)
        if where is None:
            return []
        kind, who = where
        if kind in STOP_KINDS:
            return self._on_stop(kind, who, topic, payload, now)
        if kind == "order" and who == self.id:
            return self._on_order(topic, payload, now)
        if kind == "goal" and who == self.id:
            return self._on_goal(topic, payload, now)
        if kind == "connection" and who == self.id:
            return self._on_own_connection(topic, payload)
        if kind == "coordinator":
            return self._on_coordinator(topic, payload, retained)
        return []

    def _on_coordinator(self, topic: str, payload: bytes, retained: bool) -> list[Outbound]:
        """The coordinator's status: its step period sizes the hold timeout; a new session of
        it is told again who this unit is (`online`, the factsheet and the state, fresh headers):
        its broker may not have given it the retained ones (RabbitMQ's retained messages are
        each node's own and never reach a wildcard subscription; a broker restarted empty)."""
        if not payload:
            return []  # the retained status cleared (`gridfleet clean`): nothing to read
        try:
            status = decode(CoordinatorStatus, payload)
        except ProtocolError as exc:
            # Nothing changes (the hold timeout stays), and the unit says why (§7); not in
            # its state's errors: the fault is the coordinator's, not the unit's.
            return [self.side.report(topic, str(exc))]
        new = self.sessions.new_session(status, retained=retained)
        if new or status.header.seq == 0:
            self.lateness.reset()  # a coordinator (re)started: its clock may be another's
        self.logic.on_coordinator(status.step_period_s)
        if not new or not self.logic.connected or self.leaving:
            return []
        self.announcements += 1
        return [self.side.connection("online"), self._factsheet(), *self.state()]

    def _on_own_connection(self, topic: str, payload: bytes) -> list[Outbound]:
        """Its own `connection` read back: anything but `online` while connected is set right.

        On a clustered broker a node that dies leaves its clients' last wills to a survivor,
        which may publish them seconds to minutes later: by then the unit may be online on
        another node, and its old session's `broken` would stand as its record (retained) for
        the coordinator and everyone who reads it later. The unit says `online` again, with a
        fresh header. Its own `online` read back changes nothing; nor does a cleared record (an
        empty payload: a removed unit's, §6.11), nor anything once its clean stop's `offline` is
        made, nor anything while disconnected (the next connection says `online` anyway).
        """
        if not payload or not self.logic.connected or self.leaving:
            return []
        try:
            said = decode(Connection, payload)
        except ProtocolError as exc:
            return [self.side.report(topic, str(exc))]  # nothing to set right by
        if said.state == "online":
            return []
        self.connection_corrections += 1
        return [self.side.connection("online")]

    def _on_stop(
        self, kind: str, who: str | None, topic: str, payload: bytes, now: float
    ) -> list[Outbound]:
        try:
            self.stop.apply(kind, who, topic, payload)
        except ProtocolError as exc:
            # Never a release: a bad payload changes nothing.
            return self._refused(topic, "bad_estop", str(exc))
        self.logic.on_estop(self.stop.engaged, now)
        return self.state()

    def _on_order(self, topic: str, payload: bytes, now: float) -> list[Outbound]:
        try:
            order = decode(Order, payload, TOPICS["order"].max_bytes)
        except ProtocolError as exc:
            return self._refused(topic, "bad_order", str(exc))
        gap = (self.stamp.now() - order.header.timestamp).total_seconds()
        late = self.lateness.late_by(gap, now)
        if self.logic.mode == "coordinated" and late > self.logic.late_order_s:
            # The link is piling orders up, and the stop may be queued behind them. Told on
            # `errors` once a spell, at most every 10 s.
            if self.logic.on_late_order(late, now):
                return [self.side.report(topic, self.logic.errors[-1].message), *self.state()]
            return []
        verdict = self.logic.on_order(order, now)
        if verdict.result == "refused":
            return [self.side.report(topic, verdict.reason or ""), *self.state()]
        if verdict.result != "accepted":
            return []
        # The order is acknowledged by the next step's state, which usually shows the move it
        # released too; the LEDs show that move at once.
        return self.direction()

    def _on_goal(self, topic: str, payload: bytes, now: float) -> list[Outbound]:
        try:
            goal = decode(Goal, payload, TOPICS["goal"].max_bytes)
        except ProtocolError as exc:
            return self._refused(topic, "bad_goal", str(exc))
        target = goal.target
        verdict = self.logic.on_goal(target, now)
        if verdict.result == "refused":
            return [self.side.report(topic, verdict.reason or ""), *self.state()]
        return self.state() if verdict.result == "accepted" else []

    def _refused(self, topic: str, code: str, reason: str) -> list[Outbound]:
        """A payload that could not be read: an error in the state and a report on `errors`."""
        self.logic.error(code, reason)
        return [self.side.report(topic, reason), *self.state()]

    def peer_position(self, topic: str, payload: bytes) -> tuple[str, Cell] | None:
        """Where another unit says it stands, when this is its state; else None."""
        where = self.side.parse(topic)
        if where is None:
            return None
        kind, who = where
        if kind != "state" or who is None or who == self.id:
            return None
        try:
            state = decode(UnitState, payload)
        except ProtocolError:
            return None
        return who, state.position

    # ---- the step -----------------------------------------------------------------------------

    def tick(self, sense: Sense, move: Move, now: float) -> list[Outbound]:
        """One step in the world `sense` reads and `move` changes; the state (and direction)."""
        self.logic.tick(sense, move, now)
        if not self.side.due(self._condition()):
            return []  # nothing to tell but the step count: the next change or heartbeat will
        return self.state()

    def _condition(self) -> Condition:
        """What a state would say, but its header and step count; None while news is pending."""
        lg = self.logic
        if lg.new_obstacles or lg.errors:
            return None
        # The battery only by its whole percent: its exact figure changes nearly every step (a
        # move costs 0.5 %, standing a few thousandths), and a unit that sent a state for each
        # would send one every step, every unit, for news nobody acts on. A whole percent is finer
        # than any threshold is set; every state (the heartbeat at least every 3 steps) carries
        # the exact figure anyway, and `charging` goes out the step it changes.
        battery = None if lg.battery is None else lg.battery.whole_pct
        return (
            lg.position,
            lg.direction,
            lg.status,
            lg.wait_reason,
            lg.mode,
            lg.job_id,
            lg.load_kg,
            tuple(lg.sensors.items()),
            lg.order_id,  # not its update id: a heartbeat order changes nothing else
            tuple(lg.released),
            lg.goal,
            lg.estop,
            battery,
            lg.charging,
        )

    def state(self) -> list[Outbound]:
        """The state now, and the direction when it changed; nothing while disconnected.

        Built at once, so a step can never overtake the state that showed its move. Disconnected,
        nothing is built: the obstacles and errors a state reports once wait for the next one.
        """
        if not self.logic.connected:
            return []
        told = self._condition()  # before the report forgets the news it tells once
        state = self.logic.report(self.stamp("state"))
        return self.side.state(state, told, self.logic.direction)

    def direction(self) -> list[Outbound]:
        """The direction, when it changed since it was last sent; nothing while disconnected."""
        if not self.logic.connected:
            return []
        return self.side.direction(self.logic.direction)
