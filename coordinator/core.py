"""The coordinator's decisions, without I/O: what arrived and the time in, everything to do out.

`on_message(topic, payload, now)` and `step(now)` return Effects: the exact messages to publish,
the jobs to persist, the acknowledgements the next step waits for, and when to come back for
batched views. Safety rules (protocol.md §4.4, §8), each in the module named:

- A square stays reserved for a unit until its state shows it left: its reported square, the
  squares it still may drive (`state.released`) and, until it has acknowledged our latest change,
  every square we sent it since its last acknowledgement (orders.py).
- Only *settled* units (acknowledged, nothing left to drive) get new moves; the planner never
  produces a swap, a vertex conflict or a rotation, so releasing a square that a unit is being
  released out of in the same step (following) is the only way into an occupied square, and that
  square is released only once the leader's state shows it gone (moves.py).
- A unit in motion gets its remaining squares again (heartbeat), or a halt order when it has
  waited too long or its way is blocked by a newly known obstacle (orders.py).
- With the emergency stop engaged every unit gets a halt order at once and nothing is planned or
  allocated; orders of a step that release squares and have not gone out when the stop arrives
  are withdrawn (`withdrawn`).
- Closed zones (zones.py) only take squares out of plans: the planner plans on the map with them
  blocked, and a unit inside one is given only the squares of its way out, each when nobody
  stands on, holds or is given it, as any square (`_moves`).

Lost units (connection offline/broken or state silent for 5 step periods): their squares stay
reserved; a job not yet picked up goes back to the queue; a job whose item the unit had already
picked up becomes `failed` (progress.py). An operator who knows one is gone for good removes it
(`remove_unit`, removals.py): forgotten at once, its squares free, its word ignored until it rejoins.
"""

from __future__ import annotations

import logging
import traceback
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import partial

from gridfleet.coordinator import inbound, requests
from gridfleet.coordinator.answers import Answers
from gridfleet.coordinator.audit import READ_ROLES, AuditLog, Identity
from gridfleet.coordinator.chargers import ChargerBook
from gridfleet.coordinator.directives import Directives
from gridfleet.coordinator.effects import Effects, Messages, Status
from gridfleet.coordinator.energy import (
    Battery,
    ChargeNews,
    EnergyPolicy,
    EnergySettings,
    EnergyStep,
)
from gridfleet.coordinator.events import EventLog
from gridfleet.coordinator.inbound import Arrival, Request, StopPayload
from gridfleet.coordinator.inbox import Inbox, Refusals, Waiting
from gridfleet.coordinator.jobs import CARRYING_STATES, Job, JobBook
from gridfleet.coordinator.moves import Moves
from gridfleet.coordinator.orders import OrderPlan, Orders, StepContext, heartbeat_s
from gridfleet.coordinator.pace import StepRate
from gridfleet.coordinator.planning.planner import Planner
from gridfleet.coordinator.progress import JobProgress
from gridfleet.coordinator.records import RecordKind, RecordQuery, range_problem
from gridfleet.coordinator.removals import Removal, Removals
from gridfleet.coordinator.stop import FleetStop
from gridfleet.coordinator.views import Views, views_period_s
from gridfleet.coordinator.waits import (
    Stuck,
    StuckNews,
    Wait,
    blocker,
    explain_waits,
    stuck_after_s,
)
from gridfleet.coordinator.window import DEFAULT_WINDOW, MAX_WINDOW, Claims
from gridfleet.coordinator.world import UnitRecord, World
from gridfleet.coordinator.zones import (
    Exits,
    WayOut,
    ZoneBook,
    clipped,
    closed_words,
    cut_words,
    leaving_moves,
    rectangle,
)
from gridfleet.errors import ProtocolError
from gridfleet.failures import FailureReports
from gridfleet.grid import Cell, GridMap
from gridfleet.outbound import Outbound
from gridfleet.paths import UNREACHABLE, DistanceFieldCache, route
from gridfleet.protocol import (
    Action,
    CancelJob,
    ClearObstacles,
    CloseZone,
    Connection,
    ControlUnit,
    Factsheet,
    HeaderStamper,
    JobHistoryQuery,
    OpenZone,
    RemoveUnit,
    RouteView,
    SetGoal,
    SubmitJob,
    Topics,
    UnitState,
)
from gridfleet.protocol.constants import MIN_TIMEOUT_S, REMOVED_UNIT_KINDS
from gridfleet.protocol.messages import (
    AuditLogin,
    AuditQuery,
    ChargeEntry,
    UnitControlState,
    Zone,
)

# A step that sent new squares waits for the units' acknowledgements (their states) until a step
# period after it, or this long when the period is shorter, and only while more than a third of
# them are missing: half the shortest hold timeout, so units never hold for want of orders.
ACK_WAIT_S = MIN_TIMEOUT_S / 2

Note = tuple[int, str]  # a line for the shell's log: (logging level, text)
# Requests the inbox takes (answered by `serve`, urgent kinds and each account in turn).
QUEUED = (
    SubmitJob,
    CancelJob,
    SetGoal,
    ControlUnit,
    ClearObstacles,
    RemoveUnit,
    CloseZone,
    OpenZone,
    JobHistoryQuery,
)
# What the coordinator reads of a unit: none of it counts from a unit removed until it rejoins.
UNIT_WORD = ("connection", "factsheet", "state")


@dataclass(frozen=True)
class StepResult:
    """What one step decided."""

    step: int
    orders: dict[str, OrderPlan]
    routes: dict[str, RouteView]


class CoordinatorCore:
    """World, jobs, allocation, planning and what to say; pure (time comes in as an argument)."""

    def __init__(
        self,
        world: World,
        jobs: JobBook,
        nonce: str,
        seed: int = 0,
        *,
        topics: Topics | None = None,
        stamp: HeaderStamper | None = None,
        controls: Mapping[str, UnitControlState] | None = None,
        window: int = DEFAULT_WINDOW,
        identity: Identity | None = None,
        removals: Mapping[str, Removal] | None = None,
        energy: EnergySettings | None = None,
        zones: Iterable[Zone] = (),
    ) -> None:
        if not 1 <= window <= MAX_WINDOW:
            raise ValueError(f"window {window}: give 1 to {MAX_WINDOW} squares")
        settings = energy or EnergySettings()
        problem = settings.problem()
        if problem is not None:
            raise ValueError(f"charging thresholds: {problem}")
        self.window = window  # squares a unit may be released ahead (window.py)
        self.world = world
        self.jobs = jobs
        self.topics = topics or Topics()
        self._own_status = self.topics.fleet("coordinator")
        self.say = Messages(self.topics, stamp or HeaderStamper("coordinator"))
        # Closed zones (kept across restarts): blocked for planning, but for a unit leaving one.
        self.zones = ZoneBook(world.base.width, world.base.height, zones)
        self.exits = Exits()  # each unit inside a closed zone: its way out
        self._plain: DistanceFieldCache | None = None  # distances on the map, zones open
        self._zone_told: dict[str, str] = {}  # unit -> what the events last said of it inside
        self.planner = Planner(self._planning_grid(), seed=seed)
        self.step_no = 0
        self.stop = FleetStop(self.topics)  # the emergency stop, its state and what it says
        self._free_since = float("-inf")  # the latest step under the stop (jobs stuck: after it)
        self.stuck_news = StuckNews()  # jobs whose stuck unit the events told already
        # Operators' goals and controls (paused, out of service; kept across restarts).
        self.directives = Directives(controls)
        self.orders = Orders(nonce)
        self._heartbeat_s = heartbeat_s(world.step_period_s)
        self.moves = Moves(self.planner)
        self.progress = JobProgress(world, jobs, self.directives)
        self.views = Views(period_s=views_period_s(world.step_period_s))
        self.answers = Answers()  # a retried request gets its first answer (answers.py)
        self.pace = StepRate()
        self.errors_reported = 0
        self.events = EventLog()  # the recent history, in words (fleet/events)
        self.identity = identity or Identity()
        self.audit = AuditLog(self.identity)  # who did what: operators' requests and the stop
        self.inbox = Inbox()  # requests waiting for `serve` (the shell's; tests answer at once)
        self.inbox_refusals = Refusals()
        # Units an operator removed for good (kept across restarts): ignored until they rejoin.
        self.removals = Removals(removals)
        # Its own failures on messages (bugs): told on `errors` by the class alone, at most once
        # a second per topic (gridfleet/failures.py); those held back go out with the steps.
        self.failures = FailureReports("coordinator")
        # Who charges where, and how far each unit may still drive (energy.py, chargers.py).
        self.energy = EnergyPolicy(settings, ChargerBook(world.chargers), world.step_period_s)
        self._charges: list[ChargeEntry] = []  # charges started and ended, for the history
        self.events.know(jobs.jobs.values())
        self.progress.requeue_on_restart()

    # ---- the session ----------------------------------------------------------------------

    def restored(self) -> Effects:
        """What loading the job store changed (jobs re-queued on restart), to persist."""
        return self._effects([], self._persist())

    def subscriptions(self) -> list[tuple[str, int]]:
        """Every topic filter to follow, with its QoS."""
        return inbound.subscriptions(self.topics)

    @property
    def estop(self) -> bool:
        """Whether the fleet is stopped: the latch, or a held press."""
        return self.stop.engaged

    def status(self, state: Status) -> Outbound:
        """The retained coordinator status: `online`, `offline`, or `broken` (the last will)."""
        period = self.world.step_period_s
        return self.say.status(state, self.step_no, period, self.estop, self.pace.achieved_step_s)

    def on_connect(self, now: float = 0.0, *, moved: bool = False) -> Effects:
        """Connected (and `online` said): every view goes out again, and the clears of removed
        units whose clear has not come back yet.

        `moved`: this session is on another broker than the one before (a failover): its
        retained latch is not taken as a release of the stop held (stop.py, protocol.md §5.1).
        """
        self.stop.connected(now, moved)
        self.world.listening(now)  # its own time away is no unit's silence
        self.views.reconnected()
        self.events.dirty = True  # the history goes out again with the other views
        self.energy.dirty = True
        self.zones.dirty = True  # the zones view goes out at start and after every reconnect
        persist = self._persist()
        notes: list[Note] = []
        clears = [out for unit in self.removals.uncleared() for out in self._clears(unit)]
        return self._effects([*clears, *self._views(notes)], persist, log=notes)

    def halt_orders(self) -> Effects:
        """A halt order for every unit now (a clean stop; the emergency stop does the same)."""
        return self._effects(self._halt_orders())

    def views_due(self, now: float) -> Effects:
        """The batch period `views_at` named is over: the views changed since go out."""
        self.views.batch_over()
        notes: list[Note] = []
        return self._effects(self._views(notes, now), log=notes)

    def withdrawn(self, out: Outbound) -> bool:
        """Whether a message returned by the last step must not go out after all (the stop's)."""
        return self.stop.withdrawn(out)

    # ---- inbound --------------------------------------------------------------------------

    def on_message(
        self, topic: str, payload: bytes, now: float, *, retained: bool = False
    ) -> Effects:
        """React to one message; a bad one is reported on `errors` and changes nothing.

        `retained`: the broker replayed it from what it kept, on subscribing (the stop reads a
        failover's retained latch with care: stop.py).
        """
        arrival = self._read(topic, payload, now)
        if isinstance(arrival, Effects):
            return arrival
        return self._guarded(topic, arrival, now, retained)

    def offer(
        self, topic: str, payload: bytes, now: float, *, retained: bool = False
    ) -> tuple[Effects, bool]:
        """Like `on_message`, but a readable request waits in the inbox for `serve_one`.

        (its Effects, whether it waits); refused at once, in words, when its account has too
        many waiting (inbox.py).
        """
        arrival = self._read(topic, payload, now)
        if isinstance(arrival, Effects):
            return arrival, False
        if not isinstance(arrival.message, QUEUED):
            return self._guarded(topic, arrival, now, retained), False
        req = arrival.message
        account, _ = self.identity.actor(req.header.sender)
        refusal = self.inbox.offer(Waiting(account, arrival.kind, topic, arrival))
        if refusal is None:
            return self._effects([]), True
        publish: list[Outbound] = []
        notes: list[Note] = []
        if req.reply_to is not None:
            outcome = requests.Outcome(False, refusal, code="too_many")
            publish.append(self.say.reply(req.reply_to, req.request_id, outcome))
        reason = f"{type(req).__name__}: {refusal}"
        if self.inbox_refusals.refused(account, topic, reason, now):
            publish.append(self._refuse(topic, reason, req.request_id, notes))
        else:
            self.errors_reported += 1  # refused all the same: told with the others in a second
        return self._effects(publish, log=notes), False

    def serve_one(self, now: float) -> tuple[str, Effects] | None:
        """Answer the next waiting request (urgent kinds first, each account in turn): its topic
        and Effects; None when none waits."""
        waiting = self.inbox.take()
        if waiting is None:
            return None
        return waiting.topic, self._guarded(waiting.topic, waiting.arrival, now)

    def _read(self, topic: str, payload: bytes, now: float) -> Arrival | Effects:
        """The message decoded; or, for one to ignore or refuse, the Effects of that."""
        self.world.heard(now)  # whatever it says, the coordinator can hear
        if not payload:
            cleared = self._cleared(topic)
            if cleared is not None:
                return cleared
        if topic == self._own_status:
            self.world.heard_itself = True  # and every retained factsheet has arrived
        try:
            arrival = inbound.read(self.topics, topic, payload)
        except ProtocolError as exc:
            notes: list[Note] = []
            refused = self._refuse_unreadable(topic, payload, str(exc), notes)
            return self._effects([*refused, *self.stop.heal(topic)], log=notes)
        except Exception as exc:  # a bug must not take the coordinator down: say so, carry on
            return self._failed(topic, exc, now)
        return self._effects([]) if arrival is None else arrival

    def _guarded(self, topic: str, arrival: Arrival, now: float, retained: bool = False) -> Effects:
        """`_on`, with a refusal or a bug reported instead of raised."""
        try:
            return self._on(arrival, topic, now, retained)
        except ProtocolError as exc:
            notes: list[Note] = []
            request_id = getattr(arrival.message, "request_id", None)
            reply_to = getattr(arrival.message, "reply_to", None)
            refused = [self._refuse(topic, str(exc), request_id, notes)]
            if request_id is not None and reply_to is not None:
                outcome = requests.Outcome(False, str(exc), code="invalid")
                refused.append(self.say.reply(reply_to, request_id, outcome))
            return self._effects([*refused, *self.stop.heal(topic)], log=notes)
        except Exception as exc:  # a bug must not take the coordinator down: say so, carry on
            return self._failed(topic, exc, now)

    def _failed(self, topic: str, exc: Exception, now: float) -> Effects:
        """A fault of its own on a message: logged with its traceback, told by its class alone.

        What the message changed before the fault stays (nothing of it is stored or published
        now; the next step plans from the world as it is); nothing else is undone.
        """
        reason = self.failures.failed(topic, type(exc).__name__, now)
        if reason is None:  # told with the next report on this topic (`step`)
            return self._effects([], log=[(logging.DEBUG, f"failed again on {topic}: {exc!r}")])
        notes: list[Note] = [(logging.ERROR, f"failed on a message on {topic}: {_traced(exc)}")]
        report = self._refuse(topic, reason, None, notes)
        return self._effects([report], log=notes)

    def _held_failures(self, now: float, notes: list[Note]) -> list[Outbound]:
        """The reports of its own failures held back (one a second per topic) that are due."""
        return [self._refuse(topic, held, None, notes) for topic, held in self.failures.due(now)]

    def _refuse_unreadable(
        self, topic: str, payload: bytes, reason: str, notes: list[Note]
    ) -> list[Outbound]:
        """A refused message; a request whose reply address can still be read gets its reply."""
        request_id, reply_to = inbound.reply_address(self.topics, topic, payload)
        refused = [self._refuse(topic, reason, request_id, notes)]
        if request_id is not None and reply_to is not None:
            if self.topics.parse(topic)[0] == "audit":  # the audit's answer is its page (§6.8)
                refused.append(self.say.page("audit", reply_to, request_id, refused=reason))
            else:
                outcome = requests.Outcome(False, reason, code="invalid")
                refused.append(self.say.reply(reply_to, request_id, outcome))
        return refused

    def _on(self, arrival: Arrival, topic: str, now: float, retained: bool = False) -> Effects:
        msg = arrival.message
        unit = arrival.unit
        if unit is not None and unit in self.removals and arrival.kind in UNIT_WORD:
            ignored = self._from_removed(unit, arrival.kind, msg)
            if ignored is not None:
                return ignored
        if isinstance(msg, Factsheet) and unit is not None and self.world.on_foreign(unit, msg):
            # Left on the broker by a run on another map (same root): not part of this fleet.
            line = f"unit {unit} drives on another map ({msg.map_id}, ours {self.world.map_id}): ignored"
            return self._effects([], log=((logging.WARNING, line),))
        if unit is not None and unit in self.world.foreign:
            return self._effects([])
        if isinstance(msg, Connection) and unit is not None:
            before = self.world.units[unit].connection if unit in self.world.units else None
            self.world.on_connection(unit, msg)
            if msg.state != before:
                self.events.unit_changed(self.say.stamp.now(), unit, msg.state)
        elif isinstance(msg, Factsheet) and unit is not None:
            self.world.on_factsheet(unit, msg)
        elif isinstance(msg, UnitState) and unit is not None:
            # Out of service, a unit may be moved by hand: it comes back wherever it is put.
            moved_by_hand = self.directives.controls.get(unit) == "out_of_service"
            reach = self.orders.reach(unit)  # a window may be driven at once (world.motion)
            known = self.world.units.get(unit)
            # Where it may stand after a silence: the squares released to it, kept for it.
            mine = frozenset(self.orders.reserved(known)) if known and known.state else frozenset()
            if self.world.on_state(
                unit, msg, now, relocatable=moved_by_hand, reach=reach, reserved=mine
            ):
                self._replan()  # re-plan around the new obstacles
                self.views.map_dirty = True
            forged = self.orders.heard(unit, msg)
            if forged is not None:  # the state is the unit's own; the order it follows is not
                self.errors_reported += 1
                error = self.say.error(topic, forged, None)
                return self._effects([error], log=((logging.WARNING, forged),))
        elif isinstance(msg, StopPayload):
            return self._on_stop(arrival.kind, unit, topic, msg.payload, retained)
        elif isinstance(
            msg,
            SubmitJob
            | CancelJob
            | SetGoal
            | ControlUnit
            | ClearObstacles
            | RemoveUnit
            | CloseZone
            | OpenZone,
        ):
            return self._on_request(topic, msg, now)
        elif isinstance(msg, JobHistoryQuery):
            return self._on_query(topic, "job_history", msg)
        elif isinstance(msg, AuditQuery):
            return self._on_query(topic, "audit", msg)
        elif isinstance(msg, AuditLogin):
            return self._on_login(topic, msg)
        return self._effects([])

    def _on_query(
        self, topic: str, kind: RecordKind, query: JobHistoryQuery | AuditQuery
    ) -> Effects:
        """A record query (records.py): checked here, answered by the shell from its store."""
        now = self.say.stamp.now()
        sender = query.header.sender
        why = (
            self.identity.refusal(sender, READ_ROLES, "read the audit") if kind == "audit" else None
        )
        why = why or range_problem(query.since, query.until, now)
        if why is None:
            if query.reply_to is None:
                return self._effects([])  # nobody to tell
            return replace(self._effects([]), records=(RecordQuery.of(kind, query, now),))
        notes: list[Note] = []
        publish = [self._refuse(topic, f"{type(query).__name__}: {why}", query.request_id, notes)]
        if query.reply_to is not None:
            publish.append(self.say.page(kind, query.reply_to, query.request_id, refused=why))
        return self._effects(publish, log=notes)

    def _on_login(self, topic: str, report: AuditLogin) -> Effects:
        """A dashboard's login report: recorded once by the audit (audit.py), or refused."""
        why = self.audit.login(report)
        notes: list[Note] = []
        publish = []
        if why is not None:
            publish.append(self._refuse(topic, f"AuditLogin: {why}", report.request_id, notes))
        if report.reply_to is not None:
            outcome = requests.Outcome(why is None, why, code=None if why is None else "forbidden")
            publish.append(self.say.reply(report.reply_to, report.request_id, outcome))
        return self._effects(publish, log=notes)

    def _on_stop(
        self, kind: str, source: str | None, topic: str, payload: bytes, retained: bool = False
    ) -> Effects:
        """The latch or a press (protocol.md §5.1); a bad payload raises before changing anything."""
        news = self.stop.on_payload(kind, source, topic, payload, retained)
        if news.stale is not None:  # nothing applied: no act for the audit, the fleet as it was
            self.events.add(self.say.stamp.now(), "stop", news.stale)
            return self._effects(news.publish, log=((logging.WARNING, news.stale),))
        self.audit.stop(self.say.stamp.now(), kind, source, topic, payload)  # valid: applied
        if news.line is None:
            return self._effects(news.publish)
        self.events.add(self.say.stamp.now(), "stop", news.line)
        publish = list(news.publish)
        # The stop wins at once: every unit gets a halt order now, not at the next step.
        if self.estop:
            publish += self._halt_orders()
        publish.append(self.status("online"))
        return self._effects(publish, log=((logging.WARNING, news.line),))

    def _on_request(self, topic: str, req: Request, now: float) -> Effects:
        sender = req.header.sender
        known = self.answers.recall(req)  # a retry gets its first answer and changes nothing
        notes: list[Note] = []
        controls: tuple[tuple[str, UnitControlState | None], ...] = ()  # to persist
        publish: list[Outbound] = []  # a removed unit's topics cleared go out before the reply
        if known is not None:
            outcome = known
        else:
            ctx = requests.RequestContext(
                world=self.world,
                jobs=self.jobs,
                directives=self.directives,
                cache=self.map_cache,  # what a job needs for good: zones open again
                step_no=self.step_no,
                sender=sender,
                account=partial(self._open_jobs_of, sender),
                requeue=self.progress.requeue,
                now=now,
                energy=self.energy,
                zones=self.zones,
                at=self.say.stamp.now(),
                actor=self.identity.actor(sender)[0],
            )
            version = self.zones.version
            outcome = requests.HANDLERS[type(req)](req, ctx)
            if self.zones.version != version:
                self._zone_changed(req, sender)
            controls = tuple(ctx.controls)
            for unit in ctx.removed:
                clears, lifted = self._forget(unit, sender, getattr(req, "reason", None))
                publish += clears
                controls += lifted
            cleared = ctx.cleared
            if cleared:
                self._replan()
                self.views.map_dirty = True
                squares = ", ".join(str(list(c)) for c in cleared[:20])
                more = f" and {len(cleared) - 20} more" if len(cleared) > 20 else ""
                # In the log, not the events view: its kinds (§5.7) have none for the map.
                notes.append((logging.WARNING, f"obstacles cleared by {sender}: {squares}{more}"))
        if known is None:  # a retry is the same act, recorded once
            self.audit.request(self.say.stamp.now(), req, outcome)
        if not outcome.accepted:
            what = f"refused {self.topics.parse(topic)[0]} from {sender}: {outcome.reason}"
            about = (outcome.job_id, getattr(req, "unit", None))  # the job, the unit it concerns
            self.events.add(self.say.stamp.now(), "refusal", what, *about)
            reason = f"{type(req).__name__}: {outcome.reason}"
            publish.append(self._refuse(topic, reason, req.request_id, notes))
        if self.zones.dirty:  # at once, before the reply: its requester may read it next
            publish.append(self._zones_view())
        if req.reply_to is not None:
            publish.append(self.say.reply(req.reply_to, req.request_id, outcome))
        persist = self._persist()
        views_at = None
        if self.views.jobs_dirty:
            # The queue view follows a request at once, or at the end of the batch period.
            now_due, views_at = self.views.after_request(now)
            if now_due:
                publish += self._views(notes, now)
        effects = self._effects(publish, persist, views_at=views_at, log=notes, controls=controls)
        if known is None:  # a new request: its answer is kept
            effects = replace(effects, answered=(self.answers.remember(req, outcome),))
        return effects

    # ---- units removed for good (protocol.md §6.11) -------------------------------------------

    def _forget(
        self, unit: str, by: str, reason: str | None
    ) -> tuple[list[Outbound], tuple[tuple[str, UnitControlState | None], ...]]:
        """Forget a removed unit everywhere: its squares are free from the next step on, its
        goal and control go; the clears of its retained topics, and the control lifted."""
        at = self.say.stamp.now()
        self.removals.remove(unit, at, by)  # first: a fault below leaves it removed, not new
        self.world.forget(unit)
        self.moves.following.pop(unit, None)  # a square it was to follow into, held under a stop
        self.orders.forget(unit)
        self.progress.forget(unit)
        self.planner.forget(unit)
        self.energy.forget(unit)
        self.directives.set_goal(unit, None)
        lifted: tuple[tuple[str, UnitControlState | None], ...] = ()
        if self.directives.controls.get(unit) is not None:
            self.directives.set_control(unit, None)
            lifted = ((unit, None),)
        why = f": {reason}" if reason else ""
        self.events.add(at, "unit", f"unit {unit} removed by {by}{why}", unit=unit)
        return self._clears(unit), lifted

    def _clears(self, unit: str) -> list[Outbound]:
        """Empty retained messages on a removed unit's topics, its connection last."""
        return [Outbound.of(k, self.topics.unit(k, unit), b"") for k in REMOVED_UNIT_KINDS]

    def _cleared(self, topic: str) -> Effects | None:
        """A unit's retained topic cleared (empty): nothing to read or refuse, whoever cleared it
        (`gridfleet clean`, or its removal's clear come back); None for any other topic."""
        try:
            kind, unit = self.topics.parse(topic)
        except ProtocolError:
            return None
        if unit is None or kind not in UNIT_WORD:
            return None
        if kind == "connection" and unit in self.removals:  # cleared last: the older word is gone
            self.removals.clear_heard(unit)
        return self._effects([])

    def _from_removed(self, unit: str, kind: str, msg: object) -> Effects | None:
        """A removed unit's word: None when it rejoins (as a new unit), else ignored (logged once).

        Its `offline` or `broken` (a last will the broker sends once the dead link's keep-alive
        runs out, after the removal) is cleared again: the page and the status would list it.
        """
        if isinstance(msg, Connection | UnitState) and self.removals.rejoins(unit, msg):
            at = self.say.stamp.now()
            self.events.add(
                at, "unit", f"unit {unit} joins again after its removal, as new", unit=unit
            )
            return None
        again = []
        if isinstance(msg, Connection) and msg.state != "online":
            again.append(Outbound.of("connection", self.topics.unit("connection", unit), b""))
        if not self.removals.first_ignored(unit):
            return self._effects(again)
        removal = self.removals.units[unit]
        line = (
            f"ignored the {kind} of unit {unit}: removed by {removal.by}, it joins again with a "
            "new `online` on its connection, or a state once its clear has come back"
        )
        if not removal.cleared:
            line += (
                " (its retained topics are not cleared yet: may the coordinator's account "
                "write them? protocol.md §10)"
            )
        return self._effects(again, log=((logging.WARNING, line),))

    def _open_jobs_of(self, sender: str | None) -> tuple[str, int] | None:
        """The account of `sender` and how many jobs its senders have not finished."""
        if sender is None:
            return None
        account, _ = self.identity.actor(sender)
        open_by = self.jobs.open_by_submitter().items()
        return account, sum(n for s, n in open_by if s and self.identity.actor(s)[0] == account)

    def _refuse(
        self, topic: str, reason: str, request_id: str | None, notes: list[Note]
    ) -> Outbound:
        """The error report for a refused message (and its line in `notes`, for the log)."""
        self.errors_reported += 1
        notes.append((logging.INFO, f"refused a message on {topic}: {reason}"))
        return self.say.error(topic, reason, request_id)

    # ---- closed zones (zones.py, protocol.md §5.11) -------------------------------------------

    def _planning_grid(self) -> GridMap:
        """The grid the planner plans on: the map with its obstacles, every closed square
        blocked (as a wall, for routing: a unit inside one is moved out by `_moves`)."""
        grid = self.world.grid
        if not self.zones:
            return grid
        return GridMap(grid.blocked | self.zones.mask(), name=grid.name)

    def _replan(self) -> None:
        """Plan on the map as it is now: new obstacles, obstacles cleared, zones closed or opened."""
        self.planner.set_grid(self._planning_grid())

    @property
    def map_cache(self) -> DistanceFieldCache:
        """Distances on the map with its obstacles, every zone open: what a job needs for good
        (a closed zone makes it wait, never fails or rejects it). The planner's own while no
        zone is closed."""
        if not self.zones:
            self._plain = None
            return self.planner.cache
        if self._plain is None or self._plain.grid is not self.world.grid:
            self._plain = DistanceFieldCache(self.world.grid)
        return self._plain

    def _distance(self, start: Cell, target: Cell) -> int:
        """Squares from `start` to `target` as planned: round closed zones, and from inside one
        along its way out first (UNREACHABLE: no such way)."""
        d = self.planner.cache.distance(start, target)
        if d != UNREACHABLE or not self.zones.covers(start):
            return d
        way = self.exits.way_out(self.world.grid, self.zones, start)
        if way is None or not way.path:
            return UNREACHABLE
        rest = self.planner.cache.distance(way.path[-1], target)
        return UNREACHABLE if rest == UNREACHABLE else len(way.path) + rest

    def _zones_view(self) -> Outbound:
        """The retained `fleet/zones`: the zones closed now."""
        view = self.zones.view(self.say.stamp("zones"))
        return Outbound.of("zones", self.topics.fleet("zones"), view)

    def _zone_changed(self, req: Request, sender: str) -> None:
        """A zone closed or opened: planned round from now on, and told in the events."""
        self._replan()
        at = self.say.stamp.now()
        if isinstance(req, CloseZone):
            zone = self.zones.zones[req.name]
            text = f"zone {zone.name} closed by {sender}: {zone.reason} ({rectangle(zone)})"
        else:
            text = f"zone {getattr(req, 'name', '?')} opened by {sender}"
        self.events.add(at, "zone", text)

    def _inside(self, units: list[UnitRecord]) -> dict[str, WayOut]:
        """Every unit standing in a closed zone, with its way out; the events tell once what
        becomes of each (leaving, or held with no way out)."""
        if not self.zones:
            self._zone_told.clear()
            return {}
        out: dict[str, WayOut] = {}
        for u in units:
            assert u.state is not None
            way = self.exits.way_out(self.world.grid, self.zones, u.state.position)
            if way is not None:
                out[u.id] = way
        for uid in [uid for uid in self._zone_told if uid not in out]:
            del self._zone_told[uid]
        for uid, way in out.items():
            note = way.note()
            if self._zone_told.get(uid) == note:
                continue
            self._zone_told[uid] = note
            if way.path is None:
                text = f"unit {uid} holds inside closed zone {way.zone.name}: no way out"
            else:
                n = len(way.path)
                text = (
                    f"unit {uid} leaving closed zone {way.zone.name} by the shortest way "
                    f"({n} square{'s' if n != 1 else ''}, to {list(way.path[-1])})"
                )
            self.events.add(self.say.stamp.now(), "zone", text, unit=uid)
        return out

    def _zone_targets(
        self, units: list[UnitRecord], targets: dict[str, Cell | None], inside: Mapping[str, WayOut]
    ) -> dict[str, str]:
        """Where closed zones send each unit, in `targets`, and why in words (RouteView.note): a
        unit inside one to the end of its way out (none: it holds), a unit whose errand lies in
        one, or is cut off by them, nowhere (it waits outside, keeping its load)."""
        notes: dict[str, str] = {}
        if not self.zones:
            return notes
        for u in units:
            assert u.state is not None
            way = inside.get(u.id)
            if way is not None:
                targets[u.id] = None if way.path is None else way.path[-1]
                notes[u.id] = way.note()
                continue
            target = targets.get(u.id)
            if target is None:
                continue
            closed = self._errand_closed(u.id, target)
            if closed is not None:
                targets[u.id] = None
                notes[u.id] = clipped(f"waiting outside: {closed}")
                continue
            here = u.state.position
            cut = self.planner.cache.distance(here, target) == UNREACHABLE
            if cut and self.map_cache.distance(here, target) != UNREACHABLE:
                targets[u.id] = None
                what = f"to {self._errand(u.id, target)} {list(target)}"
                notes[u.id] = f"waiting: {cut_words(self._cutting(here, target), what)}"
        return notes

    def _errand(self, unit: str, target: Cell) -> str:
        """What `target` is to `unit`, in words: its goal, its job's pickup or dropoff, ..."""
        if self.directives.goals.get(unit) == target:
            return "its goal"
        stray = self.progress.returns.get(unit)
        if stray is not None and stray.square == target:
            return "where it puts an item back"
        job = self.jobs.of_unit(unit)
        if job is not None and target in (job.pickup, job.dropoff):
            return "its dropoff" if job.state in CARRYING_STATES else "its pickup"
        return "its charger"

    def _errand_closed(self, unit: str, target: Cell) -> str | None:
        """Why `unit` is not sent to `target` for a closed zone (its errand there, or its job's
        dropoff when it goes to pick the item up), or None."""
        checks = [(self._errand(unit, target), target)]
        job = self.jobs.of_unit(unit)
        if job is not None and job.state not in CARRYING_STATES and target == job.pickup:
            checks.append(("its dropoff", job.dropoff))  # an item it could not deliver: left
        for what, square in checks:
            zone = self.zones.zone_at(square)
            if zone is not None:
                return f"{what} {list(square)} is in zone {zone.name} (closed: {zone.reason})"
        return None

    def _cutting(self, start: Cell, target: Cell) -> list[Zone]:
        """The closed zones on the shortest way from `start` to `target` with every zone open
        (all of them, should that way cross none)."""
        field = self.map_cache.get(target)
        found: list[Zone] = []
        for c in route(field, start) or []:
            for zone in self.zones.holding(c):
                if zone not in found:
                    found.append(zone)
        return found or list(self.zones.zones.values())

    def _zone_wait(
        self,
        inside: Mapping[str, WayOut],
        cut: dict[tuple[Cell, Cell, float], Wait | None],
        job: Job,
    ) -> Wait | None:
        """Why closed zones hold `job` up (waits.py), or None: its errand in one (`zone_closed`),
        or every way to it cut by them (`unreachable`). `cut`: a queued job's answer, worked out
        once a step for its squares and mass."""
        carrying = job.state in CARRYING_STATES
        for square in (job.dropoff,) if carrying else (job.pickup, job.dropoff):
            zone = self.zones.zone_at(square)
            if zone is not None:
                return ("zone_closed", closed_words(zone))
        if job.state == "queued":
            key = (job.pickup, job.dropoff, job.mass_kg)
            if key not in cut:
                cut[key] = self._queued_cut_off(job)
            return cut[key]
        rec = self.world.units.get(job.unit or "")
        if rec is None or rec.position is None:
            return None
        way = inside.get(rec.id)
        if way is not None:
            if way.path is not None:
                return None  # on its way out
            why = f"its unit {rec.id} is inside closed zone {way.zone.name} with no way out"
            return ("unreachable", why)
        errand = job.dropoff if carrying else job.pickup
        here = rec.position
        if self.planner.cache.distance(here, errand) != UNREACHABLE:
            return None
        if self.map_cache.distance(here, errand) == UNREACHABLE:
            return None  # cut off for good: the job fails (progress.py)
        what = f"from its unit {rec.id} to its {'dropoff' if carrying else 'pickup'} {list(errand)}"
        return ("unreachable", cut_words(self._cutting(here, errand), what))

    def _queued_cut_off(self, job: Job) -> Wait | None:
        """`unreachable` for a queued job no unit able to carry it can do for closed zones."""
        plain, zoned = self.map_cache, self.planner.cache
        if zoned.distance(job.dropoff, job.pickup) == UNREACHABLE:
            if plain.distance(job.dropoff, job.pickup) == UNREACHABLE:
                return None
            what = f"from its pickup {list(job.pickup)} to its dropoff {list(job.dropoff)}"
            return ("unreachable", cut_words(self._cutting(job.pickup, job.dropoff), what))
        capable = [sq for sq, kg in self.world.carriers() if kg >= job.mass_kg]
        if not capable or any(self._distance(sq, job.pickup) != UNREACHABLE for sq in capable):
            return None
        able = [sq for sq in capable if plain.distance(sq, job.pickup) != UNREACHABLE]
        if not able:
            return None  # no zone's doing: rejected or failed (allocation.py)
        what = f"to its pickup {list(job.pickup)} from every unit that can carry {job.mass_kg} kg"
        return ("unreachable", cut_words(self._cutting(able[0], job.pickup), what))

    def _action(self, unit: str) -> Action | None:
        """What `unit` does at the end of its route (progress.py): nothing in a closed zone."""
        action = self.progress.action(unit)
        if action is not None and self.zones.covers(action.square):
            return None
        return action

    # ---- the step ------------------------------------------------------------------------

    def step(self, now: float) -> Effects:
        """One coordinator step: every order (or halt order), the routes and the changed views."""
        publish, reasserted = self.stop.reassert(now)  # first, and even when the step fails
        notes: list[Note] = [] if reasserted is None else [(logging.WARNING, reasserted)]
        try:
            result = self._decide(now)
        except Exception as exc:  # a bug must not take the coordinator down: halt everyone
            notes.append((logging.ERROR, f"step {self.step_no} failed: {_traced(exc)}"))
            # Told as any handler's failure (its class alone, counted by the metric and the
            # alert), on the coordinator's status topic; a storm of them at most once a second.
            status = self.topics.fleet("coordinator")
            failed = [*publish, *self._halt_orders(), *self._held_failures(now, notes)]
            told = self.failures.failed(status, type(exc).__name__, now)
            if told is not None:
                failed.append(self._refuse(status, told, None, notes))
            return self._effects(failed, log=notes)
        persist = self._persist()
        self.orders.expect(result.orders)
        releasing = set()
        for unit_id, plan in result.orders.items():
            if not plan.send:
                continue
            order = self.say.order(unit_id, plan)
            publish.append(order)
            if plan.released:
                releasing.add(order)
        self.stop.releasing(releasing)
        publish.append(self.say.routes(result.step, result.routes))
        if self.views.due(now):
            publish += self._views(notes, now)
        for account, untold in self.inbox_refusals.due(now):
            told = (
                f"{untold.count} more requests of account {account!r} refused in the last "
                f"{self.inbox_refusals.every_s:g} s; the latest: {untold.reason}"
            )
            publish.append(self._refuse(untold.topic, told, None, notes))
        publish += self._held_failures(now, notes)
        if self.pace.stepped(self.step_no, now):  # the achieved step rate, every few seconds
            publish.append(self.status("online"))
        # Back-pressure: when states come back late (an overloaded broker), a step before the
        # units acknowledged these orders would only add load; they could not move on it.
        until = now + max(self.world.step_period_s, ACK_WAIT_S) if result.orders else None
        return self._effects(publish, persist, acks_until=until, log=notes)

    def _in_way_of(self, unit_id: str) -> str | None:
        """The unit standing where `unit_id` would go next (waits.blocker)."""
        target = self.progress.target(unit_id)
        return blocker(unit_id, self.world, target, self.planner.cache.distance)

    def _decide(self, now: float) -> StepResult:
        """Advance jobs, allocate, plan, and make one order per unit that can hear it."""
        self.step_no += 1
        units = [u for u in self.world.units.values() if u.state is not None]
        active = self._roll_call(now)
        self.progress.advance(units, active, now, self.step_no)
        settled = {u.id for u in units if u.id in active and self.orders.settled(u)}
        energy = self._energy(units, active, now)
        self._allocate(units, active, settled, now, energy)
        inside = self._inside(units)  # units in closed zones, and their ways out (zones.py)
        self._explain_waits(now, active, inside)
        targets = {u.id: self.progress.target(u.id) for u in units}
        for uid, square in energy.targets.items():
            if targets.get(uid) is None:  # a job, a goal or an item to put back goes first
                targets[uid] = square
        notes = self._zone_targets(units, targets, inside)
        charges = {uid: sq for uid, sq in energy.targets.items() if targets.get(uid) == sq}
        self._tell_charges(self.energy.take_news())
        moves = self._moves(units, active, settled, targets, energy.standing, inside)
        self._park(targets)
        # While a way out of a livelock is due, searched or followed, no window goes beyond a
        # unit's next square, so units still driving stop and the search can begin (unjam.py).
        window = 1 if self.planner.unjam.busy else self.window
        step = StepContext(
            step_no=self.step_no,
            now=now,
            estop=self.estop,
            grid=self.planner.grid,  # closed zones blocked: but for the ways out (`leaving`)
            heartbeat_s=self._heartbeat_s,
            window=window,
            settled=settled,
            moves=moves,
            targets=targets,
            actions={u.id: self._action(u.id) for u in units if u.id in active},
            held=self.directives.controls,
            router=self.planner,
            claims=self._claims(units, moves, targets, window),
            charges=charges,
            leaving={uid: frozenset(w.path) for uid, w in inside.items() if w.path},
        )
        return self._orders(units, active, step, notes, inside)

    def _roll_call(self, now: float) -> set[str]:
        """The units active this step; the events tell who went silent and who is heard again."""
        active = self.world.roll_call(now)
        for unit, silent_s in self.world.silenced:
            self.events.unit_silent(self.say.stamp.now(), unit, silent_s)
        for unit in self.world.heard_again:
            self.events.unit_changed(self.say.stamp.now(), unit, "heard")
        return active

    def _energy(self, units: list[UnitRecord], active: set[str], now: float) -> EnergyStep:
        """The energy policy's step (energy.py): every active unit that reports its charge in,
        with the squares of units that cannot make way (lost, paused, out of service, stopped,
        not coordinated, empty) and the units whose factsheet has energy but whose state has no
        charge yet; the jobs of units that must charge at once go back to the queue."""
        batteries = []
        blocked: dict[Cell, str] = {}
        unknown: list[str] = []
        for u in units:
            st, fs = u.state, u.factsheet
            if st is None:
                continue
            control = self.directives.controls.get(u.id)
            if (
                u.id not in active
                or control is not None
                or st.estop
                or st.mode != "coordinated"
                or (st.battery_pct is not None and st.battery_pct <= 0)
            ):
                blocked[st.position] = u.id
            if fs is None or fs.energy is None or u.id not in active:
                continue
            if st.battery_pct is None:
                unknown.append(u.id)
                continue
            job = self.jobs.of_unit(u.id)
            carrying = (job is not None and job.state in CARRYING_STATES) or (
                u.id in self.progress.returns
            )
            goal = u.id in self.directives.goals
            free = (
                job is None
                and not goal
                and control is None
                and st.job_id is None
                and st.mode == "coordinated"
                and not st.estop
            )
            batteries.append(
                Battery(
                    id=u.id,
                    position=st.position,
                    pct=st.battery_pct,
                    model=fs.energy,
                    charging=st.charging,
                    free=free,
                    job=job is not None and not carrying,
                    carrying=carrying,
                    held=control == "paused",
                    goal=goal,
                    out_of_service=control == "out_of_service",
                )
            )
        step = self.energy.plan(batteries, self._distance, now, blocked, unknown)
        for uid, why in step.requeue.items():
            job = self.jobs.of_unit(uid)
            if job is not None and job.state not in CARRYING_STATES:
                self.progress.requeue(job, why)
        return step

    def _to_charger(self, square: Cell) -> int | None:
        """Squares from `square` to its nearest charger (None: none can be reached)."""
        near = self.energy.chargers.nearest(square, self._distance)
        return None if near is None else near[1]

    def _allocate(
        self,
        units: list[UnitRecord],
        active: set[str],
        settled: set[str],
        now: float,
        energy: EnergyStep,
    ) -> None:
        """Queued jobs to idle units that can carry them (and finish them on their charge), and
        assigned ones under way; a unit charging that is given one leaves its charger."""
        if self.estop:
            return
        pcts = self.energy.pcts if self.energy.settings.policy == "gridfleet" else None
        given = self.progress.allocate(
            units,
            active,
            settled,
            self.planner.cache,
            self.step_no,
            now,
            plain=self.map_cache,  # a job fails for good only on the map, zones open
            energy=energy,
            to_charger=self._to_charger,
            charge_pcts=pcts,
        )
        if given:
            by_unit = {unit: job for job, unit in given.items()}
            self.energy.given_jobs(by_unit, now)
        self.progress.dispatch(units, active)

    def _tell_charges(self, news: list[ChargeNews]) -> None:
        """Each charge sent, started and ended, in the events; started and ended in the history."""
        for n in news:
            at = self.say.stamp.now()
            where = f"at {n.charger}"
            if n.event == "sent":
                text = f"unit {n.unit} sent to charge {where} ({n.pct:.0f} %: {n.reason})"
            elif n.event == "started":
                text = f"unit {n.unit} charging {where} ({n.pct:.0f} %)"
            elif n.event == "cancelled":
                text = f"unit {n.unit} no longer sent to charge {where}: {n.reason}"
            else:
                took = "" if n.seconds is None else f" in {n.seconds:.1f} s"
                text = (
                    f"unit {n.unit} charged {where}: {n.from_pct or 0.0:.0f} % to {n.pct:.0f} %"
                    f"{took} ({n.reason})"
                )
            self.events.add(at, "unit", text, unit=n.unit)
            if n.event in ("started", "ended"):
                entry = ChargeEntry(
                    at=at,
                    unit=n.unit,
                    charger=n.charger,
                    event="started" if n.event == "started" else "ended",
                    battery_pct=max(0.0, min(100.0, n.pct)),
                    reason=n.reason,
                )
                self._charges.append(entry)

    def _explain_waits(self, now: float, active: set[str], inside: Mapping[str, WayOut]) -> None:
        """Every waiting job's reason (waits.py); the events tell the jobs newly stuck."""
        if self.estop:
            self._free_since = now  # a unit held by the stop is not stuck: count from the release
        after_s = stuck_after_s(self.world.step_period_s)
        stuck = Stuck(now, after_s, self._in_way_of, self._free_since)
        explain_waits(
            self.jobs,
            self.world.units,
            active,
            self.estop,
            self.directives.goals,
            self.directives.controls,
            stuck,
            self.energy.words(self._distance) if self.energy.active else None,
            zone_wait=partial(self._zone_wait, inside, {}) if self.zones else None,
        )
        for job in self.stuck_news.newly_stuck(self.jobs):
            at = self.say.stamp.now()
            self.events.add(at, "job", f"job {job.id}: {job.wait_reason}", job.id, job.unit)

    def _moves(
        self,
        units: list[UnitRecord],
        active: set[str],
        settled: set[str],
        targets: dict[str, Cell | None],
        standing: set[str],
        inside: Mapping[str, WayOut],
    ) -> dict[str, Cell]:
        """This step's collision-free move of every settled unit free to move (moves.py); a
        unit charging on its charger stands, and the others go round it. A unit inside a
        closed zone is not the planner's (its square is blocked there): it takes the next
        square of its way out when nobody stands on, holds or is given it (zones.py), and the
        planner keeps everyone else off its squares and that next one."""
        if self.estop:
            return {}
        free = {
            u.id
            for u in units
            if u.id in settled
            and u.id not in self.directives.controls  # paused or out of service: holds
            and u.state is not None
            and not u.state.estop
            and u.state.mode == "coordinated"
        }
        movable = free - standing - inside.keys()  # a unit in a closed zone leaves, charging or not
        driving = {u.id for u in units if u.id in active and u.id not in settled}
        urgency = self.progress.urgency(units)
        if not inside:
            return self.moves.plan(
                units, movable, self.orders.reserved, targets, urgency, driving=driving
            )
        for uid in inside:
            self.moves.following.pop(uid, None)  # the planner's plans for it are over
        taken = {f.square for f in self.moves.following.values()}  # followers' squares to be
        held: set[Cell] = set()  # the squares of units inside: nobody else enters them
        for u in units:
            assert u.state is not None
            squares = {u.state.position, *self.orders.reserved(u)}
            taken |= squares
            if u.id in inside:
                held |= squares
        ways = {uid: w.path for uid, w in inside.items() if w.path and uid in free}
        leaving = leaving_moves(ways, taken)
        keep_clear = set()
        for uid, way in ways.items():
            held.add(way[0])  # its next square, given now or waited for: nobody else's
            if uid not in leaving and not self.zones.covers(way[0]):
                keep_clear.add(way[0])  # outside: an idle unit standing there makes way
        moves = self.moves.plan(
            [u for u in units if u.id not in inside],
            movable,
            self.orders.reserved,
            targets,
            urgency,
            driving=driving,
            elsewhere=held,
            keep_clear=keep_clear,
        )
        moves.update(leaving)
        return moves

    def _park(self, targets: dict[str, Cell | None]) -> None:
        """An idle unit making way for another shows where it goes: its parking square."""
        for uid, target in targets.items():
            if target is None:
                targets[uid] = self.planner.parking(uid)

    def _orders(
        self,
        units: list[UnitRecord],
        active: set[str],
        step: StepContext,
        notes: Mapping[str, str],
        inside: Mapping[str, WayOut],
    ) -> StepResult:
        """One order per unit that can hear it (orders.py), and every unit's route view: a unit
        leaving a closed zone shows the rest of its way out, and `notes` say why a unit is moved
        or held for a zone."""
        orders: dict[str, OrderPlan] = {}
        routes: dict[str, RouteView] = {}
        for u in units:
            if u.id not in active:
                # Lost units get no orders: a unit that is alive but cut off holds still after
                # 3 step periods without orders (protocol.md §8).
                routes[u.id] = RouteView(note=notes.get(u.id))
                continue
            order = self.orders.order(u, step)
            step.claims.hold(u.id, order.released)
            orders[u.id] = order
            way = inside.get(u.id)
            planned = order.planned
            if way is not None and way.path and not step.estop:
                planned = [c for c in way.path if c not in order.released]
            routes[u.id] = RouteView(
                released=order.released,
                planned=planned,
                target=order.target,
                control=self.directives.controls.get(u.id),
                note=notes.get(u.id),
            )
        return StepResult(self.step_no, orders, routes)

    def _claims(
        self,
        units: list[UnitRecord],
        moves: dict[str, Cell],
        targets: dict[str, Cell | None],
        window: int,
    ) -> Claims:
        """Who stands on, holds, enters this step or intends each square (window.py)."""
        claims = Claims(self.planner.grid)  # no window takes a closed zone's square
        if window == 1:
            return claims  # no unit is given more than its move: nothing to claim
        for u in units:
            assert u.state is not None
            claims.stand(u.id, u.state.position)
            claims.hold(u.id, sorted(self.orders.reserved(u)))
            target = targets.get(u.id)
            if target is not None and u.state.position != target:
                way = self.planner.route(u.state.position, target, window, u.id)
                claims.intend(u.id, way)
        for uid, move in moves.items():
            claims.hold(uid, [move])
        for uid, follow in self.moves.following.items():
            claims.hold(uid, [follow.square])
        return claims

    # ---- what every Effects carries ---------------------------------------------------------

    def _halt_orders(self) -> list[Outbound]:
        heard = [
            u.id
            for u in self.world.units.values()
            if u.state is not None and u.connection not in ("offline", "broken")
        ]
        plans = self.orders.halt_orders(heard, self.step_no)
        return [self.say.order(unit_id, plan) for unit_id, plan in plans.items()]

    def _views(self, notes: list[Note], now: float | None = None) -> list[Outbound]:
        send_map, send_jobs = self.views.take(now)
        out = []
        try:
            if send_map:
                out.append(self.say.fleet_map(self.world))
            if send_jobs:
                out.append(self.say.jobs(self.jobs, self.step_no, self.world.step_period_s))
            if self.energy.active and self.energy.changed():
                energy = self.energy.view(self.say.stamp("energy"))
                out.append(Outbound.of("energy", self.topics.fleet("energy"), energy))
            if self.zones.dirty:
                out.append(self._zones_view())
            if self.events.dirty:  # stamped only when sent: a topic's seq counts its messages
                view = self.events.take(self.say.stamp("events"))
                out.append(Outbound.of("events", self.topics.fleet("events"), view))
        except Exception as exc:  # a view that cannot be built must not stop the orders
            notes.append((logging.ERROR, f"views of step {self.step_no} failed: {exc!r}"))
            status = self.topics.fleet("coordinator")
            out.append(self._refuse(status, f"internal error in the views: {exc!r}", None, notes))
        return out

    def _persist(self) -> tuple[Job, ...]:
        """Jobs changed since the last Effects (the queue view is out of date with them)."""
        changed = tuple(self.jobs.jobs[j] for j in sorted(self.jobs.changed))
        self.jobs.changed.clear()
        if changed:
            self.views.jobs_dirty = True
            self.events.jobs_changed(self.say.stamp.now(), changed, self.world.step_period_s)
        return changed

    def _effects(
        self,
        publish: Sequence[Outbound],
        persist: tuple[Job, ...] = (),
        *,
        acks_until: float | None = None,
        views_at: float | None = None,
        log: Sequence[Note] = (),
        controls: tuple[tuple[str, UnitControlState | None], ...] = (),
    ) -> Effects:
        """Everything one call of the core decided: each part handed in by the call itself."""
        charges, self._charges = tuple(self._charges), []
        return Effects(
            publish=tuple(publish),
            persist=persist,
            events=self.events.take_fresh(),
            charges=charges,
            controls=controls,
            removals=self.removals.take(),
            zones=self.zones.take_changes(),
            audit=self.audit.take(),
            awaiting=frozenset(self.orders.awaiting),
            acks_until=acks_until,
            views_at=views_at,
            log=tuple(log),
        )


def _traced(exc: BaseException) -> str:
    """An exception and its traceback, for the coordinator's log (never for `errors`)."""
    return f"{exc!r}\n" + "".join(traceback.format_exception(exc)).rstrip()
